"""Geometry of a compiled object: its lowest collision point, read from the model MuJoCo built."""

from __future__ import annotations

import mujoco
import numpy as np

from ges_core.transforms import quat_to_matrix

__all__ = ["lowest_point"]


def lowest_point(model: mujoco.MjModel, body: int) -> float:
    """Lowest z (m) of body ``body``'s collision geoms, body frame at the identity pose.

    Meshes use their vertices as MuJoCo stores them (centred on the mesh's centre of mass, the geom frame
    undoing that), so the hull MuJoCo collides with is measured, not the source file.
    """
    lows = []
    for g in np.flatnonzero(model.geom_bodyid == body):
        pos, rot, size = model.geom_pos[g], quat_to_matrix(model.geom_quat[g]), model.geom_size[g]
        kind = model.geom_type[g]
        axis_z = rot[2, 2]  # z component of the geom's own z axis
        if kind == mujoco.mjtGeom.mjGEOM_MESH:
            mesh = model.geom_dataid[g]
            start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
            lows.append(float((pos[2] + model.mesh_vert[start : start + count] @ rot[2]).min()))
        elif kind == mujoco.mjtGeom.mjGEOM_BOX:
            lows.append(float(pos[2] - np.abs(rot[2]) @ size))
        elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
            lows.append(float(pos[2] - size[0]))
        elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
            lows.append(float(pos[2] - size[1] * abs(axis_z) - size[0]))
        elif kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
            lows.append(float(pos[2] - size[1] * abs(axis_z) - size[0] * np.sqrt(max(0.0, 1 - axis_z**2))))
    return min(lows)
