"""A part and its joint proposed from depth alone: the surface that left, and the joint that moves it.

Point tracks need texture; a plain painted door has none, so its tracks are too few to build a
part from. Depth needs no texture. The surface of a door or a sliding panel that the person moved
*leaves*: pixels of the first frame of the fragment whose surface a later frame sees through
(free-space violations, :mod:`funrec.parts.scene_change`) lie on the part at its canonical state.
Their dominant plane is the part's front; joints are hypothesised from it (a turn about each edge
of its extent, a slide along its normal or along either in-plane direction) and each is scored by
the 1-DoF search of the part's state in every frame's depth (:func:`funrec.parts.depth_states.depth_fit`).
The best hypothesis is kept when it explains the depth clearly better than a part that did not
move. The paper proposes parts with a VLM and tracks them with TAPIP3D; this is the geometric
stand-in behind the same output, 3D tracks of the part (:func:`proposal_tracks`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace
from types import SimpleNamespace

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from funrec.camera.tracking import CameraTrajectory
from funrec.formats.capture import Capture
from funrec.geometry.camera import backproject, project
from funrec.geometry.joints import joint_transforms
from funrec.geometry.transforms import invert_transform, transform_points
from funrec.parts.articulation import PartEstimate
from funrec.parts.depth_states import (
    Arrival,
    DepthFit,
    DepthStateConfig,
    depth_fit,
    depth_states,
    motion_costs,
    reaches_grid_end,
)
from funrec.parts.point_tracks import PointTracks
from funrec.typed import BoolArray, FloatArray, IntArray

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class DepthProposalConfig:
    """Settings of :func:`propose_part`; lengths in metres."""

    enabled: bool = True
    """Propose a part from depth where the tracks found none (off: tracks only; ablation)."""
    work_width_px: int = 160
    """Depth images are subsampled to about this width: a door covers thousands of pixels even
    at 160 px, and each hypothesis is scored on a few hundred points."""
    margin_m: float = 0.03
    """A first-frame surface point is seen through when a later frame's depth there is farther
    by this plus ``margin_per_m`` times its depth (as :class:`~funrec.parts.scene_change.SceneChangeConfig`:
    several sigma of Kinect-class noise plus camera pose error)."""
    margin_per_m: float = 0.03
    """Depth-proportional part of the margin."""
    min_frames: int = 3
    """A point must be seen through in at least this many frames: one frame of pose error or a
    flicker at a depth edge is not a surface that left."""
    hand_dilation_px: int = 3
    """Hand masks (at the work resolution) are grown by this many pixels: a hand that moved away
    is not a part."""
    plane_tolerance_m: float = 0.012
    """Points within this of the front plane belong to it (a painted front is flat to millimetres;
    Kinect noise is ~3 mm at 1 m)."""
    front_growth_rounds: int = 6
    """Rounds of refitting the front's normal on frame 0's full-resolution surface within
    ``plane_tolerance_m`` of its plane and connected to it (0: the normal of the surface that left
    alone). What leaves of a drawer pulled towards a camera above it is a strip a few work pixels
    tall, whose plane tilts by degrees across it (light_dim_pri_drawer_00: 3.1 deg); the closed
    front it lies in, and the fronts flush with it, fix the normal (0.2 deg after 6 rounds; each
    round grows the region as the plane turns true, measured 51k, 74k, 94k, 96k pixels)."""
    min_points: int = 40
    """Fewer points that left (at the work resolution) make no proposal: 40 pixels at 160 px wide
    are a 10 x 15 cm patch at 1.5 m."""
    max_points: int = 300
    """Points of the proposed part at most (evenly subsampled): its tracks and its fine state search."""
    hypothesis_points: int = 150
    """Points each hypothesis is scored on (evenly subsampled): the score is a mean cost, and a
    door's 150 points at 160 px still cover it every ~3 cm."""
    score_stride: int = 2
    """Hypotheses are scored on every this-many-th frame (a door turns ~4 deg per frame at 15 fps;
    the chain's speed bound is scaled to match)."""
    hinge_offsets_m: tuple[float, ...] = (-0.03, 0.0, 0.03, 0.06)
    """Offsets of a hinge line outwards from the edge of the surface that left: the strip by the
    hinge barely moves, so it never leaves by the margin and the hinge lies a little beyond it."""
    arrival_points: int = 150
    """Points of each frame's surface that arrived in front of frame 0's view (evenly subsampled)
    that every hypothesis moves back by its state and scores against frame 0's depth
    (:class:`~funrec.parts.depth_states.Arrival`): as many as a hypothesis's own points."""
    hinge_refine_steps_deg: tuple[float, ...] = (8.0, 4.0, 2.0, 1.0)
    """Steps of the search that turns the best hinge within the front's plane (empty: no search)."""
    hinge_refine_steps_m: tuple[float, ...] = (0.02, 0.01, 0.005, 0.005)
    """... and shifts it across the plane, metres (one per turning step)."""
    min_gain: float = 0.5
    """The best hypothesis must cost at most this fraction of the part held still (state 0 in every
    frame): less, and depth does not say the surface moved as a joint moves it."""
    challenge: bool = True
    """Where the tracks did find a part (and no object masks were recorded), propose one from depth
    anyway and let it replace the tracks' part when it explains the surface that left clearly
    better (off: depth proposes only where the tracks found nothing; ablation). A plain door's
    few tracks die in the first degrees of the opening, where a turn is also a slide."""
    rival_margin: float = 0.15
    """... clearly better: its cost is lower by this fraction of the tracks' joint's cost (as
    :class:`~funrec.parts.joint_type.JointTypeConfig`'s ``min_gain``: a right and a wrong joint
    differ by 2-5x once the part has moved)."""
    track_veto: bool = True
    """The tracks' part holds against depth's replacement when its tracks saw most of the motion
    that depth's joint reads (``track_veto_seen``) and depth's joint misplaces them
    (``track_veto_ratio``, ``track_veto_min_m``): depth scores the surface that left and can be fooled by
    what that surface lands on. Measured (reseed 1): pri_drawer_02_r1, a bottom drawer, whose front
    turned down onto the floor cost 0.141 against its true slide's 0.194, while the slide's 72 tracks,
    seen over the whole pull, lay 10.4 cm from the turn and 0.6 cm from their slide; rev_fridge_01_r1,
    whose 245 tracks lay 3.3 cm from depth's hinge (84 deg off) and 0.6 cm from their own. Tracks that
    died early (a plain door's: 8 % of the motion on dark_rev_cabinet_left_00_r1, where depth's hinge
    is right) or that no later frame sees say nothing, nor do a slide's tracks against depth's slide (settled on
    depth's surface; vetoes there lost plain_pri_drawer_00 and _02 of the tuned 56). False: depth replaces on cost
    alone (ablation)."""
    track_veto_seen: float = 0.5
    """Share of depth's largest state that must have been travelled while the tracks watched (the range of
    depth's states over the tracks' trusted frames): tracks seeded after the part had moved saw none of the
    motion, however far it had got (plain_rev_dishwasher_00_r2: 10 tracks on the open door's frame and the
    carcass, frames 42-58 of a drop-down door already down, held their spurious slide against depth's right
    hinge when this was the largest state they reached)."""
    track_veto_ratio: float = 3.0
    """Depth's joint misplaces the tracks when their median distance from where it carries them, over
    the frames in which their own part had moved at least half its tracked travel, is this many times
    their distance from where their own joint carries them ..."""
    track_veto_max_own_m: float = 0.01
    """... and only tracks that their own joint carries within this, metres, speak for a rigid part:
    a part's tracks measured 0.2-0.6 cm from their own joint on the reseed-1 bench; tracks that
    moved with the arm or slid on a plain front, 1.3-2.2 cm (geo_island_pri_drawer_00_r1 and
    mw_window_00_r1, whose depth slides were right: 8.1 deg and a lost window when such tracks held)."""
    track_veto_min_m: float = 0.02
    """... and more than this, metres: twice the largest own-joint distance measured on tracks that were
    on the part (1.0 cm, person_elbow_pri_wardrobe_00_r1; 0.4-0.6 cm elsewhere)."""
    track_veto_max_away_m: float = 0.1
    """... and only tracks on depth's part speak against its joint: the median, over the tracks, of each
    track's nearest approach to depth's part points (posed by depth's joint in the frames the track is seen)
    must be within this, metres. A joint can be wrong about how its surface moved, not about where it
    was: tracks on the part, or on what a drawer carries, came within 1.5-2.6 cm of it (rev_fridge_01_r1,
    pri_drawer_02_r1, whose front depth turned down onto the floor). Tracks that are not on it say nothing
    about its joint: 12 floor tracks 3 m away, 'moving' 4-10 cm with the camera's rotation error, lay a
    median 31 cm from depth's right door and vetoed it (person_sleeve_rev_cabinet_00_r3)."""
    search: DepthStateConfig = DepthStateConfig(revolute_step_rad=np.deg2rad(2.0), prismatic_step_m=0.015)
    """The 1-DoF state search that scores the hypotheses: 2 deg and 1.5 cm steps move a front's
    points by less than the 3 cm depth tolerance, at a quarter of the fine search's cost."""
    depth: DepthStateConfig = DepthStateConfig()
    """The fine 1-DoF search of the chosen joint's states."""


