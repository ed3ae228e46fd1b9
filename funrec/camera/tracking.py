"""Camera tracking: camera-to-world poses of every frame, robust to the hand and moving parts.

Frame-to-keyframe registration (KLT tracks lifted with depth, rigid 3D RANSAC), keyframe
loop closures (ORB + 3D RANSAC) and an Open3D pose graph. Classical stand-in for the
paper's RoMa + SupeRANSAC + pose graph.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import cache, cached_property, partial

import cv2
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from funrec.camera.depth_odometry import DepthOdometryConfig, DepthView, depth_view, register_depth, surface_agreement
from funrec.camera.features import (
    DepthNoiseModel,
    corner_snr,
    detect_corners,
    image_noise_sigma,
    information_matrix,
    lift,
    mask_at,
    match_descriptors,
    orb_features,
    refine_rigid,
    rigid_ransac,
    sample_depth,
    track_klt,
    visible_offset_px,
)
from funrec.camera.pose_graph import PoseGraphEdge, optimise_pose_graph
from funrec.errors import ReconstructionError
from funrec.formats.capture import Capture
from funrec.geometry.camera import project
from funrec.geometry.fitting import RigidFit
from funrec.geometry.transforms import invert_transform, pose_difference, transform_points
from funrec.typed import BoolArray, FloatArray, IntArray, UInt8Array

logger = logging.getLogger(__name__)

Progress = Callable[[int, int], None]
"""progress(done, total): called once per processed frame."""


@dataclass(frozen=True)
class CameraTrajectory:
    """Estimated camera poses of a capture."""

    T_world_camera: FloatArray
    """(F, 4, 4) camera-to-world transform of every frame; world = camera frame of frame 0
    unless stated otherwise."""
    keyframes: IntArray
    """(K,) frame indices used as keyframes in the pose graph."""
    tracked: BoolArray
    """(F,) True where the frame was registered; False where its pose was interpolated."""
    inliers: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """(F,) number of rigid-inlier correspondences of each frame's registration (0 where
    untracked); empty when not recorded."""

    def __post_init__(self) -> None:
        F = len(self.T_world_camera)
        if np.shape(self.T_world_camera) != (F, 4, 4) or np.shape(self.tracked) != (F,):
            raise ValueError(
                f"T_world_camera must be (F, 4, 4) and tracked (F,), got {np.shape(self.T_world_camera)}, {np.shape(self.tracked)}"
            )
        if len(self.inliers) not in (0, F):
            raise ValueError(f"inliers must be (F,) = ({F},) or empty, got {np.shape(self.inliers)}")


@dataclass(frozen=True)
class TrackingConfig:
    """Settings of :func:`track_camera`; defaults suit 640x480 Kinect-class RGB-D at 15-30 fps."""

    max_features: int = 500
    """Corners tracked from each keyframe."""
    corner_quality: float = 0.005
    """Shi-Tomasi response relative to the strongest corner; low so that weakly textured
    walls still get corners."""
    corner_min_distance_px: float = 12.0
    """Minimal spacing of corners, pixels; spreads them over the image."""
    klt_window_px: int = 21
    """Lucas-Kanade window side, pixels."""
    min_corner_snr: float = 3.0
    """A new corner is kept only where its KLT patch stands this far above the frame's own pixel noise
    (:func:`~funrec.camera.features.corner_snr`: the weakest direction's gradient energy over noise's, noise
    measured on each keyframe with :func:`~funrec.camera.features.image_noise_sigma`). A patch of pure noise
    scores 0.8-1.4; KLT follows its noise, which does not move with the scene, and the round trip agrees, so
    such a track lags the scene and still passes every check. On plain_rev_wall_cabinet_00_r2 (a plain
    painted wall and ceiling) 89 % of the corners scored under 2 and the 40 rigid "inliers" of frame 39 all
    sat on bare paint, 15 px from where the true pose puts them: they outvoted a depth fit 0.1 mm off and put
    the camera 5.6 cm off. Corners on real texture score far above it: all those of the TUM fr1_xyz frames
    (median 547), 99 % of those of the textured bench family (median 25). 0: keep every corner (ablation)."""
    klt_pyramid_levels: int = 3
    """Coarser pyramid levels; 3 follows motions of ~60 px per frame at 640x480."""
    klt_max_forward_backward_px: float = 1.0
    """Forward-backward round-trip error above which a track is dropped, pixels."""
    depth_window_px: int = 5
    """Window for the robust depth of a feature, pixels (odd)."""
    depth_max_spread: float = 0.05
    """A window whose depth spread exceeds this fraction of its median is a depth edge."""
    min_depth_m: float = 0.2
    """Readings closer than this are ignored, metres (sensor minimum range)."""
    max_depth_m: float = 5.0
    """Readings farther than this are ignored, metres (noise grows as z^2)."""
    hand_dilation_px: int = 9
    """Hand masks are grown by this many pixels before features in them are discarded
    (mask boundaries are imprecise and a KLT window straddling the hand moves with it)."""
    object_weight: float = 0.2
    """Weight of features inside the interacted-object mask in RANSAC (1 = static scene);
    the paper down-weights them rather than dropping them."""
    depth_noise: DepthNoiseModel = DepthNoiseModel()
    """Per-point noise that sets each correspondence's inlier tolerance."""
    refine: bool = False
    """Polish each registration with anisotropic (pixel + axial depth) noise after RANSAC.
    Off by default, by measurement: TUM fr1_xyz ATE 5.9 -> 4.8 mm, but the synthetic smoke
    suite got worse on 2 of 3 sequences (10.7 -> 14.4 mm), where chained KLT positions
    drift more than the 0.5 px the refinement assumes over fast camera motion."""
    inlier_sigmas: float = 3.0
    """Inlier tolerance in standard deviations of the combined noise of both points."""
    ransac_hypotheses: int = 256
    """3-point samples per registration; 256 find an all-inlier sample with probability
    0.999 at a 30 % inlier ratio."""
    min_inliers: int = 25
    """A registration with fewer rigid inliers fails and the frame is interpolated."""
    keyframe_min_inliers: int = 120
    """A new keyframe is made when the inliers to the current keyframe fall below this."""
    keyframe_min_inlier_fraction: float = 0.4
    """... or below this fraction of the features the keyframe started with."""
    keyframe_size_after_first_frame: bool = True
    """The features a keyframe "started with" (``keyframe_min_inlier_fraction``) are those tracked
    into the frame after it, not those seeded: on plain paint most seeds sit on sensor noise and
    are lost at once, so counted from the seeds every frame became a keyframe and the pose was
    chained frame to frame (plain_pri_wardrobe_00: a keyframe on each of frames 41-44, 2 cm of drift;
    camera-only ATE 3.32 -> 1.37 cm, plain_rev_wall_cabinet_00 1.17 -> 0.62). Off: counted from
    the seeds (ablation)."""
    keyframe_max_translation_m: float = 0.25
    """... or when the camera moved farther than this from the keyframe, metres."""
    keyframe_max_rotation_rad: float = math.radians(20.0)
    """... or turned more than this, radians."""
    orb_features: int = 1000
    """ORB features stored per keyframe for loop closure and relocalisation."""
    orb_ratio: float = 0.8
    """Lowe ratio for ORB matches."""
    loop_candidates: int = 3
    """Older keyframes tried for a loop closure at each new keyframe (nearest in pose)."""
    loop_radius_m: float = 1.0
    """Only keyframes whose camera centre is within this distance are tried, metres."""
    loop_angle_rad: float = math.radians(40.0)
    """... and whose viewing direction differs by less than this, radians."""
    loop_min_inliers: int = 40
    """A loop closure (or relocalisation) needs this many rigid ORB inliers."""
    depth_loop_closures: bool = True
    """Where ORB finds no loop closure to a candidate keyframe, register the new keyframe's depth against
    the candidate's (:func:`~funrec.camera.depth_odometry.register_depth`, started from the chained poses,
    with its own checks: fitness, step, how well the surfaces pin the pose) and add that as the closure.
    Plain and dark views give ORB too few matches, so each keyframe was only chained to the last and the
    chain drifted by the few millimetres of every corner or depth registration (dark_rev_fridge_00: 2.1 cm
    over 40 frames of a near-black fridge, 60-100 corners per frame). A closure is kept only where the
    older keyframe's corners do not refute it (:func:`_corners_refute_closure`). Measured, tracking alone
    (ATE as the bench computes it): on 28 fresh captures (``funrec synth --suite families --reseed 1``, none
    run before) the median 0.67 -> 0.60 cm, the mean of the 24 under 5 cm 0.76 -> 0.53, 16 better, 5 worse
    (at most +0.07 cm but for two trajectories already 10-26 cm off, +0.4 and +0.7), 7 unchanged; on 13 of
    the 56 run before dark_rev_fridge_00 2.12 -> 1.10, plain_rev_fridge_00 1.33 -> 0.60,
    light_window_rev_fridge_00 2.13 -> 1.24, person_fast_rev_fridge_00 0.48 -> 0.59. False: ORB closures
    only (ablation)."""
    verify_orb_closures: bool = True
    """An ORB loop closure that disagrees with the chained poses (beyond ``depth_max_disagreement_m`` /
    ``_rad``) is kept only where it puts at least as much of the older keyframe's depth on the new one's
    surface as the chain does (:func:`~funrec.camera.depth_odometry.surface_agreement`): ORB matches on a
    drawer's contents and the arm pushing it closed are rigid among themselves, and closures of theirs between
    keyframes 8 frames apart moved the camera 12 cm (dark_pri_drawer_00_r2). Camera-only ATE there 7.67 ->
    0.45 cm; mw_door_00_r2 1.47 -> 0.66, person_sleeve_rev_cabinet_00 0.19 -> 0.12, rev_cabinet_left_00 0.17 ->
    0.15, 5 other captures of 5 families within 0.02 cm. False: every ORB closure with ``loop_min_inliers`` is
    kept (ablation)."""
    max_stored_keyframes: int = 200
    """Keyframes whose ORB features are kept for loop closure; when full the most
    redundant one (closest in pose to another) is dropped. Bounds memory to ~25 MB."""
    use_pose_graph: bool = True
    """Close loops between keyframes (ORB) and optimise the keyframe pose graph; off keeps the
    chained frame-to-keyframe odometry (ablation)."""
    pose_graph_distance_m: float = 0.03
    """Open3D's max_correspondence_distance: residual scale of the loop-closure line process."""
    depth_odometry: DepthOdometryConfig = DepthOdometryConfig()
    """Register a frame whose corners fail, or are few, by its depth against the keyframe's
    (:mod:`funrec.camera.depth_odometry`; ``enabled = False`` turns the fallback off, ablation).
    Plain walls and doors give too few corners: the dark bench family tracked 30 of 140 frames
    without it."""
    depth_keyframe_min_fitness: float = 0.7
    """A frame registered by depth becomes a keyframe when less than this fraction of its points
    meets the keyframe's (the view has moved on), or under the keyframe motion limits above."""
    depth_max_disagreement_m: float = 0.01
    """Where corners still give a pose (but fewer than ``keyframe_min_inliers``), the depth
    registration, started from it, is used only when it stays within this distance of it,
    metres: farther, the surface fit has been dragged by the hand or the moving part (measured on
    the dark family: a door swinging through the view pulled it 3-6 cm per frame)."""
    depth_max_disagreement_rad: float = math.radians(1.0)
    """... and within this angle, radians."""
    depth_wins_unseen_slides: bool = True
    """Where the two disagree, the depth registration is still taken when it puts the corners no
    farther from where they were tracked, counting only what each corner's patch can show
    (:func:`~funrec.camera.features.visible_offset_px`), than the corners' own pose does: few
    corners on plain walls sit on edges and slide along them, pulling the corners' pose along
    unseen, while a fit dragged by an unmasked hand or a door moves well-seen corners. Measured on
    raw tracking of all 31 bench sequences (8 families): ATE plain_rev_wall_cabinet_00 2.58 ->
    0.70 cm, plain_pri_wardrobe_00 0.86 -> 0.64, plain_rev_fridge_00 0.70 -> 0.41, the others
    unchanged (no frame switched); the test scene with a hand over a quarter of the view keeps
    its corners (median visible offset 2.0 px under the dragged depth fit, 0.05 px under theirs).
    False: the corners always outvote the depth fit (before 2026-11-27)."""
    max_camera_acceleration_m_s2: float = 19.6
    """Where the corners' pose and the depth fit disagree and the corners' pose lies farther from the
    constant-velocity prediction than this acceleration allows in one frame (a dt^2, dt = 1 / fps: 8.7 cm
    at 15 fps) while the depth fit's does not, the depth fit gives the pose. 2 g: a walking head
    accelerates by 0.3-0.5 g, reaching and turning by about 1 g. Measured on person_fast_rev_fridge_00 (a
    plain fridge front filling the view): 27 corners dragged along the front's outline put the camera 15.5 cm
    from the prediction in one frame, and refuted the depth fit that stayed on it (camera ATE 13.0 cm)."""
    second_motion: bool = True
    """Where the corners that the largest rigid motion leaves out hold a second rigid motion of at least
    ``min_inliers`` corners, the camera's is the one nearer the constant-velocity prediction: a part that
    starts to move jumps away from the prediction while the room carries on with the camera (sequential
    RANSAC, one more round on the outliers). Without it a textured drawer filling the view, pulled, took the
    camera with it whenever its corners outnumbered the room's (pri_drawer_02_r1: 13 cm in five frames,
    camera-only ATE 7.04 -> 0.37 cm; pri_drawer_02_r2 2.40 -> 0.33). False: the largest motion is the
    camera's (ablation)."""
    second_motion_by_depth: bool = True
    """Of two rigid motions of the corners (``second_motion``), the camera's is the one that puts more of the
    frame's depth on the keyframe's surface (``surface_agreement``: dense, so a textured door's many corners do
    not outvote the plain room around it); the prediction decides only where a frame has no depth view. False:
    the motion nearer the constant-velocity prediction, which a door that started to move has already pulled
    (ablation)."""
    second_motion_grey_sigmas: float = 5.0
    """... and where the grey level agrees too, within this many times the keyframe's image noise
    (``image_noise_sigma``): depth alone does not see a slide along a plane, and a drawer pulled along a textured
    floor and counter, its front and inside a large share of the view, out-agreed the room in depth alone
    (multi_kitchen_00_r8: camera ATE 1.64 -> 5.28 cm). Measured as a fixed tolerance on rev_fridge_01_r7 and
    multi_kitchen_00_r8: 0.02-0.04 (grey levels in [0, 1]) keeps the room in both, 0.06 takes the drawer; the
    synthetic images' noise is 1.5 grey levels, so 5 sigmas is 0.029, and noisier real images get a wider one."""
    min_tracked_fraction: float = 0.3
    """Fewer registered frames than this fraction raise ReconstructionError."""
    seed: int = 0
    """Seed of the RANSAC random generator."""


