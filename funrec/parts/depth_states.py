"""Joint states of a part in every frame from depth: a 1-DoF search along its known joint.

A part's tracks die where a door turns edge-on to the camera, so the tracked states stop at a
fraction of the opening. With the joint known, one number per frame remains: the state whose
posed part points best explain the frame's depth. A chain of per-frame state grids, solved by
dynamic programming with a bounded speed, keeps the sequence continuous where depth alone is
ambiguous (points out of view or behind the hand). Points with a known outward normal that face
away from the camera are scored as the hidden face of a thin panel (a door leaf, a drawer front).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from funrec.camera.tracking import CameraTrajectory
from funrec.formats.capture import Capture
from funrec.geometry.joints import joint_transforms
from funrec.geometry.transforms import invert_transform
from funrec.parallel import in_order
from funrec.typed import BoolArray, FloatArray, IntArray

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class DepthStateConfig:
    """Settings of :func:`depth_states`; lengths in metres, angles in radians."""

    enabled: bool = True
    """Search the states of untracked frames in depth (off: keep the tracked interval only)."""
    revolute_step_rad: float = np.deg2rad(0.5)
    """Grid step of revolute states: 0.5 deg moves a point 45 cm from the hinge by 4 mm,
    about the depth noise at 1.5 m."""
    prismatic_step_m: float = 0.004
    """Grid step of prismatic states, metres (same 4 mm)."""
    revolute_limit_rad: float = np.deg2rad(135.0)
    """States are searched in [-limit, +limit] around the canonical state: furniture doors open
    by at most ~120 deg, oven doors by ~90 deg."""
    prismatic_limit_m: float = 0.9
    """Same for prismatic joints: drawers and wardrobe slides travel less than ~0.8 m."""
    max_speed_rad: float = np.deg2rad(12.0)
    """Largest state change between consecutive frames: a door flung open at ~180 deg/s seen
    at 15 fps (the bench's fastest doors turn by ~7 deg per frame)."""
    max_speed_m: float = 0.06
    """Largest prismatic change between consecutive frames (0.9 m/s at 15 fps)."""
    depth_tolerance_m: float = 0.03
    """A posed point agrees with the depth when within this distance along the ray: ~3 sigma of
    Kinect-like noise at 2 m, and a door leaf's thickness (a point of the outer face seen through
    the inner face once the door turned past edge-on)."""
    occluded_cost: float = 0.3
    """Cost of a point hidden behind observed surface (or outside the image), between a match (0)
    and a point seen through (1): a hidden point is neither evidence for nor against its state,
    but the state that makes the points visible and matched must win."""
    change_cost: float = 0.02
    """Cost per grid step of state change between consecutive frames, in units of the mean point
    cost (total variation: an opening pays it once whatever its speed profile, while a one-step
    wiggle at rest gains less than this from depth noise, measured ~0.01-0.03 per step)."""
    track_sigma_rad: float = np.deg2rad(2.0)
    """Standard deviation of a tracked state (revolute) in the chain's data term: tracked states
    are accurate to ~1 deg where their tracks are seen."""
    track_sigma_m: float = 0.01
    """Same for prismatic tracked states, metres."""
    depth_vetoes_tracks: bool = True
    """A trusted tracked state is not held where depth objects to it: every state within two ``track_sigma`` of it
    costs more than ``change_cost`` above the frame's best (depth sees the part elsewhere). Measured on the textured
    family's tracked parts of reseeds 2-5 (multi_kitchen_00, pri_drawer_02, rev_cabinet_left_00, rev_fridge_01, 14
    runs): of 986 tracked states within 3 deg (3 cm) of the truth 5 were vetoed (all in rev_fridge_01_r4), of 57 off
    by 5 deg (5 cm) or more 56 were (rev_cabinet_left_00_r5's tracks, 40 deg past the door, had excess 0.06-0.46).
    False: always held (ablation)."""
    min_points: int = 6
    """A frame whose depth sees fewer part points (inside the image with a reading) gives no
    depth evidence."""
    panel_thickness_m: tuple[float, float] = (0.008, 0.04)
    """A point whose normal faces away from the camera is on the far face of a panel this thick
    (door leaves and drawer fronts are 1.6-2.5 cm): its observed depth must be nearer by the
    panel's thickness along the ray (cost 0); observed within the lower bound of it, or farther,
    the panel is not there (cost 1); nearer than the upper bound, something else hides it
    (``occluded_cost``). Without this, an opened door's outer-face points matched its inner face
    and read the opening 4-6 deg short (measured on three bench doors at 70-86 deg)."""
    facing_cos: float = 0.1
    """A point faces away from the camera when the cosine between its normal and the viewing ray
    exceeds this; nearer to edge-on, the ordinary rule applies."""
    normal_radius_m: float = 0.2
    """Neighbourhood radius of the part points whose plane (PCA) gives a point's normal."""
    threads: int = 2
    """Frames scored at once, in threads (whole-array numpy releases the GIL, so a second core
    shares the work); the states do not depend on it. 1: one frame at a time."""


@dataclass(frozen=True)
class Arrival:
    """Surfaces that arrived in front of what a reference frame saw, as evidence for the state search.

    Points of a frame that the reference frame (the canonical state's) sees through stand where
    nothing stood then: the moved part. Moved back by the joint at the right state they lie on the
    reference frame's surface (the closed front); at a wrong state they float in front of it (seen
    through) or sink behind it (hidden). A part's own points can only say "hidden" once it moves
    where the camera cannot see it (a drawer pushed into its carcass costs ``occluded_cost``, as little as
    the drawer pulled out under an arm); the surface that arrived says where it went."""

    frames: IntArray
    """(A,) capture frames that have arrived points."""
    p_world: tuple[FloatArray, ...]
    """(N_a, 3) world points that arrived in each of ``frames``."""
    depth_m: FloatArray
    """(H, W) depth of the reference frame, metres (0 = no reading)."""
    K: FloatArray
    """(3, 3) intrinsics of ``depth_m``."""
    T_camera_world: FloatArray
    """(4, 4) pose of the reference camera."""
    weight: float = 0.5
    """Share of a frame's cost given to its arrived points (the part's own points keep the rest)."""


class DepthFit(NamedTuple):
    """A joint hypothesis scored on depth (:func:`depth_fit`)."""

    states: FloatArray
    """(F,) state of every frame along the least-cost chain."""
    cost: float
    """Mean point cost of the chain over the frames that see the part, in [0, 1] (NaN: none sees it)."""
    frame_costs: FloatArray
    """(F,) each frame's point cost at its chain state (NaN where the frame does not see the part)."""


def motion_costs(fits: Sequence[DepthFit], low: float = 0.1, high: float = 0.9) -> FloatArray:
    """Each fit's mean frame cost over the frames in which any of the ``fits`` is in mid-motion (its state's
    magnitude between ``low`` and ``high`` of its own largest), NaN where no frame is (or a fit sees none).

    These frames tell joints apart. At rest every hypothesis of a part agrees, and where the motion ended a
    wrong joint can land the surface on another one: a drawer's front turned down about its lower edge lies on
    the drawer's own floor once it is pulled out (light_dim_pri_drawer_00_r3: the turn 0.159, the true slide
    0.178 over all frames; in mid-motion 0.307 against 0.214). On the way there no surface holds it."""
    moving = np.zeros(len(fits[0].states), bool) if fits else np.zeros(0, bool)
    for fit in fits:
        magnitude = np.abs(fit.states)
        moving |= (magnitude > low * magnitude.max()) & (magnitude < high * magnitude.max())
    out = np.full(len(fits), np.nan)
    for k, fit in enumerate(fits):
        seen = moving & np.isfinite(fit.frame_costs)
        if seen.any():
            out[k] = float(fit.frame_costs[seen].mean())
    return out


def depth_states(
    capture: Capture,
    trajectory: CameraTrajectory,
    joint_type: str,
    axis_world: FloatArray,
    pivot_world: FloatArray | None,
    p_world: FloatArray,
    tracked_frames: IntArray,
    tracked_states: FloatArray,
    trusted: BoolArray,
    config: DepthStateConfig = DepthStateConfig(),  # noqa: B008 (frozen, immutable default)
    normal_world: FloatArray | None = None,
    arrival: Arrival | None = None,
    seen_states: tuple[IntArray, FloatArray] | None = None,
    rest_frames: int | None = None,
) -> FloatArray:
    """Joint state of every frame of the capture from its depth, consistent with the tracked states.

    Each frame scores a grid of states: the part points ``p_world`` (canonical state) are posed
    by the joint, projected into the frame, and compared with its depth along the ray (match:
    quadratic in the depth difference; seen through, i.e. observed depth farther: 1; hidden
    behind observed surface or outside the image: ``occluded_cost``). Trusted tracked frames add
    a Gaussian term around their tracked state. The least-cost chain of states with at most
    ``max_speed`` change per frame (and ``change_cost`` per step) is found by dynamic programming.

    Args:
        capture: the capture (depth read lazily, one frame at a time).
        trajectory: ``T_world_camera`` (F, 4, 4).
        joint_type: "revolute" or "prismatic".
        axis_world: (3,) unit axis. pivot_world: (3,) revolute axis point, None for prismatic.
        p_world: (M, 3) points of the part at its canonical state (state 0), world frame, metres.
        tracked_frames: (F_k,) frame indices with a tracked state.
        tracked_states: (F_k,) tracked states (rad or m), 0 at the canonical state.
        trusted: (F_k,) True where the tracked state is supported by tracks (not interpolated).
        config: settings.
        normal_world: (M, 3) outward unit normals of ``p_world`` at the canonical state (NaN where
            unknown; see :func:`oriented_normals`); None: no point is scored as a panel's far face.
        arrival: surfaces that arrived in front of the canonical frame's view (:class:`Arrival`),
            scored moved back by each state; None: the part's own points only.
        seen_states: (frames, states) another cue saw (the tracks of a slide whose axis depth
            replaced); each holds the search there as a trusted tracked state would, unless its
            depth objects: that state costs more than ``change_cost`` above the frame's best
            (depth sees the part elsewhere; the cue was on something else, e.g. the arm).
        rest_frames: the part rests at the canonical state from frame 0 until the first frame, at or after
            ``rest_frames``, whose depth objects to it (the canonical state costs more than ``change_cost``
            above the frame's best); those frames hold the search there as a trusted tracked state would,
            where their depth does not object. Frames before ``rest_frames`` (before the scene changed) may
            object without ending the rest. None: no rest is assumed.

    Returns:
        (F,) state of every capture frame (rad or m), same canonical state as ``tracked_states``.
    """
    return _search(capture, trajectory, joint_type, axis_world, pivot_world, p_world, tracked_frames, tracked_states,
                   trusted, config, normal_world, arrival, seen_states, rest_frames).states


def depth_fit(
    capture: Capture,
    trajectory: CameraTrajectory,
    joint_type: str,
    axis_world: FloatArray,
    pivot_world: FloatArray | None,
    p_world: FloatArray,
    config: DepthStateConfig = DepthStateConfig(),  # noqa: B008 (frozen, immutable default)
    arrival: Arrival | None = None,
    normal_world: FloatArray | None = None,
    rest_frames: int | None = None,
    still_frames: int = 0,
) -> DepthFit:
    """How well a joint hypothesis explains the depth of a capture, from depth alone.

    The same search as :func:`depth_states` without tracked states. The mean point cost (0: every
    posed point on the observed surface; 1: every point seen through) of the best state chain,
    averaged over the frames that see the part, compares two joint types fitted to the same part
    without any texture: a door turned by a slide leaves its points in the air.

    Args: as :func:`depth_states` (``p_world`` (M, 3) canonical part points, world frame; the mean
        cost includes the ``arrival`` term where given; ``normal_world`` scores points that face
        away from the camera as a panel's far face; ``rest_frames`` holds the part at rest as there).
        still_frames: frames before this one hold the canonical state whatever their depth says: the scene had not
            yet changed by as much as a part makes (see :func:`~funrec.parts.depth_proposal.propose_part`), so the
            part had not moved, and a cheaper state there is something else (an arm in front of a plain front
            flush with its neighbours, which a slide within the front's plane moves the points out from behind).

    Returns:
        The fit: (F,) state of every frame, the mean cost in [0, 1] (NaN when no frame sees
        ``config.min_points`` part points) and each frame's cost.
    """
    none = np.zeros(0, np.int64)
    return _search(capture, trajectory, joint_type, axis_world, pivot_world, p_world, none, np.zeros(0),
                   np.zeros(0, bool), config, normal_world, arrival, rest_frames=rest_frames,
                   still_frames=still_frames)


def _search(capture: Capture, trajectory: CameraTrajectory, joint_type: str, axis_world: FloatArray,
            pivot_world: FloatArray | None, p_world: FloatArray, tracked_frames: IntArray, tracked_states: FloatArray,
            trusted: BoolArray, config: DepthStateConfig, normal_world: FloatArray | None,
            arrival: Arrival | None = None, seen_states: tuple[IntArray, FloatArray] | None = None,
            rest_frames: int | None = None, still_frames: int = 0) -> DepthFit:
    """The states of :func:`depth_states` and the depth cost of the chain (mean over the frames that see the part)."""
    F = len(capture)
    revolute = joint_type == "revolute"
    grid, step = _state_grid(joint_type, config)
    T_grid = joint_transforms(joint_type, axis_world, pivot_world, grid)  # (G, 4, 4)
    R_grid_t = np.transpose(T_grid[:, :3, :3], (0, 2, 1))
    p_grid = p_world[None] @ R_grid_t + T_grid[:, None, :3, 3]  # (G, M, 3)
    p_rows = np.ascontiguousarray(np.moveaxis(p_grid, -1, 0))  # (3, G, M), once for every frame
    # the normals' x, y and z rows, as the points' (NaN stays NaN)
    n_rows = None if normal_world is None else np.ascontiguousarray(np.moveaxis(normal_world[None] @ R_grid_t, -1, 0))
    K = capture.intrinsics.K
    cost = np.zeros((F, len(grid)))
    seen = np.zeros(F, dtype=int)

    def frame_costs(frames: IntArray) -> None:  # each frame's own row: threads write apart
        for frame in frames:
            cost[frame], seen[frame] = _frame_cost(capture.depth_m(frame), K, invert_transform(trajectory.T_world_camera[frame]),
                                                   p_rows, n_rows, config)

    _in_threads(frame_costs, F, config.threads)
    seeing = seen >= config.min_points
    cost[~seeing] = 0.0
    if arrival is not None:
        _add_arrival(cost, seeing, T_grid, arrival, config)
    depth_only = cost.copy()
    sigma = config.track_sigma_rad if revolute else config.track_sigma_m
    held_frames, held_states = np.asarray(tracked_frames)[trusted], np.asarray(tracked_states)[trusted]
    if config.depth_vetoes_tracks and len(held_frames):
        # A tracked state is held only where depth does not object to every state within two sigmas of it: tracks that
        # slid off a door (onto the arm, or along its texture as it turned oblique) carried its states 40 deg past the
        # door, held there by a Gaussian that no depth cost outweighs (rev_cabinet_left_00_r5: 19.8 deg off).
        excess = _excess_near(depth_only[held_frames], grid, held_states, 2.0 * sigma)
        agree = ~seeing[held_frames] | (excess <= config.change_cost)
        if not agree.all():
            logger.info("depth states: depth objects to %d of %d tracked states (frames %s): not held", int((~agree).sum()),
                        len(agree), held_frames[~agree].tolist())
        held_frames, held_states = held_frames[agree], held_states[agree]
    _hold(cost, grid, held_frames, held_states, sigma)
    if seen_states is not None:
        # held as tracked states, where depth does not object (the state within change_cost of the frame's best)
        frames, seen = (np.asarray(a) for a in seen_states)
        nearest = np.abs(grid[None, :] - seen[:, None]).argmin(axis=1)
        agree = ~_depth_objects(depth_only[frames], nearest, config.change_cost)
        _hold(cost, grid, frames[agree], seen[agree], sigma)
        logger.info("depth states: %d of %d states seen by another cue held (depth objects to the rest)",
                    int(agree.sum()), len(frames))
    if rest_frames is not None or still_frames > 0:
        # A panel sliding in its own plane looks the same in depth wherever it stands but at its edges: at rest its
        # depth cost is flat in the state, and an arm in front of it (its points hidden there cost occluded_cost)
        # makes the states that slide them out from behind it slightly cheaper, frame after frame, so that the chain
        # read the panel's travel long before it moved (dark_pri_wardrobe_00, no tracks on a dark panel: 10.4 cm
        # over the 44 frames before it moved). Until depth first objects to the canonical state, the part rests.
        rest = _rest_prefix(depth_only, seeing, int(np.argmin(np.abs(grid))), rest_frames or 0, config.change_cost,
                            still_frames)
        _hold(cost, grid, rest, np.zeros(len(rest)), sigma)
        logger.info("depth states: the part rests at its canonical state in %d of the first %d frames",
                    len(rest), int(rest.max()) + 1 if len(rest) else 0)
    speed = config.max_speed_rad if revolute else config.max_speed_m
    chain = _min_cost_chain(cost, round(speed / step), config.change_cost)
    states = grid[chain]
    logger.info("depth states: %d of %d frames see >= %d part points; range [%.3f, %.3f]", int(seeing.sum()),
                F, config.min_points, states.min(), states.max())
    frame_costs = np.where(seeing, depth_only[np.arange(F), chain], np.nan)
    return DepthFit(states, float(frame_costs[seeing].mean()) if seeing.any() else float("nan"), frame_costs)


def _state_grid(joint_type: str, config: DepthStateConfig) -> tuple[FloatArray, float]:
    """The searched states of a joint type, symmetric about the canonical state 0, and their step."""
    revolute = joint_type == "revolute"
    step = config.revolute_step_rad if revolute else config.prismatic_step_m
    limit = config.revolute_limit_rad if revolute else config.prismatic_limit_m
    return np.arange(-np.ceil(limit / step), np.ceil(limit / step) + 1) * step, step


def reaches_grid_end(fit: DepthFit, joint_type: str, config: DepthStateConfig) -> bool:
    """Whether a fit's states reach the last state searched (to half a step): no state within the search's limit
    explained the frames there."""
    grid, step = _state_grid(joint_type, config)
    return bool(np.abs(fit.states).max(initial=0.0) >= grid[-1] - 0.5 * step)


def _rest_prefix(depth_only: FloatArray, seeing: BoolArray, canonical: int, rest_frames: int, change_cost: float,
                 still_frames: int = 0) -> IntArray:
    """Frames (from 1) of the rest at the canonical grid state (see :func:`depth_states`' ``rest_frames`` and
    :func:`depth_fit`'s ``still_frames``): those before the first frame at or after ``max(rest_frames, still_frames)`` whose depth
    objects to it, less the frames from ``still_frames`` on that object."""
    objects = seeing & _depth_objects(depth_only, np.full(len(depth_only), canonical), change_cost)
    objects[: max(still_frames, 1)] = False
    start = max(rest_frames, still_frames, 1)
    later = np.flatnonzero(objects[start:])
    end = start + int(later[0]) if len(later) else len(objects)
    frames = np.arange(1, end)
    return frames[~objects[frames]]


def _depth_objects(depth_only: FloatArray, columns: IntArray, change_cost: float) -> BoolArray:
    """(F,) True where a frame's depth objects to its grid state ``columns[f]``: that state costs more than
    ``change_cost`` above the frame's best (rows of ``depth_only`` (F, G), the depth term alone)."""
    return depth_only[np.arange(len(depth_only)), columns] > depth_only.min(axis=1) + change_cost


def _excess_near(depth_only: FloatArray, grid: FloatArray, states: FloatArray, window: float) -> FloatArray:
    """(N,) how much more the cheapest grid state within ``window`` of each row's state costs than the row's best
    (rows of ``depth_only`` (N, G), the depth term alone; ``states`` (N,))."""
    near = np.abs(grid[None, :] - np.asarray(states)[:, None]) <= window
    return np.where(near, depth_only, np.inf).min(axis=1) - depth_only.min(axis=1)


def _hold(cost: FloatArray, grid: FloatArray, frames: IntArray, states: FloatArray, sigma: float) -> None:
    """Add to ``cost`` (F, G), in place, a Gaussian term (``sigma``) around each given frame's state."""
    np.add.at(cost, np.asarray(frames, dtype=np.int64), 0.5 * ((grid[None, :] - np.asarray(states)[:, None]) / sigma) ** 2)


def _add_arrival(cost: FloatArray, seeing: BoolArray, T_grid: FloatArray, arrival: Arrival, config: DepthStateConfig) -> None:
    """Blend into ``cost`` (F, G), in place, each arrival frame's cost of its arrived points moved
    back by every grid state (``T_grid`` (G, 4, 4)) against the reference depth; frames with
    fewer than ``config.min_points`` arrived points keep their cost."""
    R_inv = np.transpose(T_grid[:, :3, :3], (0, 2, 1))
    t_inv = -np.einsum("gij,gj->gi", R_inv, T_grid[:, :3, 3])

    def blend(items: IntArray) -> None:  # each arrival frame's own row of cost and seeing: threads write apart
        for frame, p_world in zip(np.asarray(arrival.frames)[items], (arrival.p_world[i] for i in items), strict=True):
            if len(p_world) < config.min_points:
                continue
            # (G, 3, 3) @ (3, N): the same bits as (N, 3) @ (G, 3, 3)^T (checked on 1-4097 points), a third
            # of its time at 2,000 points; einsum is 20x slower
            back = R_inv @ p_world.T + t_inv[:, :, None]  # (G, 3, N)
            arrived, _ = _frame_cost(arrival.depth_m, arrival.K, arrival.T_camera_world,
                                     np.ascontiguousarray(np.moveaxis(back, 1, 0)), None, config)
            w = arrival.weight if seeing[frame] else 1.0
            cost[frame] = (1.0 - w) * cost[frame] + w * arrived
            seeing[frame] = True

    _in_threads(blend, len(arrival.frames), config.threads)


def _in_threads(work: Callable[[IntArray], None], count: int, threads: int) -> None:
    """``work(items)`` on ``threads`` interleaved shares of items 0 .. count - 1, at once in threads
    (``_frame_cost`` is whole-array numpy, which releases the GIL: a second core shares it). Each
    item's result is its own, so the shares give what one pass over all items gives."""
    shares = [np.arange(start, count, threads) for start in range(min(threads, count))]
    for _ in in_order(work, shares, threads, "funrec-depth-states"):
        pass


def _frame_cost(depth_m: FloatArray, K: FloatArray, T_camera_world: FloatArray, p_rows: FloatArray,
                n_rows: FloatArray | None, config: DepthStateConfig) -> tuple[FloatArray, int]:
    """(G,) mean point cost of each grid state in one frame, and how many points the frame sees
    (inside the image with a depth reading, at any state). ``p_rows`` (3, G, M) are the posed
    points' x, y and z rows and ``n_rows`` (3, G, M) their normals' (world frame; NaN normal =
    unknown)."""
    H, W = depth_m.shape
    _, G, M = p_rows.shape
    R, t = T_camera_world[:3, :3], T_camera_world[:3, 3]
    if M > 1:
        # One (3, 3) @ (3, G M) product: the same bits as the (G, M, 3) @ (3, 3) BLAS product it
        # replaces (np.testing on 127 calls sampled from real runs and on random shapes) in a
        # quarter of its time, which was half of this function's, and contiguous rows.
        x, y, z = (R @ p_rows.reshape(3, -1) + t[:, None]).reshape(3, G, M)
    else:  # numpy multiplies single points without BLAS: that product, for its bits
        x, y, z = np.moveaxis(np.moveaxis(p_rows, 0, -1) @ R.T + t, -1, 0)
    # The expressions of K[0, 0] x / z + K[0, 2] and the rest written in place, operation by operation
    # in the same order (the same bits): half the temporaries of (G, M) arrays, this function's cost.
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.multiply(K[0, 0], x)
        u /= z
        u += K[0, 2]
        np.rint(u, out=u)
        v = np.multiply(K[1, 1], y)
        v /= z
        v += K[1, 2]
        np.rint(v, out=v)
    inside = z > 0.1
    inside &= u >= 0
    inside &= u < W
    inside &= v >= 0
    inside &= v < H
    # One flat gather of pixel v W + u (exact in float64) instead of two masked index arrays; pixel
    # 0 outside the image, whose reading is never used (``valid`` is False there).
    v *= W
    v += u
    np.copyto(v, 0.0, where=~inside)
    r = depth_m.ravel()[v.astype(np.intp)]
    valid = r > 0
    valid &= inside
    r -= z
    tau = config.depth_tolerance_m
    point_cost = r / tau  # min((r / tau)^2, 1) within the tolerance, 1 seen through, occluded_cost hidden
    np.square(point_cost, out=point_cost)
    np.minimum(point_cost, 1.0, out=point_cost)
    np.copyto(point_cost, 1.0, where=r > tau)
    np.copyto(point_cost, config.occluded_cost, where=r < -tau)
    if n_rows is not None:
        # far face of a panel: the near face is seen thickness / cos(incidence) in front of it. The normals
        # turned into the camera as the points are, and the cosine summed coordinate by coordinate on the
        # rows: the bits of einsum over (G, M, 3) stacks and np.linalg.norm (checked on random and recorded
        # inputs) at half the cost, which had doubled the hypotheses' per-frame cost.
        if M > 1:
            nx, ny, nz = (R @ n_rows.reshape(3, -1)).reshape(3, G, M)
        else:  # as the points: numpy multiplies single vectors without BLAS
            nx, ny, nz = np.moveaxis(np.moveaxis(n_rows, 0, -1) @ R.T, -1, 0)
        dot = nx * x
        dot += ny * y
        dot += nz * z
        # A point faces away when dot / |p| > facing_cos; with facing_cos >= 0 only a positive dot can (a NaN
        # normal's NaN dot never does), so the norm, the cosine and the far-face cost are computed for those
        # points alone (a third to a half of them), element by element the same bits.
        candidates = np.flatnonzero(dot > 0.0) if config.facing_cos >= 0.0 else np.arange(dot.size)
        xs, ys, zs = x.ravel()[candidates], y.ravel()[candidates], z.ravel()[candidates]
        norm = xs * xs
        norm += ys * ys
        norm += zs * zs
        np.sqrt(norm, out=norm)
        cos = dot.ravel()[candidates] / np.maximum(norm, 1e-9)
        facing = np.nan_to_num(cos, nan=-1.0) > config.facing_cos
        candidates, cos = candidates[facing], cos[facing]
        along_ray = 1.0 / np.maximum(np.abs(cos), 0.3)  # grazing rays: bounded, depth is poor there anyway
        thin, thick = config.panel_thickness_m
        r_facing = r.ravel()[candidates]
        point_cost.ravel()[candidates] = np.where(r_facing > -thin * along_ray, 1.0,
                                                  np.where(r_facing > -thick * along_ray, 0.0, config.occluded_cost))
    np.copyto(point_cost, config.occluded_cost, where=~valid)
    return point_cost.mean(1), int(valid.any(0).sum())


def oriented_normals(p_part: FloatArray, view_part: FloatArray, radius_m: float, min_neighbours: int = 5,
                     max_flatness: float = 0.1) -> FloatArray:
    """Outward normals of a sparse part point set from the plane of each point's neighbours.

    Args:
        p_part: (M, 3) part points (any one frame, e.g. the canonical part frame), metres.
        view_part: (M, 3) mean direction (same frame) from each point towards the cameras that
            saw it; the normal is signed to face it (a tracked point was on a visible face).
        radius_m: neighbourhood radius, metres.
        min_neighbours: fewer neighbours (itself included) leave the normal unknown.
        max_flatness: smallest / middle PCA eigenvalue above which the neighbourhood is not a
            plane (a corner, a handle) and the normal is unknown.

    Returns:
        (M, 3) unit normals; NaN rows where unknown.
    """
    normals = np.full(p_part.shape, np.nan)
    if len(p_part) < min_neighbours:
        return normals
    tree = cKDTree(p_part)
    for i, neighbours in enumerate(tree.query_ball_point(p_part, radius_m)):
        if len(neighbours) < min_neighbours:
            continue
        eigenvalues, vectors = np.linalg.eigh(np.cov(p_part[neighbours].T))
        if eigenvalues[0] > max_flatness * eigenvalues[1]:
            continue
        n = vectors[:, 0]
        normals[i] = n if n @ view_part[i] >= 0 else -n
    return normals


def _min_cost_chain(cost: FloatArray, max_steps: int, change_cost: float) -> IntArray:
    """(F,) grid index per frame minimising the sum of unary costs (F, G) plus ``change_cost``
    per grid step moved between consecutive frames, moving at most ``max_steps`` per frame
    (Viterbi on a chain). Written out because scipy has no min-sum chain solver; G is a few
    hundred, so one (G, G) transition matrix is cheap."""
    F, G = cost.shape
    steps = np.abs(np.arange(G)[None, :] - np.arange(G)[:, None])
    transition = np.where(steps <= max_steps, change_cost * steps, np.inf)  # from (rows) -> to (cols)
    back = np.zeros((F, G), dtype=np.int64)
    total = cost[0].copy()
    for f in range(1, F):
        candidates = total[:, None] + transition
        back[f] = np.argmin(candidates, axis=0)
        total = candidates[back[f], np.arange(G)] + cost[f]
    path = np.zeros(F, dtype=np.int64)
    path[-1] = int(np.argmin(total))
    for f in range(F - 1, 0, -1):
        path[f - 1] = back[f, path[f]]
    return path


__all__ = ["Arrival", "DepthFit", "DepthStateConfig", "depth_fit", "depth_states", "motion_costs", "oriented_normals",
           "reaches_grid_end"]
