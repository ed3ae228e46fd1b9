"""What the planner needs to know about a MuJoCo scene: part joints and geoms, the front and handle of a part,
and floor footprints (convex polygons) of the furniture and of a part's swept volume.

All functions read a compiled model that holds the scene (alone or with a robot from ``build_mujoco_model``);
geometry is taken from each geom's bounding box in its own frame (``geom_aabb``), which for the boxes,
panels and bars of FunREC scenes is the geom itself.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import numpy.typing as npt
from scipy.spatial import ConvexHull

from funrec.errors import PlanningError
from funrec.typed import FloatArray, IntArray
from funrec_robot.errors import format_names
from funrec_robot.sim_model import ROBOT_PREFIX

FLOOR_TOP_M = 0.02
"""Geoms whose top is below this height are the floor: never obstacles for the base, m."""
STANDING_BELOW_M = 1.8
"""A twin's static piece whose bottom lies below this height is taken to stand on the floor when the base is placed,
m: a capture sees the tops of a room (worktops, a wall above them) and often not what stands under them. The
twin of light_harsh_rev_wall_00 holds nothing below 0.76 m, that of plain_pri_wardrobe_00 no side wall below
0.79 m, and robots placed clear of what they hold stood in the true lower cabinets and wall at t = 0. Wall
cabinets hang from 1.3-1.5 m over lower ones deeper than they are; ceilings lie higher (2.6 m on the bench)."""
HANDLE_CONTAINS_M = 0.005
"""A geom is part of the handle if the contact point lies within this distance of its box, m."""
HANDLE_ELONGATION = 2.0
"""A handle whose longest side (across the approach) is at least this many times its next is a bar."""
PANEL_THICKNESS_M = 0.05
"""Largest half-thickness of a geom taken as the part's front panel, m."""
PANEL_MIN_SIDE_M = 0.03
"""Smallest half-size of a front panel across its thickness, m (a shallow drawer front is about 0.07)."""
BEHIND_REACH_M = 0.045
"""Geoms of the part behind the handle within this lateral distance of the contact point can meet the
fingertips (a finger's reach across the approach), m."""
PANEL_MARGIN_M = 0.01
"""How far outside a panel's face the contact point may project and still face that panel, m."""
POLYGON_INFLATE_M = 0.001
"""Every footprint box is grown by this much so that a flat geom still has an area, m."""


@dataclass(frozen=True)
class Polygon:
    """A convex polygon on the floor (z = 0 plane of the world frame)."""

    name: str
    """Where it comes from: geom name, or ``<geom>@sweep`` for a part's swept volume."""
    vertices: FloatArray
    """(M, 2) vertices, counter-clockwise, m."""
    A: FloatArray
    """(M, 2) outward unit normals of the edges: inside is ``A @ p <= b``."""
    b: FloatArray
    """(M,) edge offsets, m."""
    z_band: tuple[float, float] = (-np.inf, np.inf)
    """(low, high) heights of the solid whose footprint this is, m."""

    def lower_distance(self, p_xy: npt.ArrayLike) -> FloatArray:
        """(N,) max over edges of ``A p - b``: negative inside, and outside a lower bound of the distance."""
        p = np.atleast_2d(np.asarray(p_xy, dtype=np.float64))
        return np.max(p @ self.A.T - self.b, axis=1)


def lower_distances(polygons: Sequence[Polygon], p_xy: npt.ArrayLike) -> FloatArray:
    """(N, P) :meth:`Polygon.lower_distance` of N points to each of P polygons at once: one product over every
    edge, then the largest of each polygon's run of edges. Base placement asks it of hundreds of footprints for
    each stop it poses; one polygon at a time, that took a tenth of the placement."""
    p = np.atleast_2d(np.asarray(p_xy, dtype=np.float64))
    if not polygons:
        return np.empty((len(p), 0))
    A = np.vstack([polygon.A for polygon in polygons])
    b = np.concatenate([polygon.b for polygon in polygons])
    starts = np.cumsum([0] + [len(polygon.b) for polygon in polygons[:-1]])
    return np.maximum.reduceat(p @ A.T - b, starts, axis=1)