@dataclass
class _Keyframe:
    """Loop-closure data of one keyframe (bounded store)."""

    node: int
    frame: int
    T_world_camera: FloatArray
    p_camera: FloatArray
    descriptors: UInt8Array


@dataclass
class _FrameInput:
    gray: UInt8Array
    depth_m: FloatArray
    hand_free: BoolArray
    """(H, W) False on the dilated hand: features there are discarded."""
    seedable: BoolArray
    """(H, W) hand_free and with depth: where new features may be placed."""
    object_mask: BoolArray | None
    _depth_view: tuple[DepthView | None] | None = field(default=None, repr=False)

    @cached_property
    def noise_sigma(self) -> float:
        """The image's pixel noise, grey levels (:func:`~funrec.camera.features.image_noise_sigma`), measured once:
        a keyframe's seeds its corners and weighs the two motions of the frames after it."""
        return image_noise_sigma(self.gray)

    def depth_view(self, K: FloatArray, config: DepthOdometryConfig) -> DepthView | None:
        """The frame's depth view without the hand and the interacted object (they move), built on
        first use and kept: a frame registered by depth is often the next keyframe."""
        if self._depth_view is None:
            usable = self.hand_free if self.object_mask is None else self.hand_free & ~self.object_mask
            self._depth_view = (depth_view(self.gray, self.depth_m, usable, K, config),)
        return self._depth_view[0]


