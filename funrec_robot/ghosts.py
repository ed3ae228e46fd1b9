"""Ghosts of a moving part in the static scene: geoms that the part passes through within its own range.

A reconstructed twin fuses the static scene from every frame of the capture; where the part was not masked out
well (its handle, held open for seconds), a copy of it at that state stays in the static mesh. Such a geom lies
inside the part at some state of the range the part was seen to move through, which no solid can: the part
would have been stopped there. The planner treats these geoms as no obstacle (see ``plan``), and looks for them
only in a twin's fused scene (``scene.hull_approximated``): a true scene of primitive geoms has no copies of its
parts, and looking there took real furniture within ``GHOST_TOLERANCE_M`` of the part's sweep for ghosts (a
wardrobe's fixed door 2 cm beside the sliding one, robots21p).
"""

from __future__ import annotations

import mujoco
import numpy as np
import numpy.typing as npt
from scipy.spatial import ConvexHull, QhullError

from funrec.typed import FloatArray, IntArray
from funrec_robot.scene import box_corners, floor_geoms, geom_boxes, part_geoms, robot_bodies

GHOST_TOLERANCE_M = 0.025
"""A point of a static geom counts as inside the part when it lies within this distance outside the part's
collision hull at some state, m: a twin fuses its static scene on a 1 cm voxel grid and its parts on a 5 mm one
(funrec's ``FusionConfig.static_voxel_m``, ``part_voxel_m``), so a copy of the part's surface in the static
scene sits up to a voxel of each off the part (on the r16 twins a copy of a handle at its held state lay 3 mm
outside the part's hull and 10 mm from the contact point); and the copy was fused where the true part was,
while the twin's joint sweeps the part about a centimetre elsewhere (pivots 0-1.2 cm off on the bench twins).
At 15 mm the copies of the fridge door's handle at its held state, 9-16 mm outside its hull on the twin of
``plain_rev_fridge_00`` (pivot 1.2 cm off), stayed obstacles the hand could not pass (the IK 2 cm off the
handle path). The price, in a twin: real furniture within this distance of the part's sweep counts as a ghost of
it (the planner does not look for ghosts in a true scene); a contact with such a geom still fails the check."""
GHOST_FRACTION = 0.9
"""A static geom is a ghost when at least this share of its vertices lie inside the part (as above) at some
state: a geom of real furniture next to the part (a carcass side the door's edge grazes) has most of its
vertices outside the part's sweep."""


def _mesh_vertices(model: mujoco.MjModel, geom: int) -> FloatArray | None:
    """(V, 3) vertices of a mesh geom in its own frame; None for a primitive."""
    if model.geom_type[geom] != mujoco.mjtGeom.mjGEOM_MESH:
        return None
    mesh = int(model.geom_dataid[geom])
    start, count = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
    return np.asarray(model.mesh_vert[start : start + count], dtype=np.float64)


def _hull_halfspaces(model: mujoco.MjModel, geom: int) -> FloatArray:
    """(F, 4) halfspaces ``n . p + d <= 0`` of a geom's collision hull in its own frame (its box for a
    primitive, the convex hull of its vertices for a mesh: MuJoCo collides a mesh as its hull)."""
    vertices = _mesh_vertices(model, geom)
    if vertices is not None:
        try:
            return np.asarray(ConvexHull(vertices).equations, dtype=np.float64)
        except QhullError:  # a flat or degenerate piece: its box
            pass
    centre, half = model.geom_aabb[geom, :3], model.geom_aabb[geom, 3:]
    normals = np.vstack([np.eye(3), -np.eye(3)])
    return np.column_stack([normals, -(normals @ centre) - np.concatenate([half, half])])


def _geom_points(model: mujoco.MjModel, data: mujoco.MjData, geom: int) -> FloatArray:
    """(P, 3) world points that span a geom: a mesh's vertices, a primitive's box corners."""
    vertices = _mesh_vertices(model, geom)
    if vertices is None:
        return box_corners(*geom_boxes(model, data, [geom]))[0]
    return data.geom_xpos[geom] + vertices @ data.geom_xmat[geom].reshape(3, 3).T


