"""A MuJoCo model drawn with viser primitives, posed from recorded simulator states.

Each body with visible geoms becomes a viser frame ``/sim/body_<id>``; its geoms are children at
their fixed body-relative poses (``geom_pos``, ``geom_quat``), so replaying a frame only moves the
body frames: ``mj_setState(sim.state, mjSTATE_INTEGRATION)`` + ``mj_kinematics`` and then
``xpos``/``xquat`` (world frame, metres, quaternions w-x-y-z) for every moving body. Geoms of the
world body are placed once. Shown: geom groups 0-2 (MuJoCo's default visible groups) with alpha > 0;
boxes, spheres, ellipsoids, cylinders and planes as viser primitives, capsules and meshes as
triangle meshes. Height fields and SDFs are skipped (listed in :attr:`MujocoScene.skipped`).
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

VISIBLE_GROUPS = (0, 1, 2)
STATE_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION
INFINITE_PLANE_HALF = 2.0  # metres drawn for a plane of size 0 (infinite in MuJoCo)
DEFAULT_RGBA = np.array([0.5, 0.5, 0.5, 1.0], dtype=np.float32)


def capsule_mesh(radius: float, half_length: float, segments: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``[V, 3]`` and faces ``[F, 3]`` of a capsule along z (cylinder of ``2*half_length``)."""
    rings = segments // 2  # latitude steps per hemisphere
    lon = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    rows = []
    for hemi, shift in ((np.linspace(0.0, np.pi / 2, rings + 1), half_length),
                        (np.linspace(np.pi / 2, np.pi, rings + 1), -half_length)):
        for theta in hemi:
            z = radius * np.cos(theta) + shift
            r = radius * np.sin(theta)
            rows.append(np.stack([r * np.cos(lon), r * np.sin(lon), np.full_like(lon, z)], axis=1))
    verts = np.concatenate(rows).astype(np.float32)
    faces = []
    n_rows = len(rows)
    for i in range(n_rows - 1):
        for j in range(segments):
            a, b = i * segments + j, i * segments + (j + 1) % segments
            c, d = a + segments, b + segments
            faces += [(a, c, b), (b, c, d)]
    return verts, np.asarray(faces, dtype=np.uint32)


def state_mismatch(model: mujoco.MjModel, state: np.ndarray) -> str | None:
    """Why a recorded ``sim.state`` frame cannot pose ``model``, or None when it can."""
    size = int(mujoco.mj_stateSize(model, STATE_SPEC))
    if state.ndim != 1 or state.shape[0] != size:
        return (f"sim.state has {state.shape[-1] if state.ndim else 1} values a frame but this model's "
                f"mjSTATE_INTEGRATION has {size}: the store was recorded with another model (try --mjcf)")
    return None