def _read_frame(capture: Capture, frame: int, config: TrackingConfig) -> _FrameInput:
    gray = capture.gray(frame)
    depth = capture.depth_m(frame)
    depth = np.where((depth >= config.min_depth_m) & (depth <= config.max_depth_m), depth, 0.0)
    hand_free = np.ones(depth.shape, dtype=bool)
    hand = capture.mask("hand", frame)
    if hand is not None and hand.any():
        size = 2 * config.hand_dilation_px + 1
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
        hand_free = cv2.dilate(hand.astype(np.uint8), kernel) == 0
    return _FrameInput(gray, depth, hand_free, hand_free & (depth > 0), capture.mask("object", frame))


def _weights(frame: _FrameInput, uv: FloatArray, config: TrackingConfig) -> FloatArray:
    if frame.object_mask is None:
        return np.ones(len(uv))
    return np.where(mask_at(frame.object_mask, uv), config.object_weight, 1.0)


def _lift(frame: _FrameInput, uv: FloatArray, K: FloatArray, config: TrackingConfig) -> FloatArray:
    z = sample_depth(frame.depth_m, uv, config.depth_window_px, config.depth_max_spread)
    return lift(uv, z, K)


def _tolerance(p_a: FloatArray, p_b: FloatArray, K: FloatArray, config: TrackingConfig) -> FloatArray:
    sigma_a = config.depth_noise.sigma_m(p_a[:, 2], K[0, 0])
    sigma_b = config.depth_noise.sigma_m(p_b[:, 2], K[0, 0])
    return config.inlier_sigmas * np.hypot(sigma_a, sigma_b)


