"""MuJoCo geoms as viser primitives, posed from recorded states exactly as MuJoCo poses the bodies."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import viser

from demo.view.scene import STATE_SPEC, MujocoScene, capsule_mesh, state_mismatch

XML = """
<mujoco>
  <asset>
    <mesh name="tet" vertex="0 0 0  0.1 0 0  0 0.1 0  0 0 0.1"/>
    <hfield name="terrain" nrow="3" ncol="3" size="0.2 0.2 0.05 0.01"/>
  </asset>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <geom name="bumps" type="hfield" hfield="terrain" pos="1 1 0"/>
    <body name="arm" pos="0 0 0.3">
      <joint name="hinge" type="hinge" axis="0 0 1"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
      <geom type="cylinder" pos="0.3 0 0" size="0.04 0.05"/>
      <geom type="ellipsoid" pos="0 0 0.1" size="0.05 0.03 0.02"/>
      <geom type="mesh" mesh="tet" pos="0 0.1 0"/>
      <geom name="collision_only" type="box" size="0.1 0.1 0.1" group="3"/>
      <geom name="invisible" type="sphere" size="0.1" rgba="1 1 1 0"/>
      <body name="forearm" pos="0.3 0 0">
        <joint name="elbow" type="hinge" axis="0 1 0"/>
        <geom type="box" size="0.02 0.02 0.1" pos="0 0 0.1"/>
      </body>
    </body>
    <body name="cube" pos="0.4 0 0.05">
      <freejoint/>
      <geom type="box" size="0.025 0.025 0.025"/>
      <geom type="sphere" pos="0 0 0.05" size="0.02"/>
    </body>
    <body name="target" mocap="true" pos="0 0.5 0.2"><geom type="sphere" size="0.02"/></body>
  </worldbody>
</mujoco>
"""


@pytest.fixture(scope="module")
def server():
    s = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    yield s
    s.stop()


def test_every_visible_geom_is_drawn(server: viser.ViserServer) -> None:
    model = mujoco.MjModel.from_xml_string(XML)
    scene = MujocoScene(server.scene, model, root="/t1")
    names = {g: mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in range(model.ngeom)}
    hidden = {g for g, n in names.items() if n in ("collision_only", "invisible", "bumps")}
    assert set(scene.geoms) == set(range(model.ngeom)) - hidden
    assert len(scene.skipped) == 1 and "HFIELD" in scene.skipped[0]
    kinds = {type(h).__name__ for h in scene.geoms.values()}
    assert {"BoxHandle", "IcosphereHandle", "CylinderHandle", "MeshHandle"} <= kinds
    world = {g for g in scene.geoms if model.geom_bodyid[g] == 0}
    assert world == {0}  # only the floor is static
    assert set(scene.bodies) == {1, 2, 3, 4}  # arm, forearm, cube, mocap target


def test_show_poses_bodies_like_mujoco(server: viser.ViserServer) -> None:
    model = mujoco.MjModel.from_xml_string(XML)
    scene = MujocoScene(server.scene, model, root="/t2")
    rng = np.random.default_rng(0)
    data = mujoco.MjData(model)
    for _ in range(3):
        data.qpos[:] = rng.normal(size=model.nq)
        data.qpos[5:9] /= np.linalg.norm(data.qpos[5:9])
        data.mocap_pos[0] = rng.normal(size=3)
        mujoco.mj_forward(model, data)
        state = np.zeros(mujoco.mj_stateSize(model, STATE_SPEC))
        mujoco.mj_getState(model, data, state, STATE_SPEC)
        assert state_mismatch(model, state) is None
        scene.show(state)
        for body, handle in scene.bodies.items():
            np.testing.assert_allclose(handle.position, data.xpos[body], atol=1e-12)
            np.testing.assert_allclose(handle.wxyz, data.xquat[body], atol=1e-12)
    assert "mjSTATE_INTEGRATION" in state_mismatch(model, np.zeros(5))
    position, look_at = scene.camera_pose()
    assert np.linalg.norm(position - look_at) > 0.3


def test_capsule_mesh_lies_on_the_capsule() -> None:
    radius, half = 0.03, 0.15
    verts, faces = capsule_mesh(radius, half)
    z = np.clip(verts[:, 2], -half, half)
    dist = np.linalg.norm(verts - np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=1), axis=1)
    np.testing.assert_allclose(dist, radius, atol=1e-6)
    assert verts[:, 2].max() == pytest.approx(half + radius) and verts[:, 2].min() == pytest.approx(-half - radius)
    assert faces.max() < len(verts) and faces.shape[1] == 3