class MujocoScene:
    """The model's visible geoms in a viser scene; :meth:`show` poses them from a state vector."""

    def __init__(self, scene: Any, model: mujoco.MjModel, root: str = "/sim", only_bodies: set[int] | None = None,
                 opacity: float | None = None):
        """``only_bodies``: draw the geoms of these bodies alone (None: every visible geom); ``opacity``: draw them
        translucent (a ghost, e.g. ``demo teleop``'s leader arm)."""
        self.model = model
        self.data = mujoco.MjData(model)
        self.root = root
        self.state_size = int(mujoco.mj_stateSize(model, STATE_SPEC))
        self.skipped: list[str] = []
        self.bodies: dict[int, Any] = {}  # body id -> viser frame handle, for moving bodies
        self.geoms: dict[int, Any] = {}  # geom id -> viser handle
        mujoco.mj_kinematics(model, self.data)
        scene.add_frame(root, show_axes=False)
        for g in range(model.ngeom):
            if int(model.geom_group[g]) not in VISIBLE_GROUPS:
                continue
            rgba = self._rgba(g)
            if rgba[3] <= 0:
                continue
            body = int(model.geom_bodyid[g])
            if only_bodies is not None and body not in only_bodies:
                continue
            if opacity is not None:
                rgba = np.r_[rgba[:3], opacity].astype(np.float32)
            parent = root if body == 0 else self._body_frame(scene, body)
            handle = self._add_geom(scene, f"{parent}/geom_{g}", g, rgba)
            if handle is not None:
                self.geoms[g] = handle

    def _body_frame(self, scene: Any, body: int) -> str:
        name = f"{self.root}/body_{body}"
        if body not in self.bodies:
            self.bodies[body] = scene.add_frame(
                name, show_axes=False, position=self.data.xpos[body].copy(), wxyz=self.data.xquat[body].copy()
            )
        return name

    def _rgba(self, g: int) -> np.ndarray:
        m = self.model
        rgba = np.asarray(m.geom_rgba[g], dtype=np.float32)
        mat = int(m.geom_matid[g])
        if mat >= 0 and np.allclose(rgba, DEFAULT_RGBA):
            rgba = np.asarray(m.mat_rgba[mat], dtype=np.float32)
        return rgba

    def _add_geom(self, scene: Any, name: str, g: int, rgba: np.ndarray) -> Any:
        m = self.model
        kind = int(m.geom_type[g])
        size = np.asarray(m.geom_size[g], dtype=np.float64)
        pose = {"position": np.asarray(m.geom_pos[g], dtype=np.float64), "wxyz": np.asarray(m.geom_quat[g], dtype=np.float64)}
        color = tuple(int(round(float(c) * 255)) for c in rgba[:3])
        look = {"color": color, "opacity": float(rgba[3]) if rgba[3] < 1 else None}
        T = mujoco.mjtGeom
        if kind == T.mjGEOM_BOX:
            return scene.add_box(name, dimensions=tuple(2 * size), **look, **pose)
        if kind == T.mjGEOM_SPHERE:
            return scene.add_icosphere(name, radius=float(size[0]), subdivisions=2, **look, **pose)
        if kind == T.mjGEOM_ELLIPSOID:
            return scene.add_icosphere(name, radius=1.0, subdivisions=2, scale=tuple(float(s) for s in size), **look, **pose)
        if kind == T.mjGEOM_CYLINDER:
            return scene.add_cylinder(name, radius=float(size[0]), height=float(2 * size[1]), **look, **pose)
        if kind == T.mjGEOM_CAPSULE:
            verts, faces = capsule_mesh(float(size[0]), float(size[1]))
            return scene.add_mesh_simple(name, verts, faces, **look, **pose)
        if kind == T.mjGEOM_PLANE:
            hx = float(size[0]) or INFINITE_PLANE_HALF
            hy = float(size[1]) or INFINITE_PLANE_HALF
            # A thin slab whose top face is the plane (z = 0 in the geom frame).
            thickness = 0.002
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, pose["wxyz"])
            pose["position"] = pose["position"] - rot.reshape(3, 3)[:, 2] * thickness / 2
            return scene.add_box(name, dimensions=(2 * hx, 2 * hy, thickness), **look, **pose)
        if kind == T.mjGEOM_MESH:
            mesh = int(m.geom_dataid[g])
            va, vn = int(m.mesh_vertadr[mesh]), int(m.mesh_vertnum[mesh])
            fa, fn = int(m.mesh_faceadr[mesh]), int(m.mesh_facenum[mesh])
            verts = np.asarray(m.mesh_vert[va:va + vn], dtype=np.float32)
            faces = np.asarray(m.mesh_face[fa:fa + fn], dtype=np.uint32)
            return scene.add_mesh_simple(name, verts, faces, **look, **pose)
        self.skipped.append(f"geom {g} ({mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or 'unnamed'}): "
                            f"type {T(kind).name} is not drawn")
        return None

    def show(self, state: np.ndarray) -> None:
        """Pose every moving body from one recorded ``sim.state`` (float64, mjSTATE_INTEGRATION)."""
        mujoco.mj_setState(self.model, self.data, np.asarray(state, dtype=np.float64), STATE_SPEC)
        mujoco.mj_kinematics(self.model, self.data)
        self.show_data(self.data)

    def show_data(self, data: mujoco.MjData) -> None:
        """Pose every moving body as ``data``'s kinematics have it (``xpos``/``xquat`` computed)."""
        for body, handle in self.bodies.items():
            handle.position = data.xpos[body].copy()
            handle.wxyz = data.xquat[body].copy()

    def camera_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """A viewpoint (position, look-at; world frame, metres) framing the moving bodies."""
        bodies = list(self.bodies) or list(range(1, self.model.nbody))
        if not bodies:
            center, extent = np.asarray(self.model.stat.center, dtype=np.float64), float(self.model.stat.extent) or 1.0
        else:
            points = self.data.xpos[bodies]
            lo, hi = points.min(axis=0), points.max(axis=0)
            center, extent = (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)), 0.5)
        return center + extent * np.array([0.9, -0.75, 0.6]), center