def _refine(fit: RigidFit, p_camera: FloatArray, p_keyframe: FloatArray, K: FloatArray,
            config: TrackingConfig) -> FloatArray:
    """T_keyframe_camera polished on the inliers with anisotropic noise (reprojection into
    the keyframe + depth), see :func:`funrec.camera.features.refine_rigid`."""
    if not config.refine:
        return fit.T_dst_src
    p_src, p_dst = p_camera[fit.inliers], p_keyframe[fit.inliers]
    uv_dst = p_dst[:, :2] / p_dst[:, 2:] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    noise = config.depth_noise
    sigma_z = np.hypot(noise.base_m + noise.quadratic_per_m * (p_src[:, 2] - noise.offset_m) ** 2,
                       noise.base_m + noise.quadratic_per_m * (p_dst[:, 2] - noise.offset_m) ** 2)
    return refine_rigid(fit.T_dst_src, p_src, uv_dst, p_dst[:, 2], K, noise.pixel_px, sigma_z)


def _new_corners(frame: _FrameInput, existing_uv: FloatArray, count: int, config: TrackingConfig) -> FloatArray:
    """Corners on usable pixels away from the existing features."""
    mask = frame.seedable.copy()
    if len(existing_uv):
        taken = np.zeros(mask.shape, dtype=np.uint8)
        u = np.clip(np.rint(existing_uv[:, 0]).astype(int), 0, mask.shape[1] - 1)
        v = np.clip(np.rint(existing_uv[:, 1]).astype(int), 0, mask.shape[0] - 1)
        taken[v, u] = 1
        size = 2 * int(config.corner_min_distance_px) + 1
        taken = cv2.dilate(taken, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)))
        mask &= taken == 0
    uv = detect_corners(frame.gray, mask, count, config.corner_quality, config.corner_min_distance_px)
    if config.min_corner_snr > 0 and len(uv):
        snr = corner_snr(frame.gray, uv, config.klt_window_px, frame.noise_sigma)
        uv = uv[snr >= config.min_corner_snr]
    return uv


def _moved_far(T_keyframe_camera: FloatArray, config: TrackingConfig) -> bool:
    """The camera moved or turned beyond the keyframe limits."""
    moved_m, turned_rad = pose_difference(np.eye(4), T_keyframe_camera)
    return moved_m > config.keyframe_max_translation_m or turned_rad > config.keyframe_max_rotation_rad


def _corners_refute(T_keyframe_depth: FloatArray, T_keyframe_features: FloatArray, gray: UInt8Array, uv: FloatArray,
                    p_keyframe: FloatArray, K: FloatArray, config: TrackingConfig) -> bool:
    """Whether the corners (tracked at ``uv``, at ``p_keyframe`` in the keyframe) show the depth
    fit's pose worse than their own: the median of their visible offsets from where each pose
    puts them, see ``TrackingConfig.depth_wins_unseen_slides``."""

    uv_poses = np.stack([project(transform_points(invert_transform(T), p_keyframe), K)[0]
                         for T in (T_keyframe_depth, T_keyframe_features)])
    offset_depth, offset_features = np.median(visible_offset_px(gray, uv, uv_poses, config.klt_window_px), axis=1)
    return bool(offset_depth > offset_features)


def _corners_refute_closure(gray_source: UInt8Array, gray_target: UInt8Array, p_source: FloatArray,
                            T_target_source_depth: FloatArray, T_target_source_chain: FloatArray, K: FloatArray,
                            config: TrackingConfig) -> bool:
    """Whether the source keyframe's corners (``p_source``, its ORB points with depth), tracked into the
    target keyframe from where the chained poses put them, show a depth closure worse than the chain
    does (:func:`_corners_refute` between two keyframes), or too few of them (``min_inliers``) survive
    the tracking to say: the depth fit alone is not trusted across the changes between two keyframes.
    A depth fit between keyframes is dragged where an unmasked hand and a door moved between them and
    the static surfaces left do not pin it (4.5 cm off on the tests' rendered room, where the chain of
    corners was 3 mm off)."""
    uv_source, z = project(p_source, K)
    uv_guess, z_guess = project(transform_points(T_target_source_chain, p_source), K)
    h, w = gray_target.shape
    inside = (z > 0) & (z_guess > 0) & (uv_guess[:, 0] >= 0) & (uv_guess[:, 0] <= w - 1) & (uv_guess[:, 1] >= 0) & (
        uv_guess[:, 1] <= h - 1)
    uv, ok = track_klt(gray_source, gray_target, uv_source[inside], config.klt_window_px, config.klt_pyramid_levels,
                       config.klt_max_forward_backward_px, uv_guess[inside])
    if ok.sum() < config.min_inliers:
        return True
    p = p_source[inside][ok]
    uv_poses = np.stack([project(transform_points(T, p), K)[0] for T in (T_target_source_depth, T_target_source_chain)])
    offset_depth, offset_chain = np.median(visible_offset_px(gray_target, uv[ok], uv_poses, config.klt_window_px), axis=1)
    logger.debug("depth closure: %d corners, visible offset %.2f px (depth) against %.2f (chain)", ok.sum(),
                 offset_depth, offset_chain)
    return bool(offset_depth > offset_chain)