def part_ghosts(
    model: mujoco.MjModel,
    joint: int,
    states: npt.ArrayLike,
    p_world_contact: npt.ArrayLike,
    tolerance: float = GHOST_TOLERANCE_M,
    fraction: float = GHOST_FRACTION,
) -> IntArray:
    """Static geoms that lie inside a part at some of its states, or hold its handle.

    A geom is a ghost when ``fraction`` of its vertices lie inside the part's collision hulls (each at some state),
    or when its hull holds the handle's contact point at some state (the demonstrator's hand held the handle
    there), both within ``tolerance``.

    Args:
        model: compiled scene (with or without a robot).
        joint: the part's scene joint.
        states: (S,) states the part was seen to move through (its range), rad or m.
        p_world_contact: (3,) the handle's contact point at state 0, world, m.
        tolerance: a point within this distance outside a hull counts as inside, m.
        fraction: share of a geom's vertices that must be inside the part for it to be a ghost.

    Returns:
        (k,) ids of the ghost geoms (colliding geoms of neither the robot, the part, nor the floor), ascending.
    """
    moving = part_geoms(model, joint)
    moving = moving[(model.geom_contype[moving] != 0) | (model.geom_conaffinity[moving] != 0)]
    collides = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
    others = np.flatnonzero(collides & ~np.isin(model.geom_bodyid, robot_bodies(model)))
    others = np.setdiff1d(others, moving)
    others = others[model.geom_type[others] != mujoco.mjtGeom.mjGEOM_PLANE]
    others = np.setdiff1d(others, floor_geoms(model, others))
    if not len(moving) or not len(others):
        return np.zeros(0, dtype=np.int64)
    data = mujoco.MjData(model)
    body = int(model.jnt_bodyid[joint])
    qadr = model.jnt_qposadr[joint]
    states = np.atleast_1d(np.asarray(states, dtype=np.float64))
    data.qpos[:] = model.qpos0
    data.qpos[qadr] = 0.0
    mujoco.mj_kinematics(model, data)
    p_body_contact = data.xmat[body].reshape(3, 3).T @ (np.asarray(p_world_contact, dtype=np.float64) - data.xpos[body])
    # The part's boxes at each state, and the box round them all: only static geoms that meet it can be ghosts.
    swept = []
    for state in states:
        data.qpos[qadr] = state
        mujoco.mj_kinematics(model, data)
        centre, R, half = geom_boxes(model, data, moving)
        extent = np.einsum("kij,kj->ki", np.abs(R), half) + tolerance
        contact = data.xpos[body] + data.xmat[body].reshape(3, 3) @ p_body_contact
        swept.append((centre, extent, data.geom_xpos[moving].copy(), data.geom_xmat[moving].reshape(-1, 3, 3).copy(), contact))
    low = np.min([np.min(c - e, axis=0) for c, e, *_ in swept], axis=0)
    high = np.max([np.max(c + e, axis=0) for c, e, *_ in swept], axis=0)
    data.qpos[:] = model.qpos0
    mujoco.mj_kinematics(model, data)
    centre, R, half = geom_boxes(model, data, others)
    extent = np.einsum("kij,kj->ki", np.abs(R), half)
    near_part = np.all((centre - extent <= high) & (centre + extent >= low), axis=1)
    others, centre, extent = others[near_part], centre[near_part], extent[near_part] + tolerance
    if not len(others):
        return np.zeros(0, dtype=np.int64)
    points = [_geom_points(model, data, int(g)) for g in others]
    owner = np.repeat(np.arange(len(others)), [len(p) for p in points])
    first = np.concatenate([[0], np.cumsum([len(p) for p in points])])
    points = np.vstack(points)
    halfspaces = [_hull_halfspaces(model, int(g)) for g in moving]
    inside = np.zeros(len(points), dtype=bool)
    holds = np.zeros(len(others), dtype=bool)
    planes_of: dict[int, FloatArray] = {}
    for p_centre, p_extent, xpos, xmat, contact in swept:
        # The handle's contact point at this state inside a static geom's hull.
        for k in np.flatnonzero(~holds & np.all(np.abs(contact - centre) <= extent, axis=1)):
            if k not in planes_of:
                planes_of[k] = _hull_halfspaces(model, int(others[k]))
            planes = planes_of[k]
            local = data.geom_xmat[others[k]].reshape(3, 3).T @ (contact - data.geom_xpos[others[k]])
            holds[k] = np.max(planes[:, :3] @ local + planes[:, 3]) <= tolerance
        # Static vertices inside the part's hulls at this state: of the geoms whose boxes meet the box round the
        # part, then within each piece's box, then inside its hull.
        low, high = (p_centre - p_extent).min(axis=0), (p_centre + p_extent).max(axis=0)
        meet = np.flatnonzero(np.all((centre - extent <= high) & (centre + extent >= low), axis=1))
        if not len(meet):
            continue
        todo = np.concatenate([np.arange(first[k], first[k + 1]) for k in meet])
        todo = todo[~inside[todo]]
        for k, planes in enumerate(halfspaces):
            if not len(todo):
                break
            near = todo[np.all(np.abs(points[todo] - p_centre[k]) <= p_extent[k], axis=1)]
            if not len(near):
                continue
            local = (points[near] - xpos[k]) @ xmat[k]  # p_geom = R^T (p_world - x)
            hit = near[np.max(local @ planes[:, :3].T + planes[:, 3], axis=1) <= tolerance]
            inside[hit] = True
            todo = np.setdiff1d(todo, hit, assume_unique=True)
    share = np.bincount(owner, weights=inside, minlength=len(others)) / np.bincount(owner, minlength=len(others))
    return others[(share >= fraction) | holds]


