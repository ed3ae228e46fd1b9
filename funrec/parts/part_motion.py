"""Stage 5: part poses and articulation refined jointly on a pose graph with loop closures.

Implements the paper's L(T, l, phi) (eq. part_pose_graph) with the poses parametrised as joint
transforms T_i = J(a, p, s_i), so the refined poses are joint transforms by construction (the
problem itself is :mod:`funrec.parts.joint_problem`); then the states of every frame from depth
(:mod:`funrec.parts.depth_states`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares
from scipy.spatial.transform import RigidTransform

from funrec.camera.tracking import CameraTrajectory
from funrec.formats.capture import Capture
from funrec.geometry.fitting import fit_prismatic_motions, fit_revolute_motions, ransac_rigid
from funrec.geometry.joints import closest_point_on_axis_to_origin, joint_transforms
from funrec.geometry.transforms import invert_transform
from funrec.parts.articulation import PartEstimate
from funrec.parts.depth_states import DepthStateConfig, depth_states, oriented_normals
from funrec.parts.joint_problem import PoseEdges, edge_errors, solve_joint
from funrec.parts.point_tracks import PointTracks
from funrec.typed import BoolArray, FloatArray, IntArray

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class PartMotionConfig:
    """Stage-5 settings; lengths in metres, frame offsets in frames."""

    use_pose_graph: bool = True
    """False returns the stage-3 initialisation unchanged (ablation)."""
    use_loop_closures: bool = True
    """False keeps only consecutive-frame edges."""
    use_joint_constraint: bool = True
    """False optimises free SE(3) poses, then fits the joint to them (ablation)."""
    use_track_term: bool = True
    """Add residuals J(s_i) x_l - tau_li of every part track (joint-constrained mode only)."""
    loop_stride: int = 5
    """Every loop_stride-th frame gets loop closures."""
    loop_offsets: tuple[int, ...] = (10, 20, 40, 80)
    """Frame offsets of the loop-closure partners of such a frame."""
    min_correspondences: int = 8
    """Tracks two frames must share for an edge: RANSAC needs 3, and its information matrix
    becomes meaningful with a few more."""
    ransac_inlier_m: float = 0.025
    """RANSAC inlier distance: ~3.5 sigma of the difference of two 3 mm-noise samples."""
    ransac_iterations: int = 64
    """Three-point hypotheses per edge (99.9 % success at 55 % outliers)."""
    loop_regulariser: float = 100.0
    """mu of the paper. A loop's optimal confidence is l = (mu / (mu + f))^2 for its chi-square
    cost f (6 dof when consistent): f = 6 keeps l = 0.89, f = 17 (99 %) 0.73, f = 600 < 0.03."""
    track_weight: float = 1.0
    """Weight of the whitened track residuals relative to the pose-graph terms."""
    track_outlier_sigma: float = 4.0
    """Track observations further than this many noise sigmas (3D) from the initial joint model
    are left out of the track term."""
    max_evaluations: int = 60
    """Residual evaluations allowed to the solver."""
    depth_states: DepthStateConfig = field(default_factory=DepthStateConfig)
    """States of the frames the tracks do not cover, searched in depth along the refined joint
    (needs the capture and camera trajectory)."""
    rest_offset_factor: float = 6.0
    """The canonical state moves to frame 0 when the depth search puts frame 0 more than this
    many grid steps (3 deg, 2.4 cm) from the tracked canonical state; smaller offsets are the
    search's own bias at rest (measured 0.5-1 deg on a closed cabinet door)."""
    max_depth_disagreement: float = 2.0
    """The depth-searched states are dropped (the tracked frames kept) when they differ from the
    trusted tracked states by more than this many tracked-state sigmas (median over the tracked
    frames): the tracked term pulls them within ~1 sigma when the joint and points fit the depth,
    so a larger gap means the depth does not see the part the joint describes."""
    max_point_residual_m: float = 0.02
    """Tracks whose median residual under the refined joint exceeds this are not used as part
    points by the depth search (slipped KLT tracks, hand points)."""