def _continuing_motion(fit: RigidFit, p_src: FloatArray, p_dst: FloatArray, tolerance: FloatArray, weights: FloatArray,
                       T_predicted: FloatArray, rng: np.random.Generator, config: TrackingConfig,
                       agreement: Callable[[FloatArray], float | None] | None = None) -> RigidFit:
    """Of the largest rigid motion of the corners (``fit``) and the largest among the rest, the camera's (see
    ``TrackingConfig.second_motion``): the one that puts more of the frame's depth on the keyframe's
    (``agreement(T_keyframe_camera)``, see ``TrackingConfig.second_motion_by_depth``), else, without depth to
    say, the one nearer the constant-velocity prediction ``T_predicted``."""
    rest = np.flatnonzero(~fit.inliers)
    if len(rest) < config.min_inliers or fit.inliers.sum() < config.min_inliers:
        return fit
    second = rigid_ransac(p_src[rest], p_dst[rest], tolerance[rest], weights[rest], rng, config.ransac_hypotheses)
    if second is None or second.inliers.sum() < config.min_inliers:
        return fit
    by_depth = None
    if agreement is not None and config.second_motion_by_depth:
        first_agrees, second_agrees = agreement(fit.T_dst_src), agreement(second.T_dst_src)
        if first_agrees is not None and second_agrees is not None:
            by_depth = second_agrees > first_agrees
            logger.debug("two rigid motions (%d and %d corners): depth agreement %.2f and %.2f", fit.inliers.sum(),
                         second.inliers.sum(), first_agrees, second_agrees)
    if by_depth is False:
        return fit
    # nearer by how far each carries the corners from where the prediction puts them, not by translation alone:
    # a camera turning slowly in place near a door turning slowly has both motions ~2 cm from the prediction,
    # and the door's by 8 deg more (person_slow_rev_cabinet_00_r3: the door's motion taken 9 times, camera
    # ATE 0.63 -> 2.01 cm, the hinge 88 deg off)
    if by_depth is None and _offset_from(T_predicted, second.T_dst_src, p_src) >= _offset_from(T_predicted, fit.T_dst_src,
                                                                                                 p_src):
        return fit
    inliers = np.zeros(len(p_src), dtype=bool)
    inliers[rest[second.inliers]] = True
    logger.debug("a second rigid motion (%d corners against %d) continues the camera's", inliers.sum(), fit.inliers.sum())
    return replace(second, inliers=inliers)


def _offset_from(T_predicted: FloatArray, T: FloatArray, p: FloatArray) -> float:
    """Median distance, metres, between the points ``p`` (N, 3) carried by ``T`` and by ``T_predicted``."""
    return float(np.median(np.linalg.norm(transform_points(T, p) - transform_points(T_predicted, p), axis=1)))


def _leaps(T_predicted: FloatArray, T: FloatArray, max_leap_m: float) -> bool:
    """A pose farther than ``max_leap_m`` from the constant-velocity prediction (see
    ``TrackingConfig.max_camera_acceleration_m_s2``)."""
    return pose_difference(T_predicted, T)[0] > max_leap_m


def _agree(T_a: FloatArray, T_b: FloatArray, config: TrackingConfig) -> bool:
    """Two estimates of one pose within ``depth_max_disagreement_m`` / ``_rad``."""
    apart_m, apart_rad = pose_difference(T_a, T_b)
    return apart_m <= config.depth_max_disagreement_m and apart_rad <= config.depth_max_disagreement_rad


def _needs_keyframe(T_keyframe_camera: FloatArray, inliers: int, keyframe_size: int, config: TrackingConfig) -> bool:
    """A new keyframe when the features thin out or the camera moved or turned too far."""
    return (inliers < config.keyframe_min_inliers or inliers < config.keyframe_min_inlier_fraction * keyframe_size
            or _moved_far(T_keyframe_camera, config))


def _orb_keyframe(node: int, frame_index: int, frame: _FrameInput, T_world_camera: FloatArray, K: FloatArray,
                  config: TrackingConfig) -> _Keyframe:
    uv, descriptors = orb_features(frame.gray, frame.seedable, config.orb_features)
    p_camera = _lift(frame, uv, K, config)
    valid = np.isfinite(p_camera[:, 2])
    return _Keyframe(node, frame_index, T_world_camera, p_camera[valid], descriptors[valid])


def _register_orb(source: _Keyframe, target: _Keyframe, K: FloatArray, config: TrackingConfig,
                  rng: np.random.Generator) -> tuple[FloatArray, FloatArray] | None:
    """T_target_source and its information matrix from ORB matches, or None."""
    i_src, i_dst = match_descriptors(source.descriptors, target.descriptors, config.orb_ratio)
    if len(i_src) < config.loop_min_inliers:
        return None
    p_src, p_dst = source.p_camera[i_src], target.p_camera[i_dst]
    fit = rigid_ransac(p_src, p_dst, _tolerance(p_src, p_dst, K, config), np.ones(len(p_src)), rng,
                       config.ransac_hypotheses)
    if fit is None or fit.inliers.sum() < config.loop_min_inliers:
        return None
    return fit.T_dst_src, information_matrix(p_dst[fit.inliers])


def _register_keyframe_depth(source: _Keyframe, target: _Keyframe, target_frame: _FrameInput,
                             read_source: Callable[[], _FrameInput], K: FloatArray,
                             config: TrackingConfig) -> tuple[FloatArray, FloatArray] | None:
    """T_target_source and its information matrix from the two keyframes' depth (the source's frame read
    again by ``read_source``: keyframes keep ORB features, not depth), started from their chained poses, or None."""
    if not config.depth_odometry.enabled:
        return None
    view_target = target_frame.depth_view(K, config.depth_odometry)
    source_frame = read_source()
    view_source = source_frame.depth_view(K, config.depth_odometry)
    if view_target is None or view_source is None:
        return None
    T_source_target = invert_transform(source.T_world_camera) @ target.T_world_camera
    fit = register_depth(view_target, view_source, T_source_target, config.depth_odometry)
    if fit is None:
        return None
    T_target_source_depth, T_target_source_chain = invert_transform(fit.T_target_source), invert_transform(T_source_target)
    if _corners_refute_closure(source_frame.gray, target_frame.gray, source.p_camera, T_target_source_depth,
                               T_target_source_chain, K, config):
        return None
    return T_target_source_depth, information_matrix(fit.p_source_matched)


