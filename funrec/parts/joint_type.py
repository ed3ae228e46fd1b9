"""The joint type of a found part decided in depth: the type whose posed part points best explain
the depth images, when the tracks alone cannot tell a slide from a turn.

Point tracks on a plain door die a few degrees into the opening, and for those first degrees a
turning door is also a straight slide: the tracks' model selection then says prismatic. Depth
sees the whole opening. Both explanations of the part's tracks are posed over the window by a
1-DoF search in depth (:func:`funrec.parts.depth_states.depth_fit`); a door turned by a slide
leaves its points in free space, and a drawer turned by a hinge does too. The paper's VLM proposes
the joint type from the video; this is the geometric stand-in for that proposal.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from funrec.camera.tracking import CameraTrajectory
from funrec.formats.capture import Capture
from funrec.parts.articulation import ArticulationConfig, PartEstimate, refit_joint
from funrec.parts.depth_states import DepthStateConfig, depth_fit
from funrec.parts.fragment_tracks import sub_capture, sub_trajectory
from funrec.parts.part_merge import canonical_part_points
from funrec.parts.point_tracks import PointTracks

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class JointTypeConfig:
    """Settings of :func:`choose_joint_type`."""

    enabled: bool = True
    """Let depth overturn the tracks' joint type (off: the tracks decide alone; ablation)."""
    min_gain: float = 0.15
    """The other type wins only when its mean depth cost is lower by this fraction of the
    tracks' choice: costs of a right and a wrong type differ by 2-5x once the part has moved by
    more than a few centimetres, while two near-equivalent fits (a short drawer pull that is also
    a turn about a far axis) differ by a few percent."""
    max_points: int = 400
    """Part points scored at most (evenly subsampled): the cost is a mean, and the search costs
    grid states x points per frame."""
    max_hinge_distance_m: float = 2.0
    """A revolute refit whose hinge lies farther than this from every point of the part is not a
    candidate: doors, lids and flaps hinge on their own edge (measured on a dark-family glass door:
    the refit put the hinge 2.5e12 m away)."""
    depth: DepthStateConfig = DepthStateConfig()
    """The 1-DoF state search in depth (grid, tolerances, speed limits)."""


def _plausible(part: PartEstimate, p_part: np.ndarray, config: JointTypeConfig) -> bool:
    """A hinge within ``max_hinge_distance_m`` of the part's points (a refit "turn" about a line
    kilometres away is a slide written as a turn, and its posed points overflow later stages)."""
    if part.joint_type != "revolute" or part.pivot_world is None or len(p_part) == 0:
        return True
    offset = p_part - part.pivot_world
    along = offset @ part.axis_world
    distance = np.linalg.norm(offset - along[:, None] * part.axis_world, axis=1)
    return bool(np.isfinite(distance).all() and distance.min() <= config.max_hinge_distance_m)


def choose_joint_type(part: PartEstimate, tracks: PointTracks, capture: Capture, trajectory: CameraTrajectory,
                      articulation: ArticulationConfig = ArticulationConfig(),  # noqa: B008 (frozen)
                      config: JointTypeConfig = JointTypeConfig()) -> PartEstimate:  # noqa: B008 (frozen)
    """The part as the joint type that the depth of its frames supports.

    Args:
        part: a part found in ``tracks`` (frames and track indices local to them).
        tracks: the window's point tracks, world frame.
        capture: the window's frames (same frame indices as ``tracks``).
        trajectory: the window's ``T_world_camera`` (F, 4, 4).
        articulation: settings the other type is fitted with.
        config: settings.

    Returns:
        ``part``, or its refit as the other joint type when depth clearly prefers that.
    """
    if not config.enabled:
        return part
    other_type = "prismatic" if part.joint_type == "revolute" else "revolute"
    other = refit_joint(part, tracks, other_type, articulation)
    if other is None or not _plausible(other, canonical_part_points(part, tracks), config):
        return part
    # both scored on the same frames: from the first frame either saw the part move to the window's end
    first = int(min(part.frames[0], other.frames[0]))
    frames, poses = sub_capture(capture, first, len(capture) - 1), sub_trajectory(trajectory, first, len(capture) - 1)
    costs = {}
    for candidate in (part, other):
        x = canonical_part_points(candidate, tracks)
        if len(x) > config.max_points:
            x = x[np.linspace(0, len(x) - 1, config.max_points).astype(int)]
        costs[candidate.joint_type] = depth_fit(frames, poses, candidate.joint_type, candidate.axis_world,
                                                 candidate.pivot_world, x, config.depth)[1]
    logger.info("joint type in depth: tracks chose %s; mean depth cost revolute %.3f, prismatic %.3f",
                part.joint_type, costs["revolute"], costs["prismatic"])
    if np.isfinite(costs[other_type]) and costs[other_type] < (1.0 - config.min_gain) * costs[part.joint_type]:
        logger.info("depth overturns the joint type: %s", other_type)
        return other
    return part


__all__ = ["JointTypeConfig", "choose_joint_type"]