def range_states(model: mujoco.MjModel, joint: int, state_range: tuple[float, float], tolerance: float = GHOST_TOLERANCE_M) -> FloatArray:
    """(S,) states across a part's range, close enough that no point of the part moves more than twice
    ``tolerance`` between two (a point it passes through then lies within ``tolerance`` of it at a sample), and
    the range's ends.

    A revolute part's step is ``2 tolerance / r`` with r the farthest corner of its geoms' boxes from the hinge
    (2.2 degrees for a 0.52 m door at 1 cm)."""
    low, high = (float(v) for v in state_range)
    step = 2.0 * tolerance
    if model.jnt_type[joint] == mujoco.mjtJoint.mjJNT_HINGE:
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        body = int(model.jnt_bodyid[joint])
        axis = data.xmat[body].reshape(3, 3) @ model.jnt_axis[joint]
        anchor = data.xpos[body] + data.xmat[body].reshape(3, 3) @ model.jnt_pos[joint]
        geoms = part_geoms(model, joint)
        corners = box_corners(*geom_boxes(model, data, geoms)).reshape(-1, 3) - anchor
        radius = float(np.max(np.linalg.norm(np.cross(axis, corners), axis=1))) if len(geoms) else 1.0
        step = 2.0 * tolerance / max(radius, 2.0 * tolerance)
    return np.linspace(low, high, max(2, int(np.ceil((high - low) / step)) + 1))


def without_geoms(model: mujoco.MjModel, geoms: npt.ArrayLike) -> mujoco.MjModel:
    """A copy of ``model`` in which ``geoms`` collide with nothing (the caller's model is left as it is)."""
    geoms = np.asarray(geoms, dtype=np.int64)
    if not len(geoms):
        return model
    out = mujoco.MjModel.__copy__(model)
    out.geom_contype[geoms] = 0
    out.geom_conaffinity[geoms] = 0
    return out


__all__ = ["GHOST_FRACTION", "GHOST_TOLERANCE_M", "part_ghosts", "range_states", "without_geoms"]