@dataclass(frozen=True)
class DepthProposal:
    """A part proposed from depth, world frame."""

    joint_type: str
    """"revolute" or "prismatic"."""
    axis_world: FloatArray
    """(3,) unit axis."""
    pivot_world: FloatArray | None
    """(3,) a point on the revolute axis; None for prismatic."""
    p_world: FloatArray
    """(M, 3) points of the part at its canonical state (the first frame)."""
    states: FloatArray
    """(F,) state of every frame, 0 at the first."""
    cost: float
    """Mean depth cost of the proposal (0 perfect, 1 every point seen through)."""
    static_cost: float
    """Mean depth cost of the same points held still."""
    rival_cost: float = float("inf")
    """The rival joint's cost on the same surface (inf without a rival)."""
    rival_held: bool = False
    """The rival joint passed to :func:`propose_part` explains the surface that left as well as
    this best hypothesis: keep the rival (and when this proposal's joint type is the rival's,
    depth confirms the rival's type)."""


HandMask = Callable[[int], BoolArray | None]
"""hand(frame) -> (H, W) bool hand mask of a frame, or None."""


Joint = tuple[str, FloatArray, FloatArray | None]
"""(joint type, unit axis, pivot or None), world frame."""


def propose_part(capture: Capture, trajectory: CameraTrajectory, hand: HandMask | None = None,
                 config: DepthProposalConfig = DepthProposalConfig(),  # noqa: B008 (frozen)
                 rival: Joint | None = None, rival_states: tuple[IntArray, FloatArray] | None = None,
                 rest_frames: int = 0) -> DepthProposal | None:
    """Propose the part that moved in a span of frames, and its joint, from depth alone.

    Args:
        capture: the span's frames; frame 0 shows the part at rest (the canonical state).
        trajectory: the span's ``T_world_camera`` (F, 4, 4).
        hand: hand masks to leave out; None: none known.
        config: settings.
        rival: a joint found otherwise (the point tracks' part), scored on the same surface in the
            same way as the front's hypotheses.
        rival_states: the rival's (frames, states) where its tracks saw it (frames of this span,
            states along the rival's axis, 0 at frame 0): when the rival and the proposal are both
            slides, they hold the proposal's state search where depth does not object (see below).
        rest_frames: the span's first frames in which the scene did not change (before the interaction's
            dynamic fragment). The part rests at its canonical state in them, and after them until depth first
            objects (:func:`~funrec.parts.depth_states.depth_states`).

    Returns:
        The proposal (``rival_held`` when the ``rival`` explains the surface at least as well), or
        None when too little surface left or no joint explains its motion.
    """
    if not config.enabled or len(capture) < 3:
        return None
    views = _Views(capture, trajectory, hand, config)
    p_left, leaving = _surface_that_left(views)
    if len(p_left) < config.min_points:
        logger.info("depth proposal: %d points left the first frame's surface (< %d): none", len(p_left), config.min_points)
        return None
    front = _front_plane(p_left, config.plane_tolerance_m)
    if front is None:
        return None
    points, normal, u_axis, v_axis = front
    normal = _grown_normal(views, points, normal, config)
    u_axis = u_axis - (u_axis @ normal) * normal
    u_axis /= np.linalg.norm(u_axis)
    v_axis = np.cross(normal, u_axis)
    if len(points) > config.max_points:
        points = points[np.linspace(0, len(points) - 1, config.max_points).astype(int)]
    # Hypotheses are scored on the work-resolution depth of every ``score_stride``-th frame, held in
    # memory once (a few MB), not decoded again per hypothesis from the full images.
    coarse, coarse_poses, search = _coarse(views, config)
    hypothesis_points = points[np.linspace(0, len(points) - 1, min(len(points), config.hypothesis_points)).astype(int)]
    # The front faced frame 0's camera: once a hypothesis turns it away, its points are scored as a
    # panel's far face (see DepthStateConfig.panel_thickness_m). Without it a thick door's outer face
    # matched its inner face, and the hinge that explained that best lay 3.6 cm from the true one
    # (mw_door_00: the true hinge cost 0.188 against the chosen one's 0.116; 0.099 against 0.120 so scored).
    facing = normal if normal @ (trajectory.T_world_camera[0, :3, 3] - points.mean(0)) > 0 else -normal
    hypothesis_normals = np.broadcast_to(facing, hypothesis_points.shape)
    # what arrived in front of frame 0's view, in every scored frame: the moved part must be it
    F = len(capture)
    arrived, arriving = _arrived(views, np.arange(F))  # once: the scored frames' for the hypotheses, all for the chosen joint
    first_change = min(_first_frame_over(leaving, config.min_points), _first_frame_over(arriving, config.min_points))
    scored = np.arange(0, F, config.score_stride)
    coarse_arrival = Arrival(np.arange(len(scored)), arrived[:: config.score_stride], views.depth0_m,
                             capture.intrinsics.K, invert_transform(trajectory.T_world_camera[0]))
    static = depth_fit(coarse, coarse_poses, "prismatic", normal, None, hypothesis_points, _held_still(search),
                       coarse_arrival, hypothesis_normals)[1]
    best_of: dict[str, tuple[float, str, FloatArray, FloatArray | None]] = {}
    slides: list[tuple[float, str, FloatArray, FloatArray | None]] = []
    rival_cost = np.inf
    hypotheses = _hypotheses(points, normal, u_axis, v_axis, config.hinge_offsets_m)

    fits: dict[tuple[float, ...], DepthFit] = {}  # every scored hypothesis's fit, by _joint_key
    # Every hypothesis is scored resting at the canonical state until the scene changes by as much as a part makes
    # (surface seen through or arrived in front, hands left out: _first_frame_over), whatever depth says before, and
    # after it until depth first objects, as the chosen joint's states do. An arm in front of a plain front flush with its neighbours
    # made a joint cheaper where it moved the front's points out from behind the arm onto the neighbours: unheld, a
    # slide across a drawer began 0.28 m along at frame 0, and held only until depth objected, it jumped there as the
    # arm came in, 13 frames before any of the front was seen through (light_dim_pri_drawer_00_r8: that slide 0.210
    # against the true pull's 0.231, axis 89.9 deg off; held only until the first surface left, a drop-down turn of
    # the front cost 0.181 and a door turning towards the camera, which hid what lay behind it before anything
    # behind was seen, was held to 20 deg: person_slow_rev_cabinet_00_r8 read as a slide). That change is seen once
    # the surface has moved by the free-space margin (7.5 cm at 1.5 m), so the chosen joint's states are not held
    # to it: they rest until depth objects, as before.
    coarse_rest, coarse_still = (-(-n // config.score_stride) for n in (rest_frames, first_change))  # scored frames

    def score(joint_type: str, axis: FloatArray, pivot: FloatArray | None) -> float:
        fit = depth_fit(coarse, coarse_poses, joint_type, axis, pivot, hypothesis_points, search, coarse_arrival,
                        hypothesis_normals, coarse_rest, coarse_still)
        fits[_joint_key(joint_type, axis, pivot)] = fit
        cost = fit.cost
        if not np.isfinite(cost):
            return np.inf
        logger.debug("hypothesis %s axis %s pivot %s: cost %.3f", joint_type, axis.round(3),
                     None if pivot is None else pivot.round(3), cost)
        return cost

    for k, (joint_type, axis, pivot) in enumerate([*hypotheses, *([rival] if rival is not None else [])]):
        cost = score(joint_type, axis, pivot)
        if not np.isfinite(cost):
            continue
        if k == len(hypotheses):
            rival_cost = cost
            continue
        if joint_type == "prismatic":
            slides.append((cost, joint_type, axis, pivot))
        if joint_type not in best_of or cost < best_of[joint_type][0]:
            best_of[joint_type] = (cost, joint_type, axis, pivot)
    # The best of each joint type is refined before they are compared: the grid of hypotheses is
    # coarse (principal axes, 3 cm hinge offsets) and a refined hinge can beat a slide that the
    # grid preferred (measured on plain_rev_oven_00: a drop-down door's slide 0.500 against its
    # unrefined hinge 0.519).
    if "revolute" in best_of:
        cost, _, axis, pivot = best_of["revolute"]
        cost, (axis, pivot) = _descend(cost, (axis, pivot), len(config.hinge_refine_steps_deg),
                                       _hinge_neighbours(normal, config), lambda a, p: score("revolute", a, p))
        best_of["revolute"] = (cost, "revolute", axis, pivot)
    # A slide is not refined: it runs along one of the front's axes. Across the front (a drawer) along
    # its normal, which the plane fit of hundreds of points fixes to a fraction of a degree, while the
    # depth cost is flat in the slide's tilt (tilting by 8-4-2-1 deg steps and the tracks' slide against
    # the normal, reconstruct + eval, f8e389e against this: plain_pri_drawer_01 8.1 -> 0.25 deg,
    # dark_pri_drawer_00 5.1 -> 0.77, plain_pri_drawer_02 2.0 -> 0.18, pri_drawer_00 1.5 -> 0.74,
    # geo_angled_pri_drawer_00 0.8 -> 0.31; worse: light_dim_pri_drawer_00 2.0 -> 2.9, whose normal is
    # 2.9 off, mw_drawer_00 0.1 -> 0.5). Along the front (a sliding panel) along the edges of the
    # surface it uncovered: a plain panel looks the same wherever it stands in its plane but at its
    # edges (plain_pri_wardrobe_00: tilted out of the plane 12.9 deg off, turned within it 16.3, the
    # edge 0.3).
    best = _best_type(best_of, fits, search)
    if best is None or not best[0] < config.min_gain * static:
        logger.info("depth proposal: best cost %s vs still %.3f: no joint explains the surface that left",
                    "-" if best is None else f"{best[0]:.3f}", static)
        return None
    rival_held = rival is not None and not best[0] < (1.0 - config.rival_margin) * rival_cost
    if rival is not None:
        logger.info("depth proposal: the tracks' %s costs %.3f, the best hypothesis (%s) %.3f: ratio %.2f, %s",
                    rival[0], rival_cost, best[1], best[0], best[0] / rival_cost,
                    "the tracks' joint holds" if rival_held else "depth's joint is clearly better")
    if rival is not None and rival[0] == best[1] == "prismatic" and slides:
        best = _slide_agreeing_with_tracks(best, slides, np.asarray(rival[1], dtype=float), fits, search)
    cost, joint_type, axis, pivot = best
    if rival is not None and rival_held and rival[0] == joint_type == "revolute":
        # a door's tracks lie on its leaf: depth agrees on the type and the tracks' hinge explains the surface as
        # well, the tracks' part stands (swapping in depth's surface cost the textured rev_cabinet_left_00 ADD
        # 95.5 -> 91.1, measured). A tracks' hinge that depth's beats clearly is not that door's: 11 tracks
        # of a plain wall cabinet, on a hinge 50 deg off, cost 0.212 against depth's 0.122
        # (plain_rev_wall_cabinet_01 at 665d2eb: the tracks' part stood, was turned into a slide and crashed).
        return DepthProposal(joint_type, axis, pivot, points, np.zeros(F), cost, static, rival_cost, True)
    # A slide keeps depth's axis, the front's normal or an edge of the surface it uncovered (see above), also
    # against the tracks' slide: a drawer's tracks often sit on what it carries, on the walls beside a plain
    # front or on the arm, a panel's few tracks on the handle and the panel's edge, carrying the camera's drift
    # along the slide (plain_pri_wardrobe_00 0.3 against 13.8 deg, person_elbow_pri_wardrobe_00 0.3 against
    # 2.0, mw_window_00 0.05 against 0.3 at dc34b2a; dark_pri_drawer_00's normal 0.8 deg off against its
    # tracks' 5.1 at f8e389e).
    arrival = replace(coarse_arrival, frames=np.arange(F), p_world=arrived)
    # A panel sliding in its own plane looks the same in depth wherever it stands but at its edges, so
    # its depth cost is flat in the state until it has moved far, and the chain, which prices a travel
    # the same whatever frames it happens in, spread it over the frames before the panel moved
    # (plain_pri_wardrobe_00: 7.6 cm of travel read in the 40 frames before it moved). The tracks' slide, on
    # the handle and the panel's edge, saw when it moved: its states, along depth's slide, hold the search
    # where depth does not object (a slide's tracks may be on the arm, which pulls back after a drawer
    # stopped: plain_pri_drawer_02, where depth objects). The tracks' own axis (13.8 deg off) is not used.
    seen = None
    if rival is not None and rival_states is not None and rival[0] == joint_type == "prismatic":
        frames_seen, states_seen = (np.asarray(a) for a in rival_states)
        inside = (frames_seen > 0) & (frames_seen < F)
        seen = (frames_seen[inside].astype(np.int64), states_seen[inside] * float(np.asarray(rival[1]) @ axis))
    states = depth_states(capture, trajectory, joint_type, axis, pivot, points, np.zeros(1, np.int64), np.zeros(1),
                          np.ones(1, bool), config.depth, np.broadcast_to(facing, points.shape), arrival=arrival,
                          seen_states=seen, rest_frames=rest_frames)
    states = states - states[0]
    if states[np.argmax(np.abs(states))] < 0:
        axis, states = -axis, -states
    logger.info("depth proposal: %s from %d points, cost %.3f (still %.3f), range [%.3f, %.3f] over %d frames",
                joint_type, len(points), cost, static, states.min(), states.max(), F)
    return DepthProposal(joint_type, axis, pivot, points, states, cost, static, rival_cost, rival_held)


def proposal_tracks(proposal: DepthProposal, capture: Capture, trajectory: CameraTrajectory,
                    tolerance_m: float = 0.03) -> PointTracks:
    """3D tracks of a proposal's points: each canonical point moved by the joint to every frame's
    state, visible where that frame's depth sees it there (within ``tolerance_m`` along the ray).

    Returns:
        PointTracks over the span's F frames, one track per proposal point.
    """
    F, M = len(capture), len(proposal.p_world)
    T = joint_transforms(proposal.joint_type, proposal.axis_world, proposal.pivot_world, proposal.states)  # (F, 4, 4)
    p_world = np.einsum("fij,mj->fmi", T[:, :3, :3], proposal.p_world) + T[:, None, :3, 3]
    K = capture.intrinsics.K
    uv = np.full((F, M, 2), np.nan)
    visible = np.zeros((F, M), dtype=bool)
    for frame in range(F):
        q = transform_points(invert_transform(trajectory.T_world_camera[frame]), p_world[frame])
        with np.errstate(divide="ignore", invalid="ignore"):
            u = K[0, 0] * q[:, 0] / q[:, 2] + K[0, 2]
            v = K[1, 1] * q[:, 1] / q[:, 2] + K[1, 2]
        depth_m = capture.depth_m(frame)
        H, W = depth_m.shape
        inside = (q[:, 2] > 0.1) & (u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1)
        d = np.zeros(M)
        d[inside] = depth_m[np.rint(v[inside]).astype(int), np.rint(u[inside]).astype(int)]
        seen = inside & (d > 0) & (np.abs(d - q[:, 2]) < tolerance_m)
        visible[frame] = seen
        uv[frame, seen] = np.stack([u[seen], v[seen]], 1)
    return PointTracks(p_world=np.where(visible[..., None], p_world, np.nan), uv=uv, visible=visible)


@dataclass(frozen=True)
class _DepthFrames:
    """Depth images held in memory, read like a capture by the state search (len, depth_m, intrinsics.K)."""

    depth: tuple[FloatArray, ...]
    """(h, w) depth of each frame, metres; 0 = no reading."""
    intrinsics: SimpleNamespace
    """``K`` (3, 3) of the images' resolution."""

    def __len__(self) -> int:
        return len(self.depth)

    def depth_m(self, frame: int) -> FloatArray:
        return self.depth[frame]


def _coarse(views: _Views, config: DepthProposalConfig) -> tuple[_DepthFrames, CameraTrajectory, DepthStateConfig]:
    """Every ``score_stride``-th frame's work-resolution depth (hand pixels removed), its poses, and
    the search settings for it (speeds per kept frame)."""
    frames = np.arange(0, len(views.capture), config.score_stride)
    depth = tuple(views.view(f)[0] for f in frames)
    T = views.trajectory.T_world_camera[frames]
    poses = CameraTrajectory(T, np.zeros(0, np.int64), np.ones(len(frames), dtype=bool))
    stride = config.score_stride
    search = replace(config.search, max_speed_rad=config.search.max_speed_rad * stride,
                     max_speed_m=config.search.max_speed_m * stride)
    return _DepthFrames(depth, SimpleNamespace(K=views.K)), poses, search


def _held_still(config: DepthStateConfig) -> DepthStateConfig:
    """The search with a single state (0): the cost of a part that did not move."""
    return replace(config, prismatic_limit_m=0.0, prismatic_step_m=1.0)


class _Views:
    """Depth images of a span at the work resolution, hand pixels left out, and the free-space test."""

    def __init__(self, capture: Capture, trajectory: CameraTrajectory, hand: HandMask | None,
                 config: DepthProposalConfig) -> None:
        self.capture, self.trajectory, self.hand, self.config = capture, trajectory, hand, config
        self.step = max(1, capture.intrinsics.width // config.work_width_px)
        K = capture.intrinsics.K.astype(np.float64).copy()
        K[:2, 2] -= self.step // 2  # subsampled pixel j is full-resolution pixel step // 2 + j * step
        K[:2, :] /= self.step
        self.K = K
        self._cache: dict[int, tuple[FloatArray, BoolArray, FloatArray]] = {}
        self.depth0_m = capture.depth_m(0)
        """Frame 0's full-resolution depth: every hypothesis moves the arrived surfaces back onto it."""

    def view(self, frame: int) -> tuple[FloatArray, BoolArray, FloatArray]:
        """(depth, valid, near): depth (h, w), valid pixels, and the 3x3 min-filtered depth (a point
        next to a depth edge is compared with the nearest surface around it)."""
        if frame not in self._cache:
            s, kernel = self.step, np.ones((3, 3), np.uint8)
            depth = self.capture.depth_m(frame)[s // 2 :: s, s // 2 :: s].astype(np.float64)
            valid = depth > 0
            mask = None if self.hand is None else self.hand(frame)
            if mask is not None:
                valid &= ~(cv2.dilate(mask[s // 2 :: s, s // 2 :: s].astype(np.uint8), kernel,
                                      iterations=self.config.hand_dilation_px) > 0)
            near = cv2.erode(np.where(valid, depth, 1e3).astype(np.float32), kernel).astype(np.float64)
            self._cache[frame] = (depth, valid, near)
        return self._cache[frame]

    def points(self, frame: int) -> FloatArray:
        """(N, 3) world points of a frame's valid pixels."""
        depth, valid, _ = self.view(frame)
        p_camera = backproject(np.where(valid, depth, 0.0), self.K).reshape(-1, 3)[valid.ravel()]
        return transform_points(self.trajectory.T_world_camera[frame], p_camera)

    def seen_through(self, p_world: FloatArray, frame: int) -> BoolArray:
        """(N,) True where ``frame`` sees farther than the point by the margin (the point is not there)."""
        _, valid, near = self.view(frame)
        q = transform_points(invert_transform(self.trajectory.T_world_camera[frame]), p_world)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.rint(self.K[0, 0] * q[:, 0] / q[:, 2] + self.K[0, 2])
            v = np.rint(self.K[1, 1] * q[:, 1] / q[:, 2] + self.K[1, 2])
        h, w = valid.shape
        inside = (q[:, 2] > 0.1) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        out = np.zeros(len(p_world), dtype=bool)
        rows, cols, z = v[inside].astype(int), u[inside].astype(int), q[inside, 2]
        observed = near[rows, cols]
        margin = self.config.margin_m + self.config.margin_per_m * z
        out[inside] = valid[rows, cols] & (observed < 1e3) & (observed > z + margin)
        return out


def _surface_that_left(views: _Views) -> tuple[FloatArray, IntArray]:
    """(M, 3) world points of frame 0's surface that at least ``min_frames`` later frames see through, and (F,)
    how many of them each frame sees through (0 in frame 0)."""
    p_world = views.points(0)
    through = np.stack([views.seen_through(p_world, frame) for frame in range(1, len(views.capture))])  # (F - 1, N)
    left = through.sum(axis=0) >= views.config.min_frames
    return p_world[left], np.concatenate([[0], through[:, left].sum(axis=1)])


def _arrived(views: _Views, frames: IntArray) -> tuple[tuple[FloatArray, ...], IntArray]:
    """(N, 3) world points, per frame, of surfaces in front of what frame 0 saw (frame 0 sees
    through them), at most ``arrival_points`` (evenly subsampled), and how many there were in each frame."""
    out, counts = [], []
    for frame in frames:
        p_world = views.points(int(frame))
        p_world = p_world[views.seen_through(p_world, 0)]
        counts.append(len(p_world))
        n = views.config.arrival_points
        out.append(p_world[np.linspace(0, len(p_world) - 1, n).astype(int)] if len(p_world) > n else p_world)
    return tuple(out), np.asarray(counts, dtype=np.int64)


def _first_frame_over(counts: IntArray, min_points: int) -> int:
    """The first frame whose count reaches ``min_points`` (or a tenth of the largest count, for a small part);
    ``len(counts)`` if none does.

    With the counts of the surface that left, or that arrived in front of frame 0's view (hands left out), it is
    the first frame in which the scene changed by as much as a part makes: before it the part had not moved.
    Measured, surface that left / arrived per frame before a part moved: 0-4 / 0-23 (one frame) of a plain drawer
    (light_dim_pri_drawer_00_r8, then 52 and 126 left as it moved), 0 / 0-9 of a door (person_slow_rev_cabinet_00_r8,
    whose door, turning towards the camera, hid what lay behind it: 29 then 139 arrived at 8 and 10 deg, while 3,
    16, 36, 68 left only at 12-20 deg), 0 / 0 of a sliding panel (person_elbow_pri_wardrobe_00_r8, then 101 left)."""
    over = np.flatnonzero(counts >= max(1.0, min(min_points, 0.1 * counts.max(initial=0))))
    return int(over[0]) if len(over) else len(counts)


def _front_plane(p: FloatArray, tolerance_m: float, iterations: int = 200
                 ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None:
    """The dominant plane of ``p``: its inlier points, unit normal and two in-plane unit axes
    (along the edges of the inliers' minimum-area rectangle); None if no plane holds 30 % of the points.

    A plain three-point RANSAC with a fixed seed, written here because Open3D's ``segment_plane``
    (the stack's plane fit) takes no seed in the installed version, and a twin must not change
    from one run to the next."""
    rng = np.random.default_rng(0)
    scored = p[np.linspace(0, len(p) - 1, min(len(p), 2000)).astype(int)]  # bounds the (iterations, n) test
    samples = rng.integers(0, len(p), size=(iterations, 3))
    a, b, c = p[samples[:, 0]], p[samples[:, 1]], p[samples[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-9
    if not ok.any():
        return None
    normals, a = normals[ok] / norms[ok, None], a[ok]
    counts = (np.abs((scored[None, :, :] - a[:, None, :]) @ normals[..., None])[..., 0] < tolerance_m).sum(1)
    best = int(np.argmax(counts))
    inliers = np.abs((p - a[best]) @ normals[best]) < tolerance_m
    if inliers.sum() < 0.3 * len(p):
        return None
    x = p[inliers]
    centred = x - x.mean(0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)  # least-squares refit of the inliers' plane
    normal = vt[2]
    # In-plane axes along the edges of the smallest rectangle around the points, not their principal
    # axes: what leaves of a glazed door is its frame's far bars, an L whose principal axes run 30-45 deg
    # across the door's edges (dark_rev_glass_wall_00: hinge 41 deg off).
    uv = np.stack([centred @ vt[0], centred @ vt[1]], 1).astype(np.float32)
    corners = cv2.boxPoints(cv2.minAreaRect(uv))
    edge = corners[1] - corners[0]
    if np.linalg.norm(edge) < 1e-9:
        edge = corners[2] - corners[1]
    edge = edge / max(float(np.linalg.norm(edge)), 1e-12)
    u_axis = edge[0] * vt[0] + edge[1] * vt[1]
    return x, normal, u_axis, np.cross(normal, u_axis)


def _grown_normal(views: _Views, points: FloatArray, normal: FloatArray, config: DepthProposalConfig) -> FloatArray:
    """The front's unit normal (sign of ``normal``) refitted, ``config.front_growth_rounds`` times, on the
    pixels of frame 0's full-resolution depth (hand left out) that lie within ``config.plane_tolerance_m``
    of the current plane in the connected regions that hold the front's ``points`` (N, 3), world frame."""
    depth, K = views.depth0_m, views.capture.intrinsics.K
    H, W = depth.shape
    T_camera_world = invert_transform(views.trajectory.T_world_camera[0])
    p_camera = backproject(depth, K).reshape(H, W, 3)
    valid = depth > 0
    hand = None if views.hand is None else views.hand(0)
    if hand is not None:
        valid &= ~hand
    seeds = transform_points(T_camera_world, points)
    u, v = np.rint(project(seeds, K)[0]).T  # NaN behind the camera
    inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    rows, cols = v[inside].astype(int), u[inside].astype(int)
    n_camera, centre = T_camera_world[:3, :3] @ normal, seeds.mean(0)
    for _ in range(config.front_growth_rounds):
        with np.errstate(invalid="ignore"):
            on = valid & (np.abs((p_camera - centre) @ n_camera) < config.plane_tolerance_m)
        _, labels = cv2.connectedComponents(on.astype(np.uint8), connectivity=4)
        touched = np.unique(labels[rows, cols])
        region = np.isin(labels, touched[touched > 0])
        if region.sum() < 3:
            break
        x = p_camera[region]
        centre = x.mean(0)
        refit = np.linalg.svd(x - centre, full_matrices=False)[2][2]  # least-squares plane of the region
        n_camera = refit if refit @ n_camera > 0 else -refit
    return T_camera_world[:3, :3].T @ n_camera


def _descend(cost: float, joint: tuple[FloatArray, FloatArray | None], steps: int,
             neighbours: Callable[[FloatArray, FloatArray | None, int], list[tuple[FloatArray, FloatArray | None]]],
             score: Callable[[FloatArray, FloatArray | None], float]) -> tuple[float, tuple[FloatArray, FloatArray | None]]:
    """Coordinate descent of a joint (axis, pivot): at step k, take the first of
    ``neighbours(axis, pivot, k)`` that lowers the cost, until none does, then step k + 1.
    The neighbours come in opposite pairs (2i, 2i + 1): after a move, its opposite, which leads
    back to the joint just left (that cost more), is not scored again at that step (each score is
    a state search over the span; 62 of them were a third of plain_rev_cabinet_right_00's
    articulation)."""
    for k in range(steps):
        back = -1  # the opposite of the last move taken at step k
        improved = True
        while improved:
            improved = False
            for i, candidate in enumerate(neighbours(*joint, k)):
                if i == back:
                    continue
                candidate_cost = score(*candidate)
                if candidate_cost < cost:
                    cost, joint, improved, back = candidate_cost, candidate, True, i ^ 1
                    break
    return cost, joint


def _turned(axis: FloatArray, about: FloatArray, degrees: float) -> FloatArray:
    return Rotation.from_rotvec(np.deg2rad(degrees) * about).apply(axis)


def _hinge_neighbours(normal: FloatArray, config: DepthProposalConfig):
    """The hinge line turned within the front's plane (about its normal) and shifted across it by
    the k-th of ``config.hinge_refine_steps_deg`` / ``_m``, in opposite pairs (as :func:`_descend` wants).
    The hypotheses' hinge lines follow the principal axes of the surface that left, which tilt when that surface is not a rectangle aligned
    with the door's edges, and sit on a 3 cm grid of offsets (measured on mw_door_00: 8.5 deg, 2.2 cm)."""
    if len(config.hinge_refine_steps_deg) != len(config.hinge_refine_steps_m):
        raise ValueError("hinge_refine_steps_deg and hinge_refine_steps_m need one entry per step")

    def neighbours(axis: FloatArray, pivot: FloatArray | None, k: int) -> list[tuple[FloatArray, FloatArray | None]]:
        step_deg, step_m = config.hinge_refine_steps_deg[k], config.hinge_refine_steps_m[k]
        across = np.cross(normal, axis)
        return ([(_turned(axis, normal, sign * step_deg), pivot) for sign in (1, -1)]
                + [(axis, pivot + sign * step_m * across) for sign in (1, -1)])

    return neighbours


SLIDE_AGREEMENT_DEG = 10.0
"""The tracks' slide agrees with one of depth's slides within this angle (tracks on a plain front
read its normal up to 8 deg off: plain_pri_drawer_01 at f8e389e)."""
SLIDE_OVERRIDE_RATIO = 0.5
"""Depth's other slide replaces an agreed one only with at most this fraction of its cost: a right
and a wrong joint differ 2-5x once the part has moved (``rival_margin``)."""


def _joint_key(joint_type: str, axis: FloatArray, pivot: FloatArray | None) -> tuple[float, ...]:
    return (float(joint_type == "revolute"), *np.asarray(axis, float), *(() if pivot is None else np.asarray(pivot, float)))


def _best_type(best_of: dict[str, tuple], fits: dict[tuple[float, ...], DepthFit], search: DepthStateConfig
               ) -> tuple | None:
    """The best hypothesis of the joint type whose best explains the depth best: by its mean cost averaged with its
    mean cost over the frames in which either type's best is in mid-motion (:func:`motion_costs`), which tell a
    turn from a slide where both land the surface on something at rest and at the end (a drawer pulled out and
    its front turned down onto the drawer's floor). One type alone, no mid-motion frame, or a best whose states
    reach the end of the ``search`` grid (no state there explains the frames, so its 'motion' is not one: a
    wall cabinet's slide run to 0.9 m while the camera drifted 10 cm, geo_island_rev_wall_00_r4): by mean cost."""
    if not best_of:
        return None
    candidates = sorted(best_of.values(), key=lambda b: b[0])
    if len(candidates) < 2:
        return candidates[0]
    chosen = [fits[_joint_key(*b[1:])] for b in candidates]
    if any(reaches_grid_end(fit, b[1], search) for fit, b in zip(chosen, candidates, strict=True)):
        return candidates[0]
    moving = motion_costs(chosen)
    if not np.isfinite(moving).all():
        return candidates[0]
    scores = [0.5 * (b[0] + m) for b, m in zip(candidates, moving, strict=True)]
    logger.info("depth proposal: %s", ", ".join(f"{b[1]} {b[0]:.3f} overall, {m:.3f} in mid-motion"
                                                for b, m in zip(candidates, moving, strict=True)))
    return candidates[int(np.argmin(scores))]


def _slide_agreeing_with_tracks(best: tuple, slides: list[tuple], rival_axis: FloatArray,
                                fits: dict[tuple[float, ...], DepthFit], search: DepthStateConfig) -> tuple:
    """The tracks' slide agreeing with one of depth's slide hypotheses (``slides``: (cost, type,
    axis, pivot), their ``fits`` by :func:`_joint_key` from the ``search``) is two cues against one:
    that hypothesis stands unless ``best`` explains the surface twice as well. A drawer pulled towards
    a camera above it leaves little surface that a later frame sees through (strips along the gaps
    between fronts), where a slide within the front's plane scored 0.139 against 0.165 along its
    normal, the tracks' slide 1 deg from that normal (geo_island_pri_drawer_00: axis 90 deg off before).

    A slide whose states run to the end of the search explains no frame there (see :func:`_best_type`)
    however well the tracks agree with it: a plain wardrobe panel's tracks, on the arm that pulled it
    sideways, agreed with a slide straight down run to 0.9 m, which the agreement took over the true
    slide (person_elbow_pri_wardrobe_00_r8: 0.201 against 0.125; axis 89.7 deg off)."""
    slides = [b for b in slides if not reaches_grid_end(fits[_joint_key(*b[1:])], "prismatic", search)]
    if not slides:
        return best
    agreeing = max(slides, key=lambda b: abs(float(np.dot(b[2], rival_axis))))
    agrees = abs(float(np.dot(agreeing[2], rival_axis))) > np.cos(np.deg2rad(SLIDE_AGREEMENT_DEG))
    return agreeing if agrees and not best[0] < SLIDE_OVERRIDE_RATIO * agreeing[0] else best


def track_misfit(joint_type: str, axis_world: FloatArray, pivot_world: FloatArray | None, states: FloatArray,
                 tracks: PointTracks, members: IntArray, reference: IntArray, judged: IntArray,
                 min_pairs: int = 6) -> float:
    """Median distance, metres, between where the part's point ``tracks`` (indices ``members``) were seen
    in the ``judged`` frames and where a joint (states (F,) over the tracks' frames) carries them from
    the first of the ``reference`` frames in which each was seen: how far the tracks contradict that
    joint. NaN when fewer than ``min_pairs`` (track, judged frame) pairs exist.

    Depth scores a hypothesis on the surface that left and may be fooled by what the surface's
    points land on; the tracks saw where the part's textured points went. A plain door whose few
    tracks die early agrees with its true hinge over those frames; a drawer's tracks over its whole
    pull contradict a drop-down turn by decimetres."""
    reference, judged = np.asarray(reference), np.asarray(judged)
    seen = tracks.visible[np.ix_(reference, members)]
    has = seen.any(axis=0)
    members, first = members[has], reference[np.argmax(seen, axis=0)][has]  # each member's first reference frame seen in
    if len(members) == 0 or len(judged) == 0:
        return float("nan")
    T = joint_transforms(joint_type, axis_world, pivot_world, states)
    x_canonical = transform_points(invert_transform(T[first]), tracks.p_world[first, members])
    predicted = np.stack([transform_points(T_world_part, x_canonical) for T_world_part in T[judged]])  # (J, M, 3)
    pairs_seen = tracks.visible[np.ix_(judged, members)] & (judged[:, None] > first[None, :])
    pairs = np.linalg.norm(predicted - tracks.p_world[np.ix_(judged, members)], axis=2)[pairs_seen]
    return float(np.median(pairs)) if len(pairs) >= min_pairs else float("nan")


def tracks_refute(proposal: DepthProposal, rival: PartEstimate, tracks: PointTracks,
                  config: DepthProposalConfig = DepthProposalConfig()) -> bool:  # noqa: B008 (frozen)
    """Whether the ``rival`` part's own ``tracks`` (same frames as the proposal's span) refute depth's
    ``proposal``: they saw most of its motion and it misplaces them (:attr:`DepthProposalConfig.track_veto`)."""
    if not config.track_veto:
        return False
    if rival.joint_type == proposal.joint_type == "prismatic":
        # slide against slide is settled on depth's surface (see _slide_agreeing_with_tracks): tracks on a plain
        # front slide with the arm or along its edges and their own slide misfits them by 0.8-1.4 cm, where a
        # veto lost right depth slides (plain_pri_drawer_00 ADD 99 -> 42, plain_pri_drawer_02 lost; reseed 1 two more)
        return False
    frames = rival.frames[~rival.interpolated]
    peak = float(np.abs(proposal.states).max())
    if len(frames) < 2 or peak <= 0.0:
        return False
    watched = proposal.states[frames]
    seen = float(watched.max() - watched.min()) / peak  # the motion that happened while the tracks watched
    own_states = np.zeros(len(proposal.states))
    own_states[rival.frames] = rival.states
    # judged where the tracks' part had moved by at least half its tracked travel: at rest every joint carries
    # the tracks where they were (rev_fridge_01_r1: 4 mm from a hinge 84 deg off over all 81 tracked frames);
    # each track from the first frame it was seen in, for tracks seeded as a door turns replace those that die
    travel = np.abs(own_states[frames])
    judged = frames[travel >= 0.5 * travel.max()]
    depth_misfit = track_misfit(proposal.joint_type, proposal.axis_world, proposal.pivot_world, proposal.states, tracks,
                                rival.track_indices, frames, judged)
    own_misfit = track_misfit(rival.joint_type, rival.axis_world, rival.pivot_world, own_states, tracks,
                              rival.track_indices, frames, judged)
    away = track_distance(proposal, tracks, rival.track_indices)
    refuted = bool(seen >= config.track_veto_seen and own_misfit <= config.track_veto_max_own_m
                   and depth_misfit > config.track_veto_min_m and depth_misfit > config.track_veto_ratio * own_misfit
                   and away <= config.track_veto_max_away_m)
    logger.info("depth proposal: the tracks' %s (%d tracks, frames %d-%d, %.0f %% of depth's motion, %.3f m from its "
                "surface) lie %.3f m from depth's %s and %.3f m from their own joint%s", rival.joint_type,
                len(rival.track_indices), frames[0], frames[-1], 100 * seen, away, depth_misfit, proposal.joint_type,
                own_misfit, ": the tracks' part holds" if refuted else "")
    return refuted


def track_distance(proposal: DepthProposal, tracks: PointTracks, members: IntArray, samples: int = 15) -> float:
    """Median, over the ``members`` of ``tracks``, of each track's nearest approach, metres, to the proposal's
    points posed by its joint in the frames the track is seen in (at most ``samples`` of them, evenly spread):
    whether the tracks are on the part depth proposes at all (inf without a seen member)."""
    T = joint_transforms(proposal.joint_type, proposal.axis_world, proposal.pivot_world, proposal.states)
    posed = proposal.p_world[None] @ np.transpose(T[:, :3, :3], (0, 2, 1)) + T[:, None, :3, 3]  # (F, M, 3), once
    nearest = []
    for member in members:
        frames = np.flatnonzero(tracks.visible[:, member])
        if len(frames):
            frames = frames[np.unique(np.linspace(0, len(frames) - 1, min(samples, len(frames))).astype(int))]
            nearest.append(np.linalg.norm(posed[frames] - tracks.p_world[frames, member][:, None], axis=2).min())
    return float(np.median(nearest)) if nearest else float("inf")


def _hypotheses(p: FloatArray, normal: FloatArray, u_axis: FloatArray, v_axis: FloatArray,
                hinge_offsets_m: tuple[float, ...]) -> list[tuple[str, FloatArray, FloatArray | None]]:
    """Joint hypotheses for a front in the plane (normal, u, v): slides along the normal, u and v;
    turns about lines along u or v through each edge of the points' extent, offset outwards."""
    out: list[tuple[str, FloatArray, FloatArray | None]] = [("prismatic", a.copy(), None) for a in (normal, u_axis, v_axis)]
    centre = p.mean(0)
    for along, across in ((u_axis, v_axis), (v_axis, u_axis)):
        coordinate = (p - centre) @ across
        low, high = np.percentile(coordinate, [1.0, 99.0])
        for edge, outwards in ((low, -1.0), (high, 1.0)):
            for offset in hinge_offsets_m:
                out.append(("revolute", along.copy(), centre + (edge + outwards * offset) * across))
    return out


__all__ = ["DepthProposal", "DepthProposalConfig", "Joint", "propose_part", "proposal_tracks", "track_distance",
           "track_misfit", "tracks_refute"]