def _depth_refutes_closure(source: _Keyframe, target: _Keyframe, target_frame: _FrameInput,
                           read_source: Callable[[], _FrameInput], K: FloatArray, T_target_source: FloatArray,
                           config: TrackingConfig) -> bool:
    """Whether the two keyframes' depth refutes an ORB closure (see ``TrackingConfig.verify_orb_closures``): it
    puts less of the source's surface on the target's than the chained poses do."""
    if not config.verify_orb_closures or not config.depth_odometry.enabled:
        return False
    T_target_source_chain = invert_transform(target.T_world_camera) @ source.T_world_camera
    if _agree(T_target_source, T_target_source_chain, config):
        return False
    view_target = target_frame.depth_view(K, config.depth_odometry)
    view_source = read_source().depth_view(K, config.depth_odometry)
    if view_target is None or view_source is None:
        return False
    closure, chain = (surface_agreement(view_source, view_target, T, config.depth_odometry)
                      for T in (T_target_source, T_target_source_chain))
    logger.debug("ORB closure %d -> %d: depth agreement %.2f (closure) against %.2f (chain)", source.frame, target.frame,
                 closure, chain)
    return closure < chain


def _pose_distance(T_a: FloatArray, T_b: FloatArray) -> tuple[float, float]:
    """(translation metres, angle between optical axes radians) between two camera poses."""
    cos = float(np.clip(T_a[:3, 2] @ T_b[:3, 2], -1.0, 1.0))
    return float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])), math.acos(cos)


def _loop_candidates(store: list[_Keyframe], T_world_camera: FloatArray, exclude: set[int],
                     config: TrackingConfig) -> list[_Keyframe]:
    scored = []
    for keyframe in store:
        if keyframe.node in exclude:
            continue
        distance, angle = _pose_distance(keyframe.T_world_camera, T_world_camera)
        if distance < config.loop_radius_m and angle < config.loop_angle_rad:
            scored.append((distance / config.loop_radius_m + angle / config.loop_angle_rad, keyframe.node, keyframe))
    return [k for _, _, k in sorted(scored, key=lambda s: (s[0], s[1]))[: config.loop_candidates]]


def _bound_store(store: list[_Keyframe], limit: int) -> None:
    """Drop the most redundant keyframe (nearest in position to another) until within limit;
    the newest keyframe is always kept."""
    while len(store) > limit:
        centres = np.array([k.T_world_camera[:3, 3] for k in store[:-1]])
        gaps = np.linalg.norm(centres[:, None] - centres[None], axis=2) + np.eye(len(centres)) * 1e9
        store.pop(int(np.argmin(gaps.min(axis=1))))


def _optimise(T_world_node: list[FloatArray], edges: list[PoseGraphEdge], config: TrackingConfig) -> FloatArray:
    """Pose graph over keyframes. Edge (s, t, T_t_s, information, uncertain)."""
    if len(T_world_node) < 2 or not any(e[4] for e in edges):
        return np.array(T_world_node)  # a chain without loop closures is already optimal
    return optimise_pose_graph(T_world_node, edges, config.pose_graph_distance_m)[0]


def _interpolate_untracked(T_world_camera: FloatArray, tracked: BoolArray) -> FloatArray:
    """Poses of untracked frames interpolated (slerp / lerp) between tracked neighbours;
    held constant after the last tracked frame."""
    known = np.flatnonzero(tracked)
    missing = np.flatnonzero(~tracked)
    if len(missing) == 0:
        return T_world_camera
    out = T_world_camera.copy()
    query = np.clip(missing, known[0], known[-1]).astype(float)
    if len(known) == 1:
        out[missing] = T_world_camera[known[0]]
        return out
    slerp = Slerp(known.astype(float), Rotation.from_matrix(T_world_camera[known, :3, :3]))
    out[missing, :3, :3] = slerp(query).as_matrix()
    for axis in range(3):
        out[missing, axis, 3] = np.interp(query, known, T_world_camera[known, axis, 3])
    return out