@dataclass(frozen=True)
class PartFront:
    """The front of an articulated part around its handle, at the part's canonical state."""

    normal_world: FloatArray
    """(3,) unit outward normal of the front panel (pointing from the panel towards the handle)."""
    standoff: float
    """Distance from the contact point, against the normal, to the nearest geom of the part behind the handle
    (the panel's face, or a backplate), m."""
    handle_axis_world: FloatArray | None
    """(3,) long axis of the handle bar across the normal; None for a knob or an unidentified handle."""
    panel_geom: str
    """Name of the geom taken as the front panel."""
    handle_geoms: tuple[str, ...]
    """Names of the geoms taken as the handle."""
    handle_width: float | None
    """Thickness of the handle across its long axis and the normal (a bar), or its largest size (a knob), m;
    None if no handle geom was identified."""
    handle_depth: float | None
    """Extent of the handle along the normal, m; None if no handle geom was identified."""
    handle_extent: tuple[float, float] | None = None
    """Where a bar ends either way of the contact point along ``handle_axis_world``: (below 0, above 0), m; None
    for a knob or an unidentified handle."""


def _name(model: mujoco.MjModel, kind: mujoco.mjtObj, index: int) -> str:
    return mujoco.mj_id2name(model, kind, index) or f"#{index}"


def part_joint(model: mujoco.MjModel, part: str) -> int:
    """Id of the scene joint named ``part``.

    Raises:
        PlanningError: no such joint; lists the scene's hinge and slide joints.
    """
    joint = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, part)
    if joint < 0:
        valid = [
            _name(model, mujoco.mjtObj.mjOBJ_JOINT, j)
            for j in range(model.njnt)
            if not _name(model, mujoco.mjtObj.mjOBJ_JOINT, j).startswith(ROBOT_PREFIX)
            and model.jnt_type[j] in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)
        ]
        raise PlanningError(f"scene has no joint '{part}'; articulated joints: {format_names(valid)}")
    return joint


def subtree_bodies(model: mujoco.MjModel, body: int) -> IntArray:
    """(k,) ids of ``body`` and all its descendants."""
    inside = np.zeros(model.nbody, dtype=bool)
    inside[body] = True
    for b in range(body + 1, model.nbody):  # MuJoCo numbers children after their parents
        inside[b] = inside[model.body_parentid[b]]
    return np.flatnonzero(inside)


def bodies_geoms(model: mujoco.MjModel, bodies: npt.ArrayLike) -> IntArray:
    """(k,) ids of the geoms attached to any of ``bodies``."""
    return np.flatnonzero(np.isin(model.geom_bodyid, np.asarray(bodies)))


def part_geoms(model: mujoco.MjModel, joint: int) -> IntArray:
    """(k,) geoms that move with a scene joint (the subtree of its body)."""
    return bodies_geoms(model, subtree_bodies(model, int(model.jnt_bodyid[joint])))


def robot_bodies(model: mujoco.MjModel) -> IntArray:
    """(k,) bodies whose name carries the robot prefix of ``build_mujoco_model``."""
    return np.array(
        [b for b in range(model.nbody) if _name(model, mujoco.mjtObj.mjOBJ_BODY, b).startswith(ROBOT_PREFIX)],
        dtype=np.int64,
    )


