"""The policy's observation vector: key choice, quaternions as 6D rotations, relative positions."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from demo.errors import DemoError
from demo.store import FeatureSpec
from demo.policies.observation import ObsSpec, quat_to_rot6d

FEATURES = {
    "obs.joint_pos": FeatureSpec((7,)),
    "obs.joint_vel": FeatureSpec((7,)),
    "obs.ee_pos": FeatureSpec((3,)),
    "obs.ee_quat": FeatureSpec((4,)),
    "obs.object_pos": FeatureSpec((2, 3)),
    "obs.object_quat": FeatureSpec((2, 4)),
    "obs.image_front": FeatureSpec((8, 8, 3), "uint8"),
    "sim.state": FeatureSpec((20,), "float64"),
}


STATE_FEATURES = {k: v for k, v in FEATURES.items() if k != "obs.image_front"}


def test_default_keys_drop_velocities_and_add_offsets() -> None:
    spec = ObsSpec.from_features(STATE_FEATURES)
    assert spec.keys == ("obs.joint_pos", "obs.ee_pos", "obs.ee_quat", "obs.object_pos", "obs.object_quat",
                         "obs.object_pos-obs.ee_pos")
    assert spec.dims == (7, 3, 6, 6, 12, 6)
    assert spec.source_keys == ["obs.joint_pos", "obs.ee_pos", "obs.ee_quat", "obs.object_pos", "obs.object_quat"]
    assert "obs.joint_vel" in ObsSpec.from_features(FEATURES, ["all"]).keys
    # by key, rows of values: each object its own row, its quaternion as a 6D rotation, an offset per object
    assert spec.layout(STATE_FEATURES) == ((1, 7), (1, 3), (1, 6), (2, 3), (2, 6), (2, 3))


def test_a_store_with_cameras_trains_on_images_and_proprioception_by_default() -> None:
    spec = ObsSpec.from_features(FEATURES)
    assert spec.images == ("obs.image_front",) and spec.image_shapes == ((8, 8, 3),)
    assert spec.keys == ("obs.joint_pos", "obs.ee_pos", "obs.ee_quat")  # no object poses, no velocities
    assert spec.cameras() == [("front", 8, 8)]
    assert ObsSpec.from_json(spec.to_json()) == spec
    # Shorthands: one camera, the robot's sensors, and an object pose asked for by name.
    chosen = ObsSpec.from_features(FEATURES, ["images", "proprio", "obs.object_pos"])
    assert chosen.images == ("obs.image_front",) and chosen.keys[-1] == "obs.object_pos"
    with pytest.raises(DemoError, match="besides its images"):
        ObsSpec.from_features(FEATURES, ["obs.image_front"])
    with pytest.raises(DemoError, match="has no camera image 'obs.image_wrist'"):
        ObsSpec.from_features(FEATURES, ["obs.image_wrist", "proprio"])
    with pytest.raises(DemoError, match="trained on"):
        spec.check_against({**FEATURES, "obs.image_front": FeatureSpec((16, 16, 3), "uint8")}, "env")


def test_a_foreign_camera_store_trains_on_its_own_state_and_never_on_the_simulators() -> None:
    # A Gymnasium env's camera + state (Meta-World from its corner camera), with the simulator's state recorded
    # beside them for --aux-target: the default inputs leave that out, and naming it still works.
    features = {"obs.image_corner": FeatureSpec((8, 8, 3), "uint8"), "obs.state": FeatureSpec((4,)),
                "obs.env_state": FeatureSpec((39,))}
    assert ObsSpec.from_features(features).keys == ("obs.state",)
    assert ObsSpec.from_features(features, ["images", "obs.state", "obs.env_state"]).keys == ("obs.state", "obs.env_state")


def test_vector_and_batch_agree_and_transform() -> None:
    spec = ObsSpec.from_features(STATE_FEATURES)
    rng = np.random.default_rng(0)
    frames = {k: rng.normal(size=(5, *f.shape)).astype(np.float32) for k, f in FEATURES.items() if k != "obs.image_front"}
    batch = spec.concat(frames)
    assert batch.shape == (5, spec.dim)
    for i in range(5):
        assert np.allclose(spec.vector({k: v[i] for k, v in frames.items()}), batch[i])
    offsets = batch[:, -6:].reshape(5, 2, 3)
    assert np.allclose(offsets, frames["obs.object_pos"] - frames["obs.ee_pos"][:, None], atol=1e-6)
    # A quaternion and its negative give the same input (stores flip signs to keep w >= 0).
    flipped = dict(frames, **{"obs.ee_quat": -frames["obs.ee_quat"]})
    assert np.allclose(spec.concat(flipped), batch)
    # A spec may start with an offset ("a-b" is no key of the frames themselves).
    offset_first = ObsSpec.from_features(STATE_FEATURES, ["obs.object_pos-obs.ee_pos", "obs.joint_pos"])
    assert np.allclose(offset_first.concat(frames)[:, :6], batch[:, -6:])


def test_rot6d_is_the_rotation_matrix_columns() -> None:
    q = np.random.default_rng(1).normal(size=(10, 4))
    for row, six in zip(q, quat_to_rot6d(q)):
        m = np.zeros(9)
        mujoco.mju_quat2Mat(m, row / np.linalg.norm(row))
        m = m.reshape(3, 3)
        assert np.allclose(six, np.concatenate([m[:, 0], m[:, 1]]), atol=1e-6)


def test_json_round_trip_and_checks_against_an_environment() -> None:
    spec = ObsSpec.from_features(STATE_FEATURES)
    assert ObsSpec.from_json(spec.to_json()) == spec
    spec.check_against(FEATURES, "env")
    with pytest.raises(DemoError, match="no observation 'obs.object_quat'"):
        spec.check_against({k: v for k, v in FEATURES.items() if k != "obs.object_quat"}, "env")
    with pytest.raises(DemoError, match="different size"):
        spec.check_against({**FEATURES, "obs.object_pos": FeatureSpec((3, 3))}, "env")


def test_a_difference_of_quaternions_is_the_relative_rotation() -> None:
    """``obs.object_quat-obs.ee_quat``: each object's orientation in the gripper's frame, R_ee^T R_obj,
    unchanged when both turn together, sign-free; a quaternion minus a vector is refused."""
    spec = ObsSpec.from_features(STATE_FEATURES, ["obs.object_quat-obs.ee_quat", "obs.object_pos-obs.ee_pos"])
    assert spec.dims == (12, 6) and spec.transforms == ("relative_rotation", "difference")
    assert ObsSpec.from_json(spec.to_json()) == spec
    spec.check_against(FEATURES, "env")
    rng = np.random.default_rng(2)
    q = rng.normal(size=(4, 3, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    frames = {"obs.ee_quat": q[:, 0], "obs.object_quat": q[:, 1:], "obs.object_pos": rng.normal(size=(4, 2, 3)),
              "obs.ee_pos": rng.normal(size=(4, 3))}
    batch = spec.concat(frames)
    turn = np.zeros(4)
    mujoco.mju_axisAngle2Quat(turn, np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8]), 1.1)
    for i in range(4):
        assert np.allclose(spec.vector({k: v[i] for k, v in frames.items()}), batch[i], atol=1e-6)
        mats = []
        for quat in q[i]:
            m = np.zeros(9)
            mujoco.mju_quat2Mat(m, quat)
            mats.append(m.reshape(3, 3))
        for j in (1, 2):
            rel = mats[0].T @ mats[j]
            assert np.allclose(batch[i, 6 * (j - 1):6 * j], np.concatenate([rel[:, 0], rel[:, 1]]), atol=1e-5)
        turned = {**{k: v[i] for k, v in frames.items()}, "obs.ee_quat": np.zeros(4), "obs.object_quat": np.zeros((2, 4))}
        mujoco.mju_mulQuat(turned["obs.ee_quat"], turn, q[i, 0])
        for j in (1, 2):
            mujoco.mju_mulQuat(turned["obs.object_quat"][j - 1], turn, q[i, j])
        turned["obs.object_quat"][0] *= -1  # the same rotation
        assert np.allclose(spec.vector(turned)[:12], batch[i, :12], atol=1e-5)
    with pytest.raises(DemoError, match="a quaternion and a vector do not subtract"):
        ObsSpec.from_features({**STATE_FEATURES, "obs.goal": FeatureSpec((4,))}, ["obs.ee_quat-obs.goal"])


def test_a_foreign_store_with_cameras_reads_its_own_state_as_proprioception() -> None:
    """A Gymnasium env's or a LeRobot dataset's store names no joints: its obs.state is the proprioception."""
    features = {"obs.image_corner": FeatureSpec((8, 8, 3), "uint8", "camera image (RGB)", ""),
                "obs.state": FeatureSpec((4,), "float32", "observation", "")}
    spec = ObsSpec.from_features(features)
    assert spec.images == ("obs.image_corner",) and spec.keys == ("obs.state",)