def track_camera(capture: Capture, config: TrackingConfig = TrackingConfig(),
                 progress: Progress | None = None) -> CameraTrajectory:
    """Estimate the camera-to-world pose of every frame; world = camera frame of frame 0.

    Frames are streamed; memory holds the (F, 4, 4) result plus at most
    ``config.max_stored_keyframes`` keyframes' ORB features.

    Args:
        capture: the RGB-D capture; hand masks (discarded) and object masks (down-weighted)
            are used when present.
        config: tracking settings.
        progress: optional callback ``progress(done, total)`` after each frame.

    Returns:
        The trajectory; frames whose registration failed are interpolated and flagged
        ``tracked = False``.

    Raises:
        ReconstructionError: frame 0 has too few textured pixels with depth, or fewer than
            ``config.min_tracked_fraction`` of the frames could be registered.
    """
    F = len(capture)
    K = capture.intrinsics.K
    rng = np.random.default_rng(config.seed)
    node_of_frame = np.zeros(F, dtype=np.int64)
    T_node_camera = np.tile(np.eye(4), (F, 1, 1))
    tracked = np.zeros(F, dtype=bool)
    inlier_count = np.zeros(F, dtype=np.int64)
    failures: Counter[str] = Counter()
    T_world_node: list[FloatArray] = [np.eye(4)]
    keyframe_frames = [0]
    edges: list[tuple[int, int, FloatArray, FloatArray, bool]] = []
    store: list[_Keyframe] = []
    depth_frames = 0
    max_leap_m = config.max_camera_acceleration_m_s2 / capture.intrinsics.fps**2

    def start_keyframe(frame_index: int, frame: _FrameInput, uv: FloatArray, p_camera: FloatArray):
        uv_new = _new_corners(frame, uv, config.max_features - len(uv), config)
        uv_all = np.concatenate([uv, uv_new])
        p_all = np.concatenate([p_camera, _lift(frame, uv_new, K, config)])
        valid = np.isfinite(p_all[:, 2])
        keyframe = _orb_keyframe(len(T_world_node) - 1, frame_index, frame, T_world_node[-1], K, config)
        return uv_all[valid], p_all[valid], keyframe

    def views(frame: _FrameInput, keyframe: _FrameInput) -> tuple[DepthView, DepthView] | None:
        """The frame's and the keyframe's depth views, or None where either has none."""
        target = keyframe.depth_view(K, config.depth_odometry)
        source = frame.depth_view(K, config.depth_odometry) if target is not None else None
        return None if source is None else (source, target)

    def register_by_depth(frame: _FrameInput, keyframe: _FrameInput, T_guess: FloatArray):
        pair = views(frame, keyframe) if config.depth_odometry.enabled else None
        return None if pair is None else register_depth(*pair, T_guess, config.depth_odometry)

    def agree_in_depth(frame: _FrameInput, keyframe: _FrameInput, T_keyframe_camera: FloatArray) -> float | None:
        pair = views(frame, keyframe)
        if pair is None:
            return None
        grey_tolerance = config.second_motion_grey_sigmas * keyframe.noise_sigma / 255.0
        return surface_agreement(*pair, T_keyframe_camera, config.depth_odometry, grey_tolerance)

    frame = _read_frame(capture, 0, config)
    depth_keyframe = frame
    uv, p_keyframe, current = start_keyframe(0, frame, np.zeros((0, 2)), np.zeros((0, 3)))
    depth_can_track = config.depth_odometry.enabled and frame.depth_view(K, config.depth_odometry) is not None
    if len(uv) < config.min_inliers and not depth_can_track:
        raise ReconstructionError(
            f"{capture.root} (frame 0): only {len(uv)} corners with valid depth, need {config.min_inliers}; "
            f"{np.mean(frame.depth_m > 0):.0%} of pixels have depth in [{config.min_depth_m}, {config.max_depth_m}] m "
            "(textureless view, no depth, or the hand covers the view)"
        )
    store.append(current)
    tracked[0] = True
    keyframe_size = len(uv)
    T_node_previous = np.eye(4)
    T_chain_previous, T_velocity = np.eye(4), np.eye(4)
    previous_gray = frame.gray
    if progress is not None:
        progress(1, F)

    def new_keyframe(frame_index: int, frame: _FrameInput, p_info: FloatArray, uv_kept: FloatArray,
                     p_kept: FloatArray) -> None:
        """Frame ``frame_index``, at T_node_previous from the current keyframe, becomes the next
        keyframe (chain edge, fresh corners beside the kept ones, ORB loop closures)."""
        nonlocal uv, p_keyframe, current, keyframe_size, T_node_previous, depth_keyframe
        parent = len(T_world_node) - 1
        T_world_node.append(T_world_node[parent] @ T_node_previous)
        keyframe_frames.append(frame_index)
        edges.append((parent, parent + 1, invert_transform(T_node_previous), information_matrix(p_info), False))
        node_of_frame[frame_index], T_node_camera[frame_index] = parent + 1, np.eye(4)
        uv, p_keyframe, current = start_keyframe(frame_index, frame, uv_kept, p_kept)
        keyframe_size, T_node_previous = len(uv), np.eye(4)
        depth_keyframe = frame
        closable = store if config.use_pose_graph else []
        for candidate in _loop_candidates(closable, current.T_world_camera, {parent}, config):
            # the older keyframe's frame (its depth view built once) is read at most once, for both checks
            read_source = cache(partial(_read_frame, capture, candidate.frame, config))
            result = _register_orb(candidate, current, K, config, rng)
            if result is not None and _depth_refutes_closure(candidate, current, frame, read_source, K, result[0], config):
                result = None
            if result is None and config.depth_loop_closures:
                result = _register_keyframe_depth(candidate, current, frame, read_source, K, config)
            if result is not None:
                edges.append((candidate.node, current.node, result[0], result[1], True))
        store.append(current)
        _bound_store(store, config.max_stored_keyframes)

    for frame_index in range(1, F):
        frame = _read_frame(capture, frame_index, config)
        uv, ok = track_klt(previous_gray, frame.gray, uv, config.klt_window_px, config.klt_pyramid_levels,
                           config.klt_max_forward_backward_px)
        ok &= mask_at(frame.hand_free, uv)
        uv, p_keyframe = uv[ok], p_keyframe[ok]
        p_camera = _lift(frame, uv, K, config)
        has_depth = np.isfinite(p_camera[:, 2])
        fit = None
        if has_depth.sum() >= config.min_inliers:
            p_src, p_dst = p_camera[has_depth], p_keyframe[has_depth]
            tolerance, weights = _tolerance(p_src, p_dst, K, config), _weights(frame, uv[has_depth], config)
            fit = rigid_ransac(p_src, p_dst, tolerance, weights, rng, config.ransac_hypotheses,
                               prior_T_dst_src=T_node_previous)
            if config.second_motion and fit is not None:
                fit = _continuing_motion(fit, p_src, p_dst, tolerance, weights, T_node_previous @ T_velocity, rng, config,
                                         partial(agree_in_depth, frame, depth_keyframe))
        features_ok = fit is not None and fit.inliers.sum() >= config.min_inliers
        if features_ok:
            T_features = _refine(fit, p_src, p_dst, K, config)
            keep = np.zeros(len(uv), dtype=bool)
            keep[np.flatnonzero(has_depth)[fit.inliers]] = True
            uv, p_keyframe, p_camera = uv[keep], p_keyframe[keep], p_camera[keep]
        # Few corners: the keyframe's depth gives the pose where the corners cannot (where they can,
        # and the depth fit agrees, the corners' pose is kept: measured ATE 3.0-4.7 -> 3.5 mm on
        # three plain and lighting sequences, against 4.1-5.4 mm taking the depth fit's), and it
        # decides when the view has moved on, so that a plain view is registered against one
        # keyframe rather than chained frame to frame (dark family: ATE 34 -> 9 mm).
        weak = not features_ok or len(uv) < config.keyframe_min_inliers
        T_predicted = T_node_previous @ T_velocity
        leaps = features_ok and _leaps(T_predicted, T_features, max_leap_m)
        T_guess = T_features if features_ok and not leaps else T_predicted
        depth_fit = register_by_depth(frame, depth_keyframe, T_guess) if weak else None
        if depth_fit is not None and features_ok and not _agree(depth_fit.T_target_source, T_features, config):
            if leaps and not _leaps(T_predicted, depth_fit.T_target_source, max_leap_m):
                features_ok = False  # the corners' pose leaps where no head goes: the depth fit gives the pose
            elif config.depth_wins_unseen_slides and not _corners_refute(depth_fit.T_target_source, T_features, frame.gray,
                                                                          uv, p_keyframe, K, config):
                features_ok = False  # the corners slid along edges: the depth fit gives the pose
            else:
                depth_fit = None  # the rigid corners outvote a surface fit dragged by the moving hand or door
        if depth_fit is not None:
            T_node_camera[frame_index] = T_node_previous = T_features if features_ok else depth_fit.T_target_source
            node_of_frame[frame_index] = len(T_world_node) - 1
            tracked[frame_index] = True
            inlier_count[frame_index] = len(uv) if features_ok else 0
            depth_frames += not features_ok
            if depth_fit.fitness < config.depth_keyframe_min_fitness or _moved_far(T_node_previous, config):
                kept = (uv, p_camera) if features_ok else (np.zeros((0, 2)), np.zeros((0, 3)))
                new_keyframe(frame_index, frame, depth_fit.p_source_matched, *kept)
        elif features_ok:
            T_node_camera[frame_index] = T_node_previous = T_features
            node_of_frame[frame_index] = len(T_world_node) - 1
            tracked[frame_index] = True
            inlier_count[frame_index] = len(uv)
            if keyframe_frames[-1] == frame_index - 1 and config.keyframe_size_after_first_frame:
                keyframe_size = len(uv)  # see TrackingConfig.keyframe_size_after_first_frame
            if _needs_keyframe(T_node_previous, len(uv), keyframe_size, config):
                new_keyframe(frame_index, frame, p_camera, uv, p_camera)
        else:
            reason = "too few tracked features with depth" if fit is None else "too few rigid inliers"
            failures[reason + (" and no depth registration" if config.depth_odometry.enabled else "")] += 1
            if len(uv) < config.keyframe_min_inliers:
                # Relocalise against stored keyframes near the last pose with ORB.
                T_world_last = T_world_node[-1] @ T_node_previous
                probe = _orb_keyframe(len(T_world_node), frame_index, frame, T_world_last, K, config)
                for candidate in [store[-1], *_loop_candidates(store, T_world_last, {store[-1].node}, config)]:
                    result = _register_orb(candidate, probe, K, config, rng)
                    if result is None:
                        continue
                    T_world_node.append(T_world_node[candidate.node] @ invert_transform(result[0]))
                    keyframe_frames.append(frame_index)
                    edges.append((candidate.node, len(T_world_node) - 1, result[0], result[1], False))
                    node_of_frame[frame_index] = len(T_world_node) - 1
                    tracked[frame_index] = True
                    uv, p_keyframe, current = start_keyframe(frame_index, frame, np.zeros((0, 2)), np.zeros((0, 3)))
                    keyframe_size, T_node_previous = len(uv), np.eye(4)
                    depth_keyframe = frame
                    store.append(current)
                    _bound_store(store, config.max_stored_keyframes)
                    break
            if not tracked[frame_index]:
                node_of_frame[frame_index] = len(T_world_node) - 1
                T_node_camera[frame_index] = T_node_previous
        previous_gray = frame.gray
        # Constant-velocity guess for the next depth registration: the last inter-frame motion, in
        # the camera frame (a pan of 2-3 deg per frame otherwise started the ICP outside its basin
        # and it answered with a sideways slide, measured on the dark family).
        T_chain = T_world_node[node_of_frame[frame_index]] @ T_node_camera[frame_index]
        T_velocity = np.linalg.solve(T_chain_previous, T_chain) if tracked[frame_index] else np.eye(4)
        T_chain_previous = T_chain
        if progress is not None:
            progress(frame_index + 1, F)

    if tracked.mean() < config.min_tracked_fraction:
        reasons = ", ".join(f"{n} frames: {r}" for r, n in failures.most_common())
        raise ReconstructionError(
            f"{capture.root}: only {tracked.sum()} of {F} frames could be registered "
            f"(need {config.min_tracked_fraction:.0%}); {reasons}"
        )
    if failures:
        logger.info("%d of %d frames interpolated: %s", F - tracked.sum(), F, dict(failures))
    if depth_frames:
        logger.info("%d of %d frames registered by depth (too few corners)", depth_frames, F)
    T_world_node_opt = _optimise(T_world_node, edges, config) if config.use_pose_graph else np.array(T_world_node)
    T_world_camera = T_world_node_opt[node_of_frame] @ T_node_camera
    T_world_camera = _interpolate_untracked(T_world_camera, tracked)
    return CameraTrajectory(T_world_camera, np.array(keyframe_frames, dtype=np.int64), tracked, inlier_count)


__all__ = ["CameraTrajectory", "Progress", "TrackingConfig", "track_camera"]