def geom_boxes(model: mujoco.MjModel, data: mujoco.MjData, geoms: npt.ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Oriented boxes of geoms at the pose in ``data`` (after forward kinematics).

    Returns:
        centre (k, 3) world, R (k, 3, 3) world-from-box rotations, half (k, 3) half sizes, m.
    """
    geoms = np.asarray(geoms, dtype=np.int64)
    R = data.geom_xmat[geoms].reshape(-1, 3, 3)
    aabb = model.geom_aabb[geoms]
    centre = data.geom_xpos[geoms] + np.einsum("kij,kj->ki", R, aabb[:, :3])
    return centre, R, aabb[:, 3:].copy()


def box_corners(centre: FloatArray, R: FloatArray, half: FloatArray) -> FloatArray:
    """(k, 8, 3) corners of the oriented boxes of :func:`geom_boxes`."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
    return centre[:, None, :] + np.einsum("kij,kmj->kmi", R, signs[None] * half[:, None, :])


def polygon_from_points(
    name: str, points_xy: npt.ArrayLike, z_band: tuple[float, float] = (-np.inf, np.inf)
) -> Polygon:
    """Convex hull of (N, 2) floor points as a :class:`Polygon` of a solid between the heights ``z_band``."""
    hull = ConvexHull(np.asarray(points_xy, dtype=np.float64))
    return Polygon(
        name=name,
        vertices=hull.points[hull.vertices],
        A=hull.equations[:, :2].copy(),
        b=-hull.equations[:, 2].copy(),
        z_band=(float(z_band[0]), float(z_band[1])),
    )


def _footprints(
    corners: FloatArray, names: list[str], z_band: tuple[float, float], standing: bool = False
) -> list[Polygon]:
    out = []
    for corner, name in zip(corners, names):
        z_min, z_max = corner[:, 2].min(), corner[:, 2].max()
        if standing and z_max >= FLOOR_TOP_M and z_min < STANDING_BELOW_M:
            z_min = 0.0
        if z_max < max(z_band[0], FLOOR_TOP_M) or z_min > z_band[1]:
            continue
        out.append(polygon_from_points(name, corner[:, :2], (z_min, z_max)))
    return out


def _colliding(model: mujoco.MjModel, geoms: npt.ArrayLike) -> IntArray:
    """Those of ``geoms`` that take part in collisions: a twin's display mesh of the whole room
    (contype = conaffinity = 0) would otherwise make one footprint covering the floor."""
    geoms = np.asarray(geoms, dtype=np.int64)
    return geoms[(model.geom_contype[geoms] != 0) | (model.geom_conaffinity[geoms] != 0)]


def _posed_data(model: mujoco.MjModel, qpos: npt.ArrayLike | None = None) -> mujoco.MjData:
    data = mujoco.MjData(model)
    if qpos is not None:
        data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    return data


def gravity_load(model: mujoco.MjModel, data: mujoco.MjData, qpos: npt.ArrayLike) -> FloatArray:
    """(nv,) generalised force that holding the model still at ``qpos`` takes against gravity: ``qfrc_bias``
    of ``mj_rne`` at zero velocity (a view into ``data``, which it overwrites)."""
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    mujoco.mj_rne(model, data, 0, data.qfrc_bias)
    return data.qfrc_bias


def spring_load(model: mujoco.MjModel, qpos: npt.ArrayLike, dofs: npt.ArrayLike) -> FloatArray:
    """(n,) generalised force that holding the hinge or slide joints of ``dofs`` still at ``qpos`` takes against
    their own springs (``stiffness`` in the model, towards ``springref``), N or N m: a servo carries it in full,
    gravity compensation or not (Fetch's file springs its forearm roll at 10 N m/rad)."""
    dofs = np.asarray(dofs, dtype=np.int64)
    joints = model.dof_jntid[dofs]
    adr = model.jnt_qposadr[joints]
    return model.jnt_stiffness[joints] * (np.asarray(qpos, dtype=np.float64)[adr] - model.qpos_spring[adr])


def static_footprint(
    model: mujoco.MjModel,
    exclude_geoms: npt.ArrayLike,
    z_band: tuple[float, float],
    centre_xy: npt.ArrayLike,
    radius: float,
    qpos: npt.ArrayLike | None = None,
    standing: bool = False,
) -> tuple[Polygon, ...]:
    """Floor footprints of the scene's geoms near a point.

    Args:
        model: compiled scene (with or without a robot).
        exclude_geoms: geoms to leave out (the robot's, the moving part's).
        z_band: (low, high) heights; only geoms overlapping this band are kept (the robot's body height), m.
        centre_xy: (2,) centre of the region of interest, world, m.
        radius: geoms whose box lies entirely farther than this from the centre are dropped, m.
        qpos: model configuration to read the scene at (default the reference configuration).
        standing: every geom whose bottom lies below ``STANDING_BELOW_M`` is taken to reach down to the floor
            (a twin: what the capture saw of a room is the top of what stands under it).

    Returns:
        One convex polygon per kept geom (its box's projection).
    """
    data = _posed_data(model, qpos)
    keep = np.setdiff1d(np.arange(model.ngeom), np.asarray(exclude_geoms, dtype=np.int64))
    keep = _colliding(model, keep[model.geom_type[keep] != mujoco.mjtGeom.mjGEOM_PLANE])
    centre, R, half = geom_boxes(model, data, keep)
    reach = np.linalg.norm(half, axis=1)
    near = np.linalg.norm(centre[:, :2] - np.asarray(centre_xy), axis=1) - reach < radius
    keep, centre, R, half = keep[near], centre[near], R[near], half[near]
    corners = box_corners(centre, R, half + POLYGON_INFLATE_M)
    names = [_name(model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in keep]
    return tuple(_footprints(corners, names, z_band, standing))


def part_sweep_footprint(
    model: mujoco.MjModel, joint: int, states: npt.ArrayLike, z_band: tuple[float, float]
) -> tuple[Polygon, ...]:
    """Floor footprints of the volume a part sweeps between states: per geom, the hull of its boxes at the states.

    A revolute leaf sweeps a sector (convex for less than half a turn); the hull of its sampled boxes misses
    only the sagitta between samples, a few mm for the 4-degree spacing of the planner's paths.
    """
    geoms = _colliding(model, part_geoms(model, joint))
    qadr = model.jnt_qposadr[joint]
    data = mujoco.MjData(model)
    per_geom: list[list[FloatArray]] = [[] for _ in geoms]
    bands = np.tile([np.inf, -np.inf], (len(geoms), 1))
    for state in np.atleast_1d(np.asarray(states, dtype=np.float64)):
        data.qpos[:] = model.qpos0
        data.qpos[qadr] = state
        mujoco.mj_kinematics(model, data)
        centre, R, half = geom_boxes(model, data, geoms)
        corners = box_corners(centre, R, half + POLYGON_INFLATE_M)
        for k, corner in enumerate(corners):
            if corner[:, 2].max() < max(z_band[0], FLOOR_TOP_M) or corner[:, 2].min() > z_band[1]:
                continue
            per_geom[k].append(corner[:, :2])
            bands[k] = min(bands[k, 0], corner[:, 2].min()), max(bands[k, 1], corner[:, 2].max())
    out = []
    for g, pieces, band in zip(geoms, per_geom, bands):
        if pieces:
            name = f"{_name(model, mujoco.mjtObj.mjOBJ_GEOM, g)}@sweep"
            out.append(polygon_from_points(name, np.vstack(pieces), (band[0], band[1])))
    return tuple(out)


def part_travel(model: mujoco.MjModel, joint: int, states: npt.ArrayLike) -> FloatArray:
    """(S - 1,) how far any corner of the part's colliding boxes moves between consecutive states (straight
    line, the chord of a turning door's arc), m."""
    geoms = _colliding(model, part_geoms(model, joint))
    data = mujoco.MjData(model)
    corners = []
    for state in np.atleast_1d(np.asarray(states, dtype=np.float64)):
        data.qpos[:] = model.qpos0
        data.qpos[model.jnt_qposadr[joint]] = state
        mujoco.mj_kinematics(model, data)
        corners.append(box_corners(*geom_boxes(model, data, geoms)).reshape(-1, 3))
    if len(corners) < 2 or not len(geoms):
        return np.zeros(max(len(corners) - 1, 0))
    stacked = np.array(corners)
    return np.linalg.norm(np.diff(stacked, axis=0), axis=2).max(axis=1)


def _front_face(
    p_box: FloatArray, half: FloatArray, low: FloatArray, high: FloatArray, candidates: npt.NDArray[np.bool_], thin_only: bool
) -> tuple[float, int, int] | None:
    """(gap, box, axis) of the box face behind the contact point (``p_box``: in each box's frame) among the
    ``candidates``, whose extent across the face overlaps [``low``, ``high``] (per box, in its frame; the contact
    point itself, or the handle's boxes) within ``PANEL_MARGIN_M``: the one the contact point projects onto
    best, then the nearest; with ``thin_only``, only the big face of a thin panel (half-thickness below
    ``PANEL_THICKNESS_M``)."""
    best: tuple[tuple[float, float], int, int] | None = None
    for k in np.flatnonzero(candidates):
        for axis in ([int(np.argmin(half[k]))] if thin_only else range(3)):
            others = [a for a in range(3) if a != axis]
            if thin_only and (half[k, axis] > PANEL_THICKNESS_M or np.min(half[k, others]) < max(PANEL_MIN_SIDE_M, 3.0 * half[k, axis])):
                continue
            if np.any(low[k, others] > half[k, others] + PANEL_MARGIN_M) or np.any(high[k, others] < -half[k, others] - PANEL_MARGIN_M):
                continue
            gap = abs(float(p_box[k, axis])) - half[k, axis]
            # How far the contact point's projection falls outside the face (0 within the margin) comes first:
            # a handle on posts overlaps the panel's edge face as well as its front.
            excess = float(np.linalg.norm(np.maximum(np.abs(p_box[k, others]) - half[k, others] - PANEL_MARGIN_M, 0.0)))
            if gap > 0.0 and (best is None or (excess, gap) < best[0]):
                best = ((excess, gap), int(k), axis)
    return None if best is None else (best[0][1], best[1], best[2])


def part_front(model: mujoco.MjModel, joint: int, p_world_contact: npt.ArrayLike) -> PartFront:
    """Outward normal, handle standoff and handle axis of a part, from its geoms at the canonical state.

    The front panel is the thin geom of the part (half-thickness below ``PANEL_THICKNESS_M``) whose face the
    contact point projects onto and lies nearest in front of; the handle is the geoms whose boxes contain
    the contact point. Where no thin panel is so, the face of any other geom of the part that lies nearest
    behind the contact point and that the handle's boxes overlap (a handle reaching past a panel's edge, a
    front that is one face of a thick body).

    Raises:
        PlanningError: no panel of the part faces the contact point.
    """
    p = np.asarray(p_world_contact, dtype=np.float64)
    geoms = part_geoms(model, joint)
    qpos = model.qpos0.copy()
    data = _posed_data(model, qpos)
    centre, R, half = geom_boxes(model, data, geoms)
    p_box = np.einsum("kji,kj->ki", R, p - centre)  # R^T (p - c): contact point in each box's frame
    outside = np.maximum(np.abs(p_box) - half, 0.0)
    in_handle = np.linalg.norm(outside, axis=1) <= HANDLE_CONTAINS_M
    everything = np.ones(len(geoms), dtype=bool)
    best = _front_face(p_box, half, p_box, p_box, everything, thin_only=True)
    if best is None and np.any(in_handle):
        # A handle that reaches past the panel's edge (Meta-World's door) or a front that is the face of a thick
        # geom (Meta-World's drawer is one box): the face nearest behind the contact point that the handle's
        # boxes overlap.
        corners = box_corners(centre[in_handle], R[in_handle], half[in_handle]).reshape(-1, 3)
        local = np.einsum("kji,kmj->kmi", R, corners[None, :, :] - centre[:, None, :])
        best = _front_face(p_box, half, local.min(axis=1), local.max(axis=1), ~in_handle, thin_only=False)
    if best is None:
        raise PlanningError(
            f"part '{_name(model, mujoco.mjtObj.mjOBJ_JOINT, joint)}': no front panel of the part faces the "
            f"contact point {np.round(p, 3).tolist()}; geoms: "
            f"{format_names(_name(model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in geoms)}"
        )
    _, panel, face = best
    normal = np.sign(p_box[panel, face]) * R[panel][:, face]
    in_handle[panel] = False
    handle_axis, width, depth, extent = None, None, None, None
    if np.any(in_handle):
        k = int(np.flatnonzero(in_handle)[np.argmin(np.prod(half[in_handle], axis=1))])  # the smallest: the bar
        across = [(half[k, a], R[k][:, a]) for a in range(3) if abs(float(R[k][:, a] @ normal)) < 0.7]
        across.sort(key=lambda item: -item[0])
        width = 2.0 * float(np.max(half[k]))
        depth = 2.0 * float(np.sum(np.abs(R[k].T @ normal) * half[k]))
        if len(across) == 2 and across[0][0] >= HANDLE_ELONGATION * across[1][0]:
            axis = across[0][1] - normal * float(across[0][1] @ normal)
            handle_axis = axis / np.linalg.norm(axis)
            width = 2.0 * float(across[1][0])
            along = float((p - centre[k]) @ handle_axis)
            extent = (-float(across[0][0]) - along, float(across[0][0]) - along)
    # The standoff is the gap to whatever of the part lies behind the handle within a gripper's reach
    # across the approach (the front panel, a backplate, the posts of a bar); a geom no wider than the
    # handle (a knob's stem) passes between the fingers.
    handle_size = 0.0 if width is None else width / 2.0
    u1 = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u1 /= np.linalg.norm(u1)
    lateral_axes = np.stack([u1, np.cross(normal, u1)])
    standoff = np.inf
    for k in np.flatnonzero(~in_handle):
        corners = box_corners(centre[k : k + 1], R[k : k + 1], half[k : k + 1])[0] - p
        gap = -float((corners @ normal).max())  # the handle is in front (+normal) of what lies behind it
        if gap < 0.0:
            continue
        lateral = corners @ lateral_axes.T
        lo, hi = lateral.min(axis=0), lateral.max(axis=0)
        if np.max(hi - lo) / 2.0 <= handle_size:
            continue
        if np.all(lo <= BEHIND_REACH_M) and np.all(hi >= -BEHIND_REACH_M):
            standoff = min(standoff, gap)
    return PartFront(
        normal_world=normal,
        standoff=float(standoff),
        handle_axis_world=handle_axis,
        panel_geom=_name(model, mujoco.mjtObj.mjOBJ_GEOM, geoms[panel]),
        handle_geoms=tuple(_name(model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in geoms[in_handle]),
        handle_width=width,
        handle_depth=depth,
        handle_extent=extent,
    )


def geoms_near(
    model: mujoco.MjModel, data: mujoco.MjData, geoms: npt.ArrayLike, points: npt.ArrayLike, radius: float
) -> IntArray:
    """(k,) the geoms whose boxes come within ``radius`` of any of the (N, 3) world points."""
    geoms = np.asarray(geoms, dtype=np.int64)
    centre, R, half = geom_boxes(model, data, geoms)
    points = np.atleast_2d(np.asarray(points, dtype=np.float64))
    local = np.einsum("kji,knj->kni", R, points[None, :, :] - centre[:, None, :])
    outside = np.maximum(np.abs(local) - half[:, None, :], 0.0)
    distance = np.linalg.norm(outside, axis=2).min(axis=1)
    return geoms[distance <= radius]


def hull_approximated(model: mujoco.MjModel, joint: int) -> bool:
    """Whether a part's collision geoms approximate a display mesh of its own: its subtree holds a mesh geom that
    collides with nothing beside geoms that collide (a twin, FORMATS.md section 2: the fused mesh to show and
    convex pieces of it to collide), rather than being its exact shape (a scene of primitive geoms)."""
    geoms = part_geoms(model, joint)
    shown = (model.geom_contype[geoms] == 0) & (model.geom_conaffinity[geoms] == 0)
    return bool(np.any(shown & (model.geom_type[geoms] == mujoco.mjtGeom.mjGEOM_MESH)) and np.any(~shown))


def floor_geoms(model: mujoco.MjModel, geoms: npt.ArrayLike) -> IntArray:
    """(k,) those of ``geoms`` that lie below ``FLOOR_TOP_M`` at the reference configuration (the floor)."""
    geoms = np.asarray(geoms, dtype=np.int64)
    data = _posed_data(model)
    centre, R, half = geom_boxes(model, data, geoms)
    top = centre[:, 2] + np.abs(R[:, 2, :] * half).sum(axis=1)
    plane = model.geom_type[geoms] == mujoco.mjtGeom.mjGEOM_PLANE
    return geoms[(top <= FLOOR_TOP_M) | plane]


__all__ = [
    "FLOOR_TOP_M",
    "PartFront",
    "Polygon",
    "bodies_geoms",
    "box_corners",
    "floor_geoms",
    "geom_boxes",
    "geoms_near",
    "gravity_load",
    "hull_approximated",
    "lower_distances",
    "part_front",
    "part_geoms",
    "part_joint",
    "part_sweep_footprint",
    "part_travel",
    "polygon_from_points",
    "robot_bodies",
    "static_footprint",
    "subtree_bodies",
]
