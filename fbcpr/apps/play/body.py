"""The humanoid in the page: one viser scene node per MJCF geom (capsule, sphere, box; the floor plane as a grid),
each posed every frame from MuJoCo's geom_xpos and geom_xmat, so what is drawn is what is simulated."""
from __future__ import annotations

from typing import Any

import mujoco
import numpy as np


def capsule_mesh(radius: float, half_length: float, rings: int = 6, segments: int = 16
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of a capsule along z: a sphere's upper half lifted by half_length, its lower half lowered
    (the two equators, duplicated, are the cylinder's rims); faces wind counter-clockwise seen from outside."""
    theta = np.concatenate([np.linspace(0, np.pi / 2, rings + 1), np.linspace(np.pi / 2, np.pi, rings + 1)])
    lift = np.where(np.arange(len(theta)) <= rings, half_length, -half_length)
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    verts = np.stack([radius * st * np.cos(phi), radius * st * np.sin(phi),
                      np.broadcast_to(radius * ct + lift[:, None], (len(theta), segments))], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(len(theta) - 1), np.arange(segments), indexing="ij")
    a, b = i * segments + j, (i + 1) * segments + j
    c, d = (i + 1) * segments + (j + 1) % segments, i * segments + (j + 1) % segments
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return verts.astype(np.float32), faces.astype(np.uint32)


class Body:
    """Scene nodes for the geoms of `model`; `update(data)` poses them (inside one atomic update of the scene)."""

    def __init__(self, server: Any, model: mujoco.MjModel, root: str = "/humanoid") -> None:
        self.server = server
        self.geoms: list[int] = []
        self.handles: list[Any] = []
        for g in range(model.ngeom):
            kind, size = model.geom_type[g], model.geom_size[g]
            color = tuple(int(c) for c in np.round(model.geom_rgba[g, :3] * 255))
            name = f"{root}/{mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or g}"
            if kind == mujoco.mjtGeom.mjGEOM_PLANE:
                server.scene.add_grid("/floor", width=40.0, height=40.0, cell_size=0.5, section_size=2.0,
                                      plane_color=(235, 235, 235), plane_opacity=1.0)
                continue
            if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
                verts, faces = capsule_mesh(float(size[0]), float(size[1]))
                handle = server.scene.add_mesh_simple(name, verts, faces, color=color)
            elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
                handle = server.scene.add_icosphere(name, radius=float(size[0]), color=color, subdivisions=2)
            elif kind == mujoco.mjtGeom.mjGEOM_BOX:
                handle = server.scene.add_box(name, color=color, dimensions=tuple(2 * size), flat_shading=False)
            else:
                raise ValueError(f"geom {name}: type {kind} is not drawn (capsules, spheres, boxes and a plane are)")
            self.geoms.append(g)
            self.handles.append(handle)
        self._quat = np.zeros(4)

    def update(self, data: mujoco.MjData) -> None:
        """Pose every geom from data.geom_xpos and geom_xmat (world frame, as MuJoCo computed them)."""
        with self.server.atomic():
            for g, handle in zip(self.geoms, self.handles):
                mujoco.mju_mat2Quat(self._quat, data.geom_xmat[g])
                handle.position = data.geom_xpos[g].copy()
                handle.wxyz = self._quat.copy()
