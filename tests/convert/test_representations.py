"""The representation registry: every documented convention, every pair, and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from demo.convert import representations as reps
from demo.convert.representations import Anchor, JointTrack, PoseTrack, Segments
from demo.errors import DemoError
from demo.sim import geometry as rot

JOINTS = tuple(f"j{i}" for i in range(7))
FPS = 20.0


def _pose_track(n: int, seed: int = 0) -> PoseTrack:
    """A smooth random EE trajectory (base frame) with a gripper signal."""
    rng = np.random.default_rng(seed)
    pos = np.array([0.5, 0.0, 0.3]) + np.cumsum(rng.normal(0, 0.004, (n, 3)), axis=0)
    steps = rot.rotvec_to_mat(rng.normal(0, 0.03, (n, 3)))
    R = np.empty((n, 3, 3))
    cur = rot.euler_to_mat(np.array([np.pi, 0.1, 0.4]))  # gripper pointing down: roll near +-pi
    for t in range(n):
        cur = steps[t] @ cur
        R[t] = cur
    return PoseTrack(pos, R, rng.uniform(0, 1, n))


def _anchor(track: PoseTrack, seg: Segments, seed: int = 1) -> Anchor:
    rng = np.random.default_rng(seed)
    E = len(seg.ends)
    return Anchor(q=rng.normal(size=(E, 7)),
                  pos=track.pos[seg.starts] + rng.normal(0, 0.01, (E, 3)),
                  rot=rot.rotvec_to_mat(rng.normal(0, 0.02, (E, 3))) @ track.rot[seg.starts])


EE_FORMATS = [("ee7", {}), ("ee_abs", {}), ("ee_abs", {"rotation": "euler"}), ("ee_abs", {"rotation": "rotvec"}),
              ("ee_abs", {"rotation": "quat"}), ("ee_delta", {}), ("ee_delta", {"rotation": "euler"}),
              ("ee_delta", {"rotation": "rot6d", "delta_frame": "ee"}), ("ee_delta", {"delta_frame": "ee"})]


def test_registry_names_dims_units():
    assert set(reps.REPRESENTATIONS) == {"joint_pos", "joint_vel", "ee_abs", "ee_delta", "ee7"}
    ee7 = reps.make_format("ee7").spec()
    assert ee7.names == ("dx", "dy", "dz", "droll", "dpitch", "dyaw", "gripper")
    assert ee7.units[:6] == ("m", "m", "m", "rad", "rad", "rad") and ee7.dim == 7 and ee7.frame == "base"
    assert ee7.params["rotation"] == "euler" and ee7.params["delta_frame"] == "base"
    assert ee7.params["anchor"] == reps.EE_ANCHOR_KEY
    assert reps.make_format("ee_abs").spec().dim == 10  # default rot6d
    assert reps.make_format("ee_abs", rotation="quat").dim == 8
    jp = reps.make_format("joint_pos", joint_names=JOINTS).spec()
    assert jp.names == (*JOINTS, "gripper") and jp.units[:7] == ("rad",) * 7 and jp.frame == "joint"
    jv = reps.make_format("joint_vel", joint_names=JOINTS).spec()
    assert jv.names[0] == "j0.vel" and jv.units[0] == "rad/s"
    for name, kw in EE_FORMATS:
        fmt = reps.make_format(name, **kw)
        parsed = reps.parse_spec(fmt.spec(), "test")
        assert parsed == fmt, name


@pytest.mark.parametrize("name,kw", EE_FORMATS)
def test_ee_formats_round_trip_over_several_episodes(name, kw):
    track = _pose_track(400)
    seg = Segments([150, 151, 300, 400])  # includes a 1-frame episode
    anchor = _anchor(track, seg)
    fmt = reps.make_format(name, **kw)
    a = reps.encode(fmt, track, FPS, anchor, seg)
    assert a.shape == (400, fmt.dim)
    back = reps.decode(fmt, a.astype(np.float32), FPS, anchor, seg)  # as stored: float32
    assert np.abs(back.pos - track.pos).max() < 1e-6
    assert rot.angle_between(back.rot, track.rot).max() < 2e-6
    assert np.array_equal(back.gripper, a[:, -1].astype(np.float32))
    # Episodes are independent: encoding one alone gives the same rows.
    s, t = 151, 300
    one = reps.encode(fmt, PoseTrack(track.pos[s:t], track.rot[s:t], track.gripper[s:t]), FPS,
                      Anchor(pos=anchor.pos[2], rot=anchor.rot[2]))
    assert np.abs(one - a[s:t]).max() < 1e-12


def test_joint_formats_round_trip():
    rng = np.random.default_rng(2)
    q = np.cumsum(rng.normal(0, 0.01, (300, 7)), axis=0)
    track = JointTrack(q, rng.uniform(size=300))
    seg = Segments([100, 300])
    anchor = Anchor(q=rng.normal(size=(2, 7)))
    jv = reps.make_format("joint_vel", joint_names=JOINTS)
    v = reps.encode(jv, track, FPS, anchor, seg)
    assert np.allclose(v[1:100, :7], np.diff(q[:100], axis=0) * FPS)  # rad/s between commands
    assert np.allclose(v[0, :7], (q[0] - anchor.q[0]) * FPS)  # first: from the anchor
    assert np.abs(reps.decode(jv, v, FPS, anchor, seg).q - q).max() < 1e-12
    jp = reps.make_format("joint_pos", joint_names=JOINTS)
    assert np.array_equal(reps.encode(jp, track, FPS), np.column_stack([q, track.gripper]))


def test_ee7_composes_in_the_base_frame():
    """ee7 rotation deltas are about base axes, applied on the left: R_t = R(delta) @ R_{t-1}."""
    R_prev = rot.euler_to_mat(np.array([0.3, -0.4, 1.0]))
    anchor = Anchor(pos=np.array([0.4, 0.1, 0.2]), rot=R_prev)
    a = np.array([[0.01, -0.02, 0.03, 0.0, 0.0, 0.2, 1.0]])  # dyaw = 0.2 rad, about base z
    out = reps.decode(reps.make_format("ee7"), a, FPS, anchor)
    Rz = rot.euler_to_mat(np.array([0.0, 0.0, 0.2]))
    assert np.allclose(out.rot[0], Rz @ R_prev)
    assert not np.allclose(out.rot[0], R_prev @ Rz)
    assert np.allclose(out.pos[0], [0.41, 0.08, 0.23])  # translations in base coordinates, not EE
    # The EE-frame variant of ee_delta composes on the right and rotates the translation.
    ee = reps.decode(reps.make_format("ee_delta", rotation="euler", delta_frame="ee"), a, FPS, anchor)
    assert np.allclose(ee.rot[0], R_prev @ Rz)
    assert np.allclose(ee.pos[0], anchor.pos + R_prev @ a[0, :3])


def test_ee7_delta_euler_is_extrinsic_roll_pitch_yaw():
    R_prev = np.eye(3)
    d = np.array([0.05, -0.1, 0.2])
    R_next = rot.euler_to_mat(d)
    track = PoseTrack(np.zeros((1, 3)), R_next[None], np.zeros(1))
    a = reps.encode(reps.make_format("ee7"), track, FPS, Anchor(pos=np.zeros(3), rot=R_prev))
    assert np.allclose(a[0, 3:6], d)
    # Rz(yaw) Ry(pitch) Rx(roll): check against an explicit product.
    c, s = np.cos, np.sin
    Rx = np.array([[1, 0, 0], [0, c(d[0]), -s(d[0])], [0, s(d[0]), c(d[0])]])
    Ry = np.array([[c(d[1]), 0, s(d[1])], [0, 1, 0], [-s(d[1]), 0, c(d[1])]])
    Rz = np.array([[c(d[2]), -s(d[2]), 0], [s(d[2]), c(d[2]), 0], [0, 0, 1]])
    assert np.allclose(R_next, Rz @ Ry @ Rx)


def test_gripper_is_copied_unchanged_between_all_formats():
    track = _pose_track(50)
    seg = Segments([50])
    anchor = _anchor(track, seg)
    for name, kw in EE_FORMATS:
        a = reps.encode(reps.make_format(name, **kw), track, FPS, anchor, seg)
        assert np.array_equal(a[:, -1], track.gripper)


def test_ee_abs_euler_is_continuous_across_the_pi_wrap():
    n = 100
    R = rot.euler_to_mat(np.column_stack([np.pi - 0.05 + 0.001 * np.arange(n), np.zeros(n), np.zeros(n)]))
    a = reps.encode(reps.make_format("ee_abs", rotation="euler"), PoseTrack(np.zeros((n, 3)), R, np.zeros(n)), FPS)
    assert np.abs(np.diff(a[:, 3])).max() < 0.01  # roll passes pi without jumping by 2 pi
    assert a[:, 3].max() > np.pi


def test_compose_prefix_equals_a_loop():
    rng = np.random.default_rng(3)
    Rd = rot.rotvec_to_mat(rng.normal(0, 0.5, (37, 3)))
    R0 = rot.rotvec_to_mat(rng.normal(size=(2, 3)))
    seg = Segments([20, 37])
    for left in (True, False):
        out = reps.compose_prefix(Rd, R0, seg, left=left)
        for e, (s, t) in enumerate(zip(seg.starts, seg.ends)):
            cur = R0[e]
            for i in range(s, t):
                cur = Rd[i] @ cur if left else cur @ Rd[i]
                assert np.abs(out[i] - cur).max() < 1e-12


def test_bad_input_fails_clearly():
    with pytest.raises(DemoError, match="unknown action representation 'ee8'.*known: joint_pos"):
        reps.make_format("ee8")
    with pytest.raises(DemoError, match="ee7 takes rotation euler, not 'rot6d'"):
        reps.make_format("ee7", rotation="rot6d")
    with pytest.raises(DemoError, match="always in the base frame"):
        reps.make_format("ee7", delta_frame="ee")
    with pytest.raises(DemoError, match="has no rotation"):
        reps.make_format("joint_pos", joint_names=JOINTS, rotation="euler")
    fmt = reps.make_format("ee7")
    anchor = Anchor(pos=np.zeros(3), rot=np.eye(3))
    with pytest.raises(DemoError, match=r"must be \[T, 7\], got shape \(5, 6\)"):
        reps.decode(fmt, np.zeros((5, 6)), FPS, anchor)
    bad = np.zeros((5, 7))
    bad[3, 2] = np.nan
    with pytest.raises(DemoError, match="non-finite action .* at frame 3"):
        reps.decode(fmt, bad, FPS, anchor)
    with pytest.raises(DemoError, match="needs the episode's initial EE pose"):
        reps.decode(fmt, np.zeros((5, 7)), FPS, None)
    with pytest.raises(DemoError, match="defines no rotation"):
        reps.decode(reps.make_format("ee_abs"), np.zeros((2, 10)), FPS)
    spec = reps.make_format("joint_pos", joint_names=JOINTS).spec()
    with pytest.raises(DemoError, match="7 joints but the robot has 6"):
        reps.parse_spec(spec, "store", JOINTS[:6])
