"""One part from several interactions: parts found in different dynamic fragments whose joints
agree (same type, axis, pivot line) and whose geometry coincides between the fragments are one
part, with the union of the frames and every state measured from the first one's canonical state.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from funrec.geometry.joint_tracks import canonical_points
from funrec.geometry.joints import joint_transforms
from funrec.parts.articulation import PartEstimate
from funrec.parts.point_tracks import PointTracks
from funrec.typed import FloatArray

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class PartMergeConfig:
    """When two parts of different fragments are one part; lengths in metres, angles in radians."""

    max_axis_angle_rad: float = np.deg2rad(8.0)
    """Largest angle between the two joint axes (either direction): stage 3 axes of one part from
    two fragments differ by a few degrees (measured 2.8 deg on the bench's multi_same_00)."""
    max_pivot_distance_m: float = 0.06
    """Largest distance between the two revolute axis lines: a few cm of pivot error each
    (measured 2 mm on multi_same_00; stage 3's pivots are off by up to ~2 cm on single doors)."""
    overlap_distance_m: float = 0.05
    """A point of one part is on the other when a point of the other, moved along the joint, is
    within this distance: about the spacing of the tracks on a part (a 20 px seed grid is ~4 cm
    at 1 m for a 525 px focal length)."""
    min_overlap_fraction: float = 0.5
    """Fraction of either part's points that must lie on the other at the best joint state:
    parallel drawers of one cabinet, or doors above each other on one hinge line, share their
    axis but not their place."""
    max_slide_m: float = 1.0
    """Prismatic states searched for the rest state span +- this, metres (longer than drawers)."""


def canonical_part_points(part: PartEstimate, tracks: PointTracks) -> FloatArray:
    """(M, 3) the part's track points at its canonical state (its first tracked frame), world
    frame: each track's observations moved back by the part's poses and averaged. ``part.frames``
    and ``part.track_indices`` index ``tracks``."""
    frames = part.frames
    p = tracks.p_world[frames][:, part.track_indices]
    w = (tracks.visible[frames][:, part.track_indices] & np.isfinite(p).all(-1)).astype(np.float64)
    T_world_part = joint_transforms(part.joint_type, part.axis_world, part.pivot_world, part.states)
    x = canonical_points(T_world_part, np.nan_to_num(p), w)
    return x[np.isfinite(x).all(1)]


def _axis_line_distance(a: PartEstimate, b: PartEstimate) -> float:
    """Distance between two revolute axis lines, metres."""
    n = np.cross(a.axis_world, b.axis_world)
    delta = b.pivot_world - a.pivot_world
    if np.linalg.norm(n) < 1e-9:
        return float(np.linalg.norm(np.cross(delta, a.axis_world)))
    return float(abs(delta @ n) / np.linalg.norm(n))


def rest_state(earlier: PartEstimate, later: PartEstimate, x_earlier: FloatArray, x_later: FloatArray,
               config: PartMergeConfig = PartMergeConfig()) -> float | None:  # noqa: B008 (frozen, immutable default)
    """The state of ``earlier``'s joint at which ``later`` (tracked after it) started, when
    ``later`` is the same part; None otherwise. ``x_earlier`` and ``x_later`` are their (M, 3)
    canonical track points (:func:`canonical_part_points`), world frame.

    Same part: same joint type, axes within ``max_axis_angle_rad``, revolute axis lines within
    ``max_pivot_distance_m``, and ``earlier``'s points moved along its joint to some state
    coincide with ``later``'s points at its first state (``min_overlap_fraction`` of either set
    within ``overlap_distance_m`` of the other). The state is searched over the whole joint (1 deg
    or 5 mm steps, then refined), not taken as ``earlier``'s last one: stage 3 may lose a fast
    door before it stops, and the hand may move it back.
    """
    if earlier.joint_type != later.joint_type:
        return None
    cosine = min(1.0, abs(float(earlier.axis_world @ later.axis_world)))
    if np.arccos(cosine) > config.max_axis_angle_rad:
        return None
    if earlier.joint_type == "revolute" and _axis_line_distance(earlier, later) > config.max_pivot_distance_m:
        return None
    if len(x_earlier) == 0 or len(x_later) == 0:
        return None
    step = np.deg2rad(1.0) if earlier.joint_type == "revolute" else 0.005
    limit = np.pi if earlier.joint_type == "revolute" else config.max_slide_m
    grid = np.arange(-limit, limit, step)
    tree_earlier, tree_later = cKDTree(x_earlier), cKDTree(x_later)
    d = config.overlap_distance_m
    to_later, to_earlier = _distances(earlier, x_earlier, x_later, tree_earlier, tree_later, grid, d)
    overlap = np.maximum(np.isfinite(to_later).mean(1), np.isfinite(to_earlier).mean(1))
    if overlap.max() < config.min_overlap_fraction:
        logger.debug("not the same part: overlap at most %.2f", overlap.max())
        return None
    # Among the overlapping states (a plateau several steps wide), the one with the smallest mean
    # clipped distance between the point sets, which unlike the overlap count varies smoothly
    # with the state; then refined within one step.
    cost = np.minimum(to_later, d).mean(1) + np.minimum(to_earlier, d).mean(1)
    best = int(np.argmin(np.where(overlap >= config.min_overlap_fraction, cost, np.inf)))
    fine = grid[best] + np.linspace(-step, step, 41)
    cost = sum(np.minimum(a, d).mean(1) for a in _distances(earlier, x_earlier, x_later, tree_earlier, tree_later, fine, d))
    logger.debug("same part: overlap %.2f at state %.3f (earlier ended at %.3f)", overlap[best], grid[best], earlier.states[-1])
    return float(fine[int(np.argmin(cost))])


def _distances(earlier: PartEstimate, x_earlier: FloatArray, x_later: FloatArray, tree_earlier: cKDTree,
               tree_later: cKDTree, states: FloatArray, bound_m: float) -> tuple[FloatArray, FloatArray]:
    """Nearest distances at each of S states of ``earlier``'s joint: (S, M_earlier) from its
    points so moved to ``x_later``, and (S, M_later) from ``x_later`` moved back to its points
    (inf beyond ``bound_m``)."""
    T = joint_transforms(earlier.joint_type, earlier.axis_world, earlier.pivot_world, states)
    moved = np.einsum("sij,mj->smi", T[:, :3, :3], x_earlier) + T[:, None, :3, 3]
    back = np.einsum("sji,smj->smi", T[:, :3, :3], x_later[None] - T[:, None, :3, 3])
    to_later = tree_later.query(moved.reshape(-1, 3), distance_upper_bound=bound_m)[0].reshape(len(states), -1)
    to_earlier = tree_earlier.query(back.reshape(-1, 3), distance_upper_bound=bound_m)[0].reshape(len(states), -1)
    return to_later, to_earlier


def same_part(earlier: PartEstimate, later: PartEstimate, x_earlier: FloatArray, x_later: FloatArray,
              config: PartMergeConfig = PartMergeConfig()) -> bool:  # noqa: B008 (frozen, immutable default)
    """True when ``later`` (tracked after ``earlier``) is the same part (see :func:`rest_state`)."""
    return rest_state(earlier, later, x_earlier, x_later, config) is not None


def merge_two(earlier: PartEstimate, later: PartEstimate, rest: float | None = None) -> PartEstimate:
    """One part from two tracked spans of it: ``earlier``'s joint and canonical state; ``later``'s
    states re-signed to ``earlier``'s axis and started at ``rest`` (default: ``earlier``'s last
    state), where the part rested in between. Frames between the spans hold ``rest`` and are
    marked interpolated (where the spans overlap, ``earlier``'s states are kept); the tracks are
    the union."""
    rest = float(earlier.states[-1]) if rest is None else rest
    sign = 1.0 if float(earlier.axis_world @ later.axis_world) >= 0 else -1.0
    first, last = int(earlier.frames[0]), int(max(earlier.frames[-1], later.frames[-1]))
    frames = np.arange(first, last + 1, dtype=np.int64)
    states = np.full(len(frames), rest)
    interpolated = np.ones(len(frames), dtype=bool)
    states[later.frames - first] = rest + sign * (later.states - later.states[0])
    interpolated[later.frames - first] = later.interpolated
    states[earlier.frames - first] = earlier.states
    interpolated[earlier.frames - first] = earlier.interpolated
    axis = earlier.axis_world
    if states[np.argmax(np.abs(states))] < 0:  # stage 3's sign convention: largest |state| positive
        axis, states = -axis, -states
    return dataclasses.replace(
        earlier,
        axis_world=axis,
        frames=frames,
        states=states,
        interpolated=interpolated,
        track_indices=np.union1d(earlier.track_indices, later.track_indices),
        size_score=earlier.size_score + later.size_score,
        evidence_score=None if earlier.evidence_score is None else earlier.evidence_score + (later.evidence_score or 0.0),
    )


def merge_parts(parts: list[PartEstimate], points: list[FloatArray],
                config: PartMergeConfig = PartMergeConfig()  # noqa: B008 (frozen, immutable default)
                ) -> tuple[list[PartEstimate], list[int]]:
    """Merge parts of different fragments that are one part (:func:`rest_state`), in time order.

    Args:
        parts: parts in the order of their fragments, frames in capture frame indices.
        points: per part, its (M_k, 3) canonical track points (:func:`canonical_part_points`).
        config: thresholds.

    Returns:
        The merged parts (in order of first appearance) and, per input part, the index of the
        merged part it became.
    """
    merged: list[PartEstimate] = []
    merged_points: list[FloatArray] = []
    owner: list[int] = []
    for part, x in zip(parts, points, strict=True):
        for k, m in enumerate(merged):
            rest = rest_state(m, part, merged_points[k], x, config) if m.frames[-1] < part.frames[-1] else None
            if rest is not None:
                logger.info("part of frames %d-%d is part %d again (rest state %.3f): merged", part.frames[0],
                            part.frames[-1], k, rest)
                # the later part's canonical state is the earlier joint's state `rest`
                T_back = np.linalg.inv(joint_transforms(m.joint_type, m.axis_world, m.pivot_world, np.array([rest]))[0])
                merged_points[k] = np.concatenate([merged_points[k], x @ T_back[:3, :3].T + T_back[:3, 3]])
                merged[k] = merge_two(m, part, rest)
                owner.append(k)
                break
        else:
            owner.append(len(merged))
            merged.append(part)
            merged_points.append(x)
    return merged, owner


__all__ = ["PartMergeConfig", "canonical_part_points", "merge_parts", "merge_two", "rest_state", "same_part"]
