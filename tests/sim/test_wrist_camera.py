"""The robot config's `wrist_camera` key: where the `wrist` camera goes, a named MJCF camera, bad values."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from demo.errors import DemoError
from demo.sim import load_robot, make_env
from demo.sim.geometry import quat_to_mat
from demo.sim.robot import ASSETS, BUILTIN_CONFIG, DEFAULT_WRIST_CAMERA, config_keys, robot_from_keys

BUILTIN_TOML = BUILTIN_CONFIG.read_text().replace('mjcf = "panda.xml"', f'mjcf = "{ASSETS / "panda.xml"}"')


def config(tmp_path: Path, extra: str, xml: str | None = None) -> Path:
    text = BUILTIN_TOML + extra + "\n"
    if xml is not None:
        (tmp_path / "arm.xml").write_text(xml)
        text = text.replace(f'mjcf = "{ASSETS / "panda.xml"}"', 'mjcf = "arm.xml"')
    path = tmp_path / "arm.toml"
    path.write_text(text)
    return path


def wrist_pose_in_site_frame(robot: object) -> tuple[np.ndarray, np.ndarray, float]:
    """(position (m), rotation matrix, fovy) of the scene's `wrist` camera in the EE site frame."""
    env = make_env("reach", robot=robot)
    try:
        m, d = env.model, env.data
        cam, site = m.camera("wrist").id, env.ee_site
        site_rot = d.site_xmat[site].reshape(3, 3)
        pos = site_rot.T @ (d.cam_xpos[cam] - d.site_xpos[site])
        return pos, site_rot.T @ d.cam_xmat[cam].reshape(3, 3), float(m.cam_fovy[cam])
    finally:
        env.close()


def test_default_is_documented_and_not_recorded() -> None:
    robot = load_robot(None)
    assert robot.wrist_camera == DEFAULT_WRIST_CAMERA
    pos, rot, fovy = wrist_pose_in_site_frame(robot)
    assert np.allclose(pos, [0.05, 0.0, -0.05], atol=1e-9) and fovy == 80.0
    look = -rot[:, 2]  # a MuJoCo camera looks along its -z
    assert np.allclose(look, np.subtract([0, 0, 0.12], [0.05, 0, -0.05]) / np.linalg.norm([-0.05, 0, 0.17]))
    assert "wrist_camera" not in config_keys(robot, "panda.xml")  # records of older stores stay equal


def test_pose_in_ee_site_frame(tmp_path: Path) -> None:
    robot = load_robot(config(tmp_path, "wrist_camera = { pos = [0.0, 0.06, 0.02], target = [0, 0, 0.2], fovy = 60 }"))
    pos, rot, fovy = wrist_pose_in_site_frame(robot)
    assert np.allclose(pos, [0.0, 0.06, 0.02], atol=1e-9) and fovy == pytest.approx(60.0)
    look = np.subtract([0, 0, 0.2], [0.0, 0.06, 0.02])
    assert np.allclose(-rot[:, 2], look / np.linalg.norm(look), atol=1e-9)
    # A store records the key by content and reads it back as the same robot.
    again = robot_from_keys(config_keys(robot, str(robot.mjcf_path)), tmp_path, tmp_path)
    assert again.wrist_camera == robot.wrist_camera

    q = [0.0, 1.0, 0.0, 0.0]  # looking along the site's +z (the approach axis), flipped about y
    robot = load_robot(config(tmp_path, f"wrist_camera = {{ quat = {q} }}"))
    pos, rot, fovy = wrist_pose_in_site_frame(robot)
    assert np.allclose(pos, DEFAULT_WRIST_CAMERA.pos, atol=1e-9) and fovy == 80.0
    assert np.allclose(rot, quat_to_mat(np.array(q)), atol=1e-9)


def test_named_mjcf_camera(tmp_path: Path) -> None:
    xml = (ASSETS / "panda.xml").read_text()
    hand = xml.index('<body name="hand"')
    close = xml.index(">", hand) + 1
    xml = xml[:close] + '<camera name="handcam" pos="0.1 0 0.05" xyaxes="0 -1 0 1 0 0" fovy="70"/>' + xml[close:]
    robot = load_robot(config(tmp_path, 'wrist_camera = "handcam"', xml))
    assert robot.wrist_camera == "handcam"
    env = make_env("reach", robot=robot, cameras=["wrist@32x24"])
    try:
        cam = env.model.camera("wrist").id
        assert env.model.cam_fovy[cam] == pytest.approx(70.0)
        assert mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_CAMERA, "handcam") < 0  # rendered as "wrist"
        assert env.observe()["obs.image_wrist"].shape == (24, 32, 3)
    finally:
        env.close()
    with pytest.raises(DemoError, match="has a camera named 'wrist'"):
        load_robot(config(tmp_path, "", xml.replace('"handcam"', '"wrist"')))


@pytest.mark.parametrize(
    "line,needle",
    [
        ("wrist_camera = 3", "'wrist_camera' must be a camera name or a table"),
        ('wrist_camera = ""', "'wrist_camera' must name a camera"),
        ('wrist_camera = "nocam"', "wrist_camera 'nocam' not found in panda.xml"),
        ("wrist_camera = { pos = [1, 2] }", "'wrist_camera.pos' must have 3 numbers"),
        ('wrist_camera = { pos = ["a", 0, 0] }', "'wrist_camera.pos' must be a number"),
        ("wrist_camera = { pos = [nan, 0, 0] }", "'wrist_camera.pos' must be finite"),
        ("wrist_camera = { fovy = 180 }", "'wrist_camera.fovy' must be in (0, 180)"),
        ("wrist_camera = { quat = [0, 0, 0, 0] }", "'wrist_camera.quat' must be a non-zero quaternion"),
        ("wrist_camera = { quat = [1, 0, 0, 0], target = [0, 0, 1] }", "target or quat, not both"),
        ("wrist_camera = { target = [0.05, 0, -0.05] }", "'wrist_camera.target' must differ from its pos"),
        ("wrist_camera = { zoom = 2 }", "unknown 'wrist_camera' key(s): zoom"),
    ],
)
def test_bad_values_name_the_file_and_key(tmp_path: Path, line: str, needle: str) -> None:
    path = config(tmp_path, line)
    with pytest.raises(DemoError) as e:
        load_robot(path)
    assert Path(e.value.where) == path.resolve() and needle in e.value.problem
    assert "\n" not in str(e.value)