@dataclass(frozen=True)
class PartMotion:
    """Refined articulation and poses of one part (world frame)."""

    joint_type: str
    """"revolute" or "prismatic"."""
    axis_world: FloatArray
    """(3,) unit axis."""
    pivot_world: FloatArray | None
    """(3,) revolute axis point closest to the origin; None for prismatic."""
    frames: IntArray
    """(F_k,) frame indices: those of the stage-3 estimate, or every capture frame when the
    states were searched in depth."""
    states: FloatArray
    """(F_k,) joint states; frames[0] is the canonical state 0."""
    state_range: tuple[float, float]
    """(min, max) of the states."""
    T_world_part: FloatArray
    """(F_k, 4, 4) joint_transforms(joint_type, axis, pivot, states): canonical -> posed part."""
    edge_frames: IntArray
    """(E, 2) frame indices (i, j) of the pose-graph edges."""
    edge_is_loop: BoolArray
    """(E,) True for loop closures, False for consecutive edges."""
    edge_confidence: FloatArray
    """(E,) optimised loop-closure confidence l_ij in [0, 1] (1 for consecutive edges)."""
    edge_chi2: FloatArray
    """(E,) final f_ij = e^T Omega e of each edge."""
    point_sigma_m: float
    """Track noise estimated from the RANSAC inliers, metres."""
    track_rms_init_m: float
    """RMS track residual under the stage-3 joint, metres."""
    track_rms_m: float
    """RMS track residual under the refined joint, metres."""
    evaluations: int
    """Residual evaluations used by the solver (0 when the pose graph is off)."""


def _pairs(num: int, config: PartMotionConfig) -> list[tuple[int, int, bool]]:
    pairs = [(k, k + 1, False) for k in range(num - 1)]
    if config.use_loop_closures:
        pairs += [(k, k + d, True) for k in range(0, num, config.loop_stride) for d in config.loop_offsets if k + d < num]
    return pairs


def _measure_edges(p: FloatArray, vis: BoolArray, config: PartMotionConfig,
                   rng: np.random.Generator) -> tuple[PoseEdges, float] | None:
    """RANSAC every pair; Omega = sum_k A_k^T A_k / sigma_r^2 with A_k = [-[q_k]x, I], the
    Gauss-Newton information of a rigid fit of the inliers q_k (relative to their centroid). None
    when no frame pair shares ``min_correspondences`` inlier tracks."""
    rows, rms = [], []
    for i, j, loop in _pairs(len(p), config):
        common = np.flatnonzero(vis[i] & vis[j])
        if len(common) < config.min_correspondences:
            continue
        fit = ransac_rigid(p[i, common], p[j, common], np.ones(len(common)), config.ransac_inlier_m, rng, config.ransac_iterations)
        if fit.inliers.sum() < config.min_correspondences:
            continue
        q = p[j, common[fit.inliers]]
        centre = q.mean(0)
        q = q - centre
        info = np.zeros((6, 6))
        info[:3, :3] = (q**2).sum() * np.eye(3) - q.T @ q
        info[3:, 3:] = len(q) * np.eye(3)
        rows.append((i, j, loop, fit.T_dst_src, centre, info))
        if not loop:
            rms.append(fit.rms_m)
    if not rows:
        return None
    sigma_r = float(np.median(rms if rms else [r[5][3, 3] for r in rows])) / np.sqrt(3.0)
    info = np.stack([r[5] for r in rows]) / sigma_r**2
    L = np.swapaxes(np.linalg.cholesky(info), -1, -2)
    edges = PoseEdges(
        i=np.array([r[0] for r in rows]),
        j=np.array([r[1] for r in rows]),
        loop=np.array([r[2] for r in rows]),
        M=np.stack([r[3] for r in rows]),
        centre=np.stack([r[4] for r in rows]),
        sqrt_info=L,
    )
    return edges, sigma_r / np.sqrt(2.0)


def _solve_free_poses(edges: PoseEdges, T_init: FloatArray, config: PartMotionConfig) -> tuple[FloatArray, FloatArray, int]:
    """Ablation: free SE(3) poses T_i = exp(d_i) T_i^0 (frame 0 fixed) on the same L(T, l).

    The Jacobian is left to scipy's finite differences with its sparsity pattern (each edge
    touches two poses and its confidence), which group columns so few evaluations are needed.
    """
    F, E, n_loop = len(T_init), len(edges.i), int(edges.loop.sum())
    loop_idx = np.flatnonzero(edges.loop)
    mu = np.sqrt(config.loop_regulariser)

    def poses(theta: FloatArray) -> FloatArray:
        T = T_init.copy()
        T[1:] = RigidTransform.from_exp_coords(theta[: 6 * (F - 1)].reshape(-1, 6)).as_matrix() @ T_init[1:]
        return T

    def residuals(theta: FloatArray) -> FloatArray:
        T = poses(theta)
        b = theta[6 * (F - 1) :]
        err = edge_errors(edges, T[edges.j] @ invert_transform(T[edges.i]))
        err[loop_idx] *= b[:, None]
        return np.concatenate([err.ravel(), mu * (b - 1.0)])

    S = sp.lil_matrix((6 * E + n_loop, 6 * (F - 1) + n_loop), dtype=int)
    for e in range(E):
        for f in (edges.i[e], edges.j[e]):
            if f > 0:
                S[6 * e : 6 * e + 6, 6 * (f - 1) : 6 * f] = 1
    S[6 * loop_idx[:, None] + np.arange(6), 6 * (F - 1) + np.arange(n_loop)[:, None]] = 1
    S[6 * E + np.arange(n_loop), 6 * (F - 1) + np.arange(n_loop)] = 1
    theta0 = np.concatenate([np.zeros(6 * (F - 1)), np.ones(n_loop)])
    lb = np.concatenate([np.full(6 * (F - 1), -np.inf), np.zeros(n_loop)])
    ub = np.concatenate([np.full(6 * (F - 1), np.inf), np.ones(n_loop)])
    res = least_squares(residuals, theta0, jac_sparsity=S.tocsr(), bounds=(lb, ub), method="trf", x_scale="jac",
                        max_nfev=config.max_evaluations)
    return poses(res.x), res.x[6 * (F - 1) :], int(res.nfev)


def _solve_joint(part: PartEstimate, edges: PoseEdges, obs: tuple[IntArray, IntArray, FloatArray] | None, sigma_p: float,
                 config: PartMotionConfig) -> tuple[FloatArray, FloatArray | None, FloatArray, FloatArray, FloatArray, int]:
    """:func:`~funrec.parts.joint_problem.solve_joint` with this stage's settings."""
    return solve_joint(part, edges, obs, sigma_p, config.loop_regulariser, config.track_weight, config.max_evaluations)


def _track_rms(p: FloatArray, vis: BoolArray, T: FloatArray) -> tuple[float, FloatArray, FloatArray]:
    """RMS residual of tracks under poses T (F, 4, 4) with least-squares canonical points; also
    the per-observation residual norms (F, M) and the canonical points (M, 3)."""
    T_inv = invert_transform(T)
    p0 = np.where(vis[..., None], p, 0.0)
    back = np.einsum("fij,fnj->fni", T_inv[:, :3, :3], p0) + T_inv[:, None, :3, 3]
    x = np.where(vis[..., None], back, 0.0).sum(0) / np.maximum(vis.sum(0), 1)[:, None]
    pred = np.einsum("fij,nj->fni", T[:, :3, :3], x) + T[:, None, :3, 3]
    res = np.where(vis, np.linalg.norm(p0 - pred, axis=-1), 0.0)
    return float(np.sqrt((res**2).sum() / max(vis.sum(), 1))), res, x


def refine_part_motion(
    tracks: PointTracks,
    estimate_part: PartEstimate,
    config: PartMotionConfig = PartMotionConfig(),  # noqa: B008 (frozen, immutable default)
    rng: np.random.Generator | None = None,
    *,
    capture: Capture | None = None,
    trajectory: CameraTrajectory | None = None,
) -> PartMotion:
    """Refine a part's articulation and poses on the pose graph of its tracks (paper eq. L).

    With the capture and its camera trajectory, the states of every capture frame are then
    searched in depth along the refined joint (:func:`~funrec.parts.depth_states.depth_states`): tracks
    die where a door turns edge-on, long before it is fully open. The part's frames become all
    capture frames and its canonical state that of frame 0.

    Args:
        tracks: the point tracks stage 3 used (world frame).
        estimate_part: one part of stage 3's :class:`~funrec.parts.articulation.ArticulationEstimate`.
        config: switches and thresholds.
        rng: generator for RANSAC sampling; None uses ``np.random.default_rng(0)``.
        capture: the capture (depth read lazily); None keeps the tracked frames only.
        trajectory: its ``T_world_camera`` (F, 4, 4); needed with ``capture``.

    Returns:
        :class:`PartMotion` whose poses are joint transforms of its axis, pivot and states.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    part = estimate_part
    frames = part.frames
    p = tracks.p_world[frames][:, part.track_indices]
    vis = tracks.visible[frames][:, part.track_indices] & np.isfinite(p).all(-1)
    T_init = joint_transforms(part.joint_type, part.axis_world, part.pivot_world, part.states)
    rms_init, res_init, _ = _track_rms(p, vis, T_init)
    no_edges = np.zeros((0, 2), dtype=np.int64)
    measured = _measure_edges(p, vis, config, rng) if config.use_pose_graph else None
    if measured is None:
        if config.use_pose_graph:
            logger.warning("part %s: no two frames share %d rigid part tracks: its joint stays as stage 3 fitted it, "
                           "without the pose-graph refinement", part.joint_type, config.min_correspondences)
        return _output(part, part.axis_world, part.pivot_world, part.states, no_edges, np.zeros(0, bool), np.zeros(0), np.zeros(0),
                       float("nan"), rms_init, rms_init, 0)
    edges, sigma_p = measured
    if config.use_joint_constraint:
        obs = None
        if config.use_track_term:
            good = vis & (res_init < config.track_outlier_sigma * np.sqrt(3.0) * sigma_p)
            good &= good.sum(0) >= 2
            f, track = np.nonzero(good)
            # no track within the outlier bound (the part's tracks all disagree with its joint): the pose
            # edges alone constrain the joint
            obs = (f, np.unique(track, return_inverse=True)[1], p[f, track]) if len(f) else None
        axis, pivot, states, confidence, err, evaluations = _solve_joint(part, edges, obs, sigma_p, config)
    else:
        T, b, evaluations = _solve_free_poses(edges, T_init, config)
        centre = np.nanmean(np.where(vis[0][:, None], p[0], np.nan), axis=0)
        if part.joint_type == "revolute":
            axis, pivot, states = fit_revolute_motions(T, np.ones(len(T)), centre)
        else:
            (axis, states), pivot = fit_prismatic_motions(T, np.ones(len(T)), centre), None
        confidence = np.ones(len(edges.i))
        confidence[edges.loop] = b**2
        err = edge_errors(edges, T[edges.j] @ invert_transform(T[edges.i]))
    if axis @ part.axis_world < 0:  # keep stage 3's orientation (largest |state| positive)
        axis, states = -axis, -states
    states = states - states[0]
    T_final = joint_transforms(part.joint_type, axis, pivot, states)
    rms_final, res_final, x = _track_rms(p, vis, T_final)
    logger.info("part %s refined: track rms %.4f -> %.4f m in %d evaluations", part.joint_type, rms_init, rms_final, evaluations)
    if capture is not None and trajectory is not None and config.depth_states.enabled:
        median = np.nanmedian(np.where(vis, res_final, np.nan), axis=0)
        good = (vis.sum(0) >= 2) & (median < config.max_point_residual_m)
        # direction from each canonical point towards the cameras that saw it, canonical frame
        T_part_world = invert_transform(T_final)
        c_part = np.einsum("fij,fj->fi", T_part_world[:, :3, :3], trajectory.T_world_camera[frames, :3, 3]) + T_part_world[:, :3, 3]
        toward = np.where(vis[..., None], c_part[:, None, :] - x[None], 0.0).sum(0)
        normals = oriented_normals(x[good], toward[good], config.depth_states.normal_radius_m)
        frames, states, axis = _extend_states(capture, trajectory, part, axis, pivot, states, x[good], normals, config)
    return _output(part, axis, pivot, states, np.stack([part.frames[edges.i], part.frames[edges.j]], -1), edges.loop,
                   confidence, (err**2).sum(-1), sigma_p, rms_init, rms_final, evaluations, frames)


def _extend_states(capture: Capture, trajectory: CameraTrajectory, part: PartEstimate, axis: FloatArray,
                   pivot: FloatArray | None, states: FloatArray, points: FloatArray, normals: FloatArray,
                   config: PartMotionConfig) -> tuple[IntArray, FloatArray, FloatArray]:
    """States of every capture frame from depth (tracked states kept where the depth search
    agrees with them; the tracked frames alone when it disagrees overall), re-based to frame 0
    when its state is clearly not the tracked canonical one, and signed so the largest |state| is
    positive. Returns frames (F,), states (F,) and the (possibly flipped) axis (3,)."""
    trusted = ~part.interpolated
    found = depth_states(capture, trajectory, part.joint_type, axis, pivot, points, part.frames, states, trusted,
                         config.depth_states, normals)
    revolute = part.joint_type == "revolute"
    step = config.depth_states.revolute_step_rad if revolute else config.depth_states.prismatic_step_m
    sigma = config.depth_states.track_sigma_rad if revolute else config.depth_states.track_sigma_m
    disagreement = float(np.median(np.abs(found[part.frames] - states)[trusted])) if trusted.any() else 0.0
    if disagreement > config.max_depth_disagreement * sigma:
        logger.warning("part %s: depth states disagree with the tracked states by %.3f (median over %d tracked frames): "
                       "kept the tracked frames only", part.joint_type, disagreement, int(trusted.sum()))
        return part.frames, states, axis
    agree = trusted & (np.abs(found[part.frames] - states) <= 2.0 * step)
    found[part.frames[agree]] = states[agree]
    if abs(found[0]) > config.rest_offset_factor * step:  # tracking began after the part moved: frame 0 is canonical
        found = found - found[0]
    if found[np.argmax(np.abs(found))] < 0:
        axis, found = -axis, -found
    logger.info("part %s states from depth: frames 0-%d, range [%.3f, %.3f] (tracked %d-%d, [%.3f, %.3f])", part.joint_type,
                len(found) - 1, found.min(), found.max(), part.frames[0], part.frames[-1], states.min(), states.max())
    return np.arange(len(found), dtype=np.int64), found, axis


def _output(part: PartEstimate, axis: FloatArray, pivot: FloatArray | None, states: FloatArray, edge_frames: IntArray,
            is_loop: BoolArray, confidence: FloatArray, chi2: FloatArray, sigma_p: float, rms_init: float, rms: float,
            evaluations: int, frames: IntArray | None = None) -> PartMotion:
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    pivot = None if pivot is None else closest_point_on_axis_to_origin(axis, pivot)
    return PartMotion(
        joint_type=part.joint_type,
        axis_world=axis,
        pivot_world=pivot,
        frames=(part.frames if frames is None else np.asarray(frames, dtype=np.int64)).copy(),
        states=np.asarray(states, dtype=np.float64),
        state_range=(float(np.min(states)), float(np.max(states))),
        T_world_part=joint_transforms(part.joint_type, axis, pivot, states),
        edge_frames=np.asarray(edge_frames, dtype=np.int64),
        edge_is_loop=np.asarray(is_loop, dtype=bool),
        edge_confidence=np.asarray(confidence, dtype=np.float64),
        edge_chi2=np.asarray(chi2, dtype=np.float64),
        point_sigma_m=float(sigma_p),
        track_rms_init_m=rms_init,
        track_rms_m=rms,
        evaluations=evaluations,
    )


__all__ = ["PartMotion", "PartMotionConfig", "refine_part_motion"]
