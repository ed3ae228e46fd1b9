"""Stage 3: articulation-aware motion clustering of point tracks and joint initialisation.

Implements the paper's "Articulation-aware motion clustering" (per-track line/circle fits,
HDBSCAN on joint parameters, interaction-consistency score) plus data-driven joint-type
selection and a least-squares joint initialisation per part.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from sklearn.cluster import HDBSCAN

from funrec.geometry.fitting import fit_prismatic_motions, fit_revolute_motions, fit_track_motions, ransac_rigid
from funrec.geometry.joints import joint_transforms
from funrec.geometry.transforms import invert_transform
from funrec.point_tracks import PointTracks
from funrec.typed import BoolArray, FloatArray, IntArray

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ArticulationConfig:
    """Thresholds of stage 3; lengths in metres, angles in radians."""

    min_track_frames: int = 8
    """Visible frames a track needs: a line or circle through fewer noisy samples is unreliable."""
    static_motion_m: float = 0.03
    """eps_s: tracks whose displacement stays below it are static. Depth noise is a few mm at 1 m
    (~1 cm at 2 m) per frame, so a static track's largest deviation over ~100 frames reaches
    ~2 cm; 3 cm keeps it out while a 12 deg door still moves its outer half by more."""
    noise_multiple: float = 4.0
    """A moving track's displacement must also exceed this multiple of its median frame-to-frame
    jitter: a static track reaches ~2x (its q95 deviation ~4 sigma, jitter ~2.2 sigma), so eps_s
    need not be raised for far, noisier points."""
    displacement_quantile: float = 0.95
    """Quantile of the per-frame displacement used as the track's "maximal" displacement, so a
    single depth spike does not make a static track look moving."""
    fit_error_m: float = 0.015
    """eps_f: mean distance between a track and its fitted line/circle (and later the part's
    joint model). A correct fit leaves ~1.3 sigma (off-model part of 3D noise): 1.5 cm admits
    sigma up to ~1 cm and rejects random walks and hand points, which deviate by several cm."""
    min_part_tracks: int = 10
    """Smallest track set accepted as a part (also HDBSCAN's min_cluster_size)."""
    hdbscan_min_samples: int = 5
    """HDBSCAN min_samples: neighbours a track needs to be a cluster core."""
    profile_scale: float = 0.05
    """Unit of the motion-pattern distance 1 - |corr| between two state profiles: tracks of one
    rigid part correlate above ~0.98 at few-mm noise."""
    rigidity_scale_m: float = 0.01
    """Unit of the rigidity distance (std of the distance between two tracks over time): two
    points of one part vary by the depth noise (~5 mm), of different parts by centimetres."""
    axis_scale_rad: float = np.deg2rad(15.0)
    """Unit of the axis-angle distance between two per-track fits (their axes scatter by degrees)."""
    line_scale_m: float = 0.05
    """Unit of the distance between two per-track revolute axis lines."""
    cluster_merge_distance: float = 1.0
    """Soft floor of the distance, in the units above: differences below one unit (e.g.
    correlation 0.95, 15 deg, 1 cm rigidity) are one part's own track scatter."""
    min_arc_rad: float = np.deg2rad(20.0)
    """A per-track circle spanning less arc gives an axis too noisy to compare."""
    min_common_frames: int = 8
    """Frames two tracks must share before their state profiles are compared."""
    min_visible_tracks: int = 6
    """Part tracks that must be visible in a frame (and shared with its keyframe) to fit its motion."""
    keyframe_overlap: float = 0.5
    """Switch keyframe once fewer than this fraction of its tracks remain visible."""
    ransac_inlier_m: float = 0.025
    """RANSAC inlier distance between two frames' points: ~3.5 sigma of the difference of two
    3 mm-noise samples (sqrt(2) * 3 mm * 3 axes)."""
    ransac_iterations: int = 48
    """Three-point hypotheses per frame; 99.9 % success at 50 % outliers needs ~52."""
    rotation_z: float = 5.0
    """A revolute explanation needs the largest rigid rotation to exceed this many noise sigmas."""
    min_rotation_rad: float = np.deg2rad(2.0)
    """...and this angle, so camera-drift rotations of a drawer never make it revolute."""
    rigidity_frame_stride: int = 3
    """Frames between samples of the pairwise-distance rigidity term (motion is smooth; O(N^2)
    per sampled frame)."""
    max_parts: int = 5
    """Rounds of cluster-and-extract; each round can add several parts."""
    evidence_stride: int = 1
    """Evaluate interaction evidence on every n-th frame (bounds mask reads)."""


@dataclass(frozen=True)
class InteractionEvidence:
    """Per-frame, confidence-weighted 2D evidence of which part is being interacted with.

    Queried sparsely: ``lookup(frame, uv)`` receives the projected pixels of the tracks visible
    in that frame and returns the evidence at each, so a capture's masks are read one frame at a
    time. The score of a part is the paper's s = sum_l sum_i o_li C_i e_i(pi(tau_li)).
    """

    lookup: Callable[[int, FloatArray], FloatArray]
    """lookup(frame, uv (M, 2) pixels) -> (M,) evidence in [0, 1] (1 = inside the object mask)."""
    confidence: FloatArray
    """(F,) C_i >= 0 per frame; 0 skips a frame (no mask there)."""
    kind: str = "object_mask"
    """What the evidence is ("object_mask", "hand_proximity", ...); reported, not interpreted."""

    @classmethod
    def from_masks(
        cls, mask_at: Callable[[int], BoolArray | None], confidence: FloatArray, kind: str = "object_mask"
    ) -> InteractionEvidence:
        """Indicator evidence 1[pi(tau) in M_i] from a per-frame (H, W) bool mask reader."""

        def lookup(frame: int, uv: FloatArray) -> FloatArray:
            mask = mask_at(frame)
            if mask is None:
                return np.zeros(len(uv))
            col, row = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
            inside = (row >= 0) & (row < mask.shape[0]) & (col >= 0) & (col < mask.shape[1])
            out = np.zeros(len(uv))
            out[inside] = mask[row[inside], col[inside]]
            return out

        return cls(lookup, np.asarray(confidence, dtype=np.float64), kind)

    @classmethod
    def from_hand_masks(
        cls, hand_mask_at: Callable[[int], BoolArray | None], confidence: FloatArray, radius_px: float = 40.0
    ) -> InteractionEvidence:
        """Hand-proximity evidence exp(-d^2 / 2 r^2), d = pixel distance to the nearest hand pixel."""
        from scipy.ndimage import distance_transform_edt

        def to_distance_evidence(frame: int) -> FloatArray | None:
            hand = hand_mask_at(frame)
            if hand is None or not np.any(hand):
                return None
            d = distance_transform_edt(~np.asarray(hand, dtype=bool))
            return np.exp(-0.5 * (d / radius_px) ** 2)

        return cls.from_masks(to_distance_evidence, confidence, kind="hand_proximity")  # type: ignore[arg-type]


@dataclass(frozen=True)
class JointEvidence:
    """Model-selection evidence for one part: both joint explanations of all its tracks."""

    residual_prismatic_m: float
    """RMS track residual under the prismatic fit, metres."""
    residual_revolute_m: float
    """RMS track residual under the revolute fit, metres."""
    residual_rigid_m: float
    """RMS residual under free per-frame rigid motions (the noise level), metres."""
    bic_prismatic: float
    """BIC of the prismatic model with the rigid residual as noise variance."""
    bic_revolute: float
    """BIC of the revolute model."""
    max_rotation_rad: float
    """Largest rotation angle of the per-frame rigid motions."""
    rotation_noise_rad: float
    """Standard deviation expected for that angle from the noise alone."""


@dataclass(frozen=True)
class PartEstimate:
    """One independently moving part and its initial articulation (world frame)."""

    joint_type: str
    """"revolute" or "prismatic"."""
    axis_world: FloatArray
    """(3,) unit axis; signed so that the largest |state| is positive."""
    pivot_world: FloatArray | None
    """(3,) revolute axis point closest to the origin; None for prismatic."""
    frames: IntArray
    """(F_k,) consecutive frame indices from the first to the last tracked frame."""
    states: FloatArray
    """(F_k,) joint state (rad or m) from the canonical state, which is frames[0] (state 0)."""
    interpolated: BoolArray
    """(F_k,) True where too few tracks were visible and the state is interpolated."""
    track_indices: IntArray
    """(M,) indices of the part's tracks in the input PointTracks."""
    evidence: JointEvidence
    """Why the joint type was chosen."""
    size_score: float
    """Tracks explained by the joint x fraction of the motion cluster it explains."""
    evidence_score: float | None
    """Interaction-consistency score s; None when no evidence was given."""

    @property
    def state_range(self) -> tuple[float, float]:
        """(min, max) of the observed states."""
        return float(self.states.min()), float(self.states.max())


@dataclass(frozen=True)
class ArticulationEstimate:
    """Output of stage 3: moving parts sorted by score; parts[0] is the interacted one."""

    parts: tuple[PartEstimate, ...]
    """Parts found (empty when nothing moves enough)."""
    moving_track_indices: IntArray
    """(K,) tracks that moved more than eps_s."""
    cluster_track_indices: IntArray
    """(K2,) tracks that also passed the line/circle fit (the clustering input)."""
    cluster_labels: IntArray
    """(K2,) HDBSCAN label of each clustered track (-1 = noise)."""

    @property
    def interacted(self) -> PartEstimate | None:
        return self.parts[0] if self.parts else None


def _first_visible(p: FloatArray, vis: BoolArray) -> FloatArray:
    return p[np.argmax(vis, axis=0), np.arange(p.shape[1])]


def _rigidity(p: FloatArray, vis: BoolArray) -> FloatArray:
    """(N, N) standard deviation over shared frames of the distance between two tracks: noise
    level for points of one rigid part, centimetres or more across parts or for the hand."""
    N = p.shape[1]
    s1, s2, n = np.zeros((N, N)), np.zeros((N, N)), np.zeros((N, N))
    for p_f, v_f in zip(p, vis, strict=True):
        q = np.where(v_f[:, None], p_f, 0.0)
        sq = (q**2).sum(1)
        d = np.sqrt(np.maximum(sq[:, None] + sq[None, :] - 2.0 * q @ q.T, 0.0))
        w = np.outer(v_f, v_f)
        s1 += w * d
        s2 += w * d**2
        n += w
    mean = s1 / np.maximum(n, 1)
    return np.where(n >= 2, np.sqrt(np.maximum(s2 / np.maximum(n, 1) - mean**2, 0.0)), np.inf)


def _distance_matrix(fits: dict[str, FloatArray], p: FloatArray, vis: BoolArray, config: ArticulationConfig) -> FloatArray:
    """Pairwise track distance: rigidity + motion-pattern decorrelation + axis angle + axis line.

    The motion pattern compares state profiles by |Pearson correlation| on the frames both
    tracks see, which is invariant to each track's start frame, scale (radius, units) and sign.
    Rigidity separates parts (and the hand) moving at the same time with similar profiles.
    """
    W = vis.T.astype(float)
    X = np.where(vis, fits["states"], 0.0).T
    n_vis = np.maximum(W.sum(1, keepdims=True), 1)
    X = X - (X.sum(1, keepdims=True) / n_vis) * W
    X = X / np.maximum(np.sqrt((X**2).sum(1, keepdims=True) / n_vis), 1e-12)
    n = W @ W.T
    Sx = X @ W.T
    Sxx = (X**2) @ W.T
    Sxy = X @ X.T
    with np.errstate(divide="ignore", invalid="ignore"):
        cov = Sxy - Sx * Sx.T / n
        var = Sxx - Sx**2 / n
        corr = cov / np.sqrt(np.maximum(var * var.T, 1e-300))
    corr = np.where((n >= config.min_common_frames) & np.isfinite(corr), np.clip(corr, -1, 1), 0.0)
    D = (1.0 - np.abs(corr)) / config.profile_scale
    stride = config.rigidity_frame_stride
    D += np.minimum(_rigidity(p[::stride], vis[::stride]), 1e3) / config.rigidity_scale_m
    axis, centre, circle = fits["axis"], fits["centre"], fits["circle"]
    good_circle = circle & (fits["arc"] > config.min_arc_rad)
    angle = np.arccos(np.clip(np.abs(axis @ axis.T), 0.0, 1.0))
    same_kind = np.outer(good_circle, good_circle) | np.outer(~circle, ~circle)
    D += np.where(same_kind, angle / config.axis_scale_rad, 0.0)
    delta = centre[None, :, :] - centre[:, None, :]
    off = np.linalg.norm(delta - (delta * axis[:, None, :]).sum(-1, keepdims=True) * axis[:, None, :], axis=-1)
    line = 0.5 * (off + off.T)
    D += np.where(np.outer(good_circle, good_circle), np.nan_to_num(line, nan=1e3) / config.line_scale_m, 0.0)
    np.fill_diagonal(D, 0.0)
    return D


def _part_motions(
    p: FloatArray, vis: BoolArray, config: ArticulationConfig, rng: np.random.Generator
) -> tuple[FloatArray, BoolArray]:
    """Rigid motion of a track set from its first tracked frame to every frame, by RANSAC
    against keyframes (switched when overlap drops) so drift stays small.

    Returns (F, 4, 4) motions and (F,) bool where a motion was estimated.
    """
    F = len(p)
    T = np.tile(np.eye(4), (F, 1, 1))
    have = np.zeros(F, dtype=bool)
    ok = np.flatnonzero(vis.sum(1) >= config.min_visible_tracks)
    if len(ok) < 2:
        return T, have
    key = prev = ok[0]
    have[key] = True
    for i in ok[1:]:
        common = vis[key] & vis[i]
        if common.sum() < max(config.min_visible_tracks, config.keyframe_overlap * vis[key].sum()) and prev != key:
            key = prev
            common = vis[key] & vis[i]
        if common.sum() < max(config.min_visible_tracks, 3):
            continue
        fit = ransac_rigid(p[key, common], p[i, common], np.ones(common.sum()), config.ransac_inlier_m, rng, config.ransac_iterations)
        T[i] = fit.T_dst_src @ T[key]
        have[i] = True
        prev = i
    return T, have


def _joint_residuals(p: FloatArray, vis: BoolArray, T: FloatArray) -> tuple[FloatArray, float, int]:
    """Per-track mean residual of ``p`` under motions T (F, 4, 4), with each track's canonical
    point the least-squares one (mean of the back-transformed observations).

    Returns (N,) mean residual (inf for tracks with no observation), RSS (m^2), observations.
    """
    T_inv = invert_transform(T)
    back = np.einsum("fij,fnj->fni", T_inv[:, :3, :3], np.where(vis[..., None], p, 0.0)) + T_inv[:, None, :3, 3]
    count = vis.sum(0)
    x = np.where(vis[..., None], back, 0.0).sum(0) / np.maximum(count, 1)[:, None]
    pred = np.einsum("fij,nj->fni", T[:, :3, :3], x) + T[:, None, :3, 3]
    res2 = np.where(vis, ((np.where(vis[..., None], p, 0.0) - pred) ** 2).sum(-1), 0.0)
    mean = np.where(count > 0, np.sqrt(res2).sum(0) / np.maximum(count, 1), np.inf)
    return mean, float(res2.sum()), int(count.sum())


def _fit_joint(p: FloatArray, vis: BoolArray, config: ArticulationConfig, rng: np.random.Generator) -> dict | None:
    """Both joint explanations of one track set, model selection, and the chosen joint.

    Returns None when the motion cannot be followed over two frames, else a dict with the
    joint (type, axis, pivot, states (F,) NaN where untracked, have (F,)) and JointEvidence.
    """
    T_rigid, have = _part_motions(p, vis, config, rng)
    if have.sum() < 2:
        return None
    vis = vis & have[:, None]
    f0 = int(np.argmax(have))
    centre = np.nanmean(np.where(vis[f0][:, None], p[f0], np.nan), axis=0)
    Th = T_rigid[have]
    w = np.ones(len(Th))
    axis_r, pivot_r, theta = fit_revolute_motions(Th, w, centre)
    axis_p, lam = fit_prismatic_motions(Th, w, centre)
    T_rev = np.tile(np.eye(4), (len(p), 1, 1))
    T_pri = T_rev.copy()
    T_rev[have] = joint_transforms("revolute", axis_r, pivot_r, theta)
    T_pri[have] = joint_transforms("prismatic", axis_p, None, lam)
    _, rss_rigid, n_obs = _joint_residuals(p, vis, T_rigid)
    _, rss_rev, _ = _joint_residuals(p, vis, T_rev)
    _, rss_pri, _ = _joint_residuals(p, vis, T_pri)
    n_frames = int(have.sum())
    dof = max(3 * n_obs - 6 * (n_frames - 1) - 3 * p.shape[1], 1)
    sigma2 = max(rss_rigid / dof, 1e-12)
    # BIC with shared unknowns (per-track canonical points) omitted: they cancel in the difference.
    bic_rev = rss_rev / sigma2 + (n_frames - 1 + 4) * np.log(3 * n_obs)
    bic_pri = rss_pri / sigma2 + (n_frames - 1 + 2) * np.log(3 * n_obs)
    max_rotation = float(Rotation.from_matrix(Th[:, :3, :3]).magnitude().max())
    spread2 = np.nanmean(np.sum((np.where(vis[f0][:, None], p[f0], np.nan) - centre) ** 2, -1))
    rotation_noise = float(np.sqrt(sigma2 / max(spread2 * vis.sum(1)[have].mean(), 1e-12)))
    revolute = bic_rev < bic_pri and max_rotation > max(config.rotation_z * rotation_noise, config.min_rotation_rad)
    states = np.full(len(p), np.nan)
    if revolute:
        joint_type, axis, pivot, states[have] = "revolute", axis_r, pivot_r, theta
    else:
        joint_type, axis, pivot, states[have] = "prismatic", axis_p, None, lam
    if states[have][np.argmax(np.abs(states[have]))] < 0:
        axis, states = -axis, -states
    rms = lambda rss: float(np.sqrt(rss / max(n_obs, 1)))  # noqa: E731
    evidence = JointEvidence(rms(rss_pri), rms(rss_rev), rms(rss_rigid), float(bic_pri), float(bic_rev), max_rotation, rotation_noise)
    return {"joint_type": joint_type, "axis": axis, "pivot": pivot, "states": states, "have": have, "evidence": evidence}


def _joint_track_error(p: FloatArray, vis: BoolArray, joint: dict) -> FloatArray:
    """(N,) mean residual of every track under a fitted joint (inf if unseen in tracked frames)."""
    have = joint["have"]
    T = np.tile(np.eye(4), (len(p), 1, 1))
    T[have] = joint_transforms(joint["joint_type"], joint["axis"], joint["pivot"], joint["states"][have])
    return _joint_residuals(p, vis & have[:, None], T)[0]


def _make_part(joint: dict, members: IntArray, size_score: float) -> PartEstimate:
    have = joint["have"]
    frames = np.arange(np.flatnonzero(have)[0], np.flatnonzero(have)[-1] + 1)
    states = np.interp(frames, np.flatnonzero(have), joint["states"][have])
    pivot = joint["pivot"]
    return PartEstimate(
        joint_type=joint["joint_type"],
        axis_world=np.asarray(joint["axis"], dtype=np.float64),
        pivot_world=None if pivot is None else np.asarray(pivot, dtype=np.float64),
        frames=frames.astype(np.int64),
        states=states,
        interpolated=~have[frames],
        track_indices=np.sort(members).astype(np.int64),
        evidence=joint["evidence"],
        size_score=float(size_score),
        evidence_score=None,
    )


def _moving_tracks(p: FloatArray, vis: BoolArray, config: ArticulationConfig) -> IntArray:
    """Tracks seen long enough whose displacement from their first position exceeds eps_s and
    noise_multiple times their own frame-to-frame jitter (depth noise grows with distance)."""
    long_enough = np.flatnonzero(vis.sum(0) >= config.min_track_frames)
    if len(long_enough) == 0:
        return np.zeros(0, dtype=np.int64)
    p, vis = p[:, long_enough], vis[:, long_enough]
    disp = np.where(vis, np.linalg.norm(np.where(vis[..., None], p - _first_visible(p, vis), 0.0), axis=-1), np.nan)
    disp = np.nanquantile(disp, config.displacement_quantile, axis=0)
    both = vis[1:] & vis[:-1]
    step = np.where(both, np.linalg.norm(np.where(both[..., None], p[1:] - p[:-1], 0.0), axis=-1), np.nan)
    with np.errstate(all="ignore"):
        jitter = np.nan_to_num(np.nanmedian(step, axis=0), nan=0.0)
    return long_enough[(disp > config.static_motion_m) & (disp > config.noise_multiple * jitter)].astype(np.int64)


def _cluster(fits: dict[str, FloatArray], p: FloatArray, vis: BoolArray, config: ArticulationConfig) -> list[IntArray]:
    """HDBSCAN labellings (-1 = noise) of tracks from their pairwise joint-parameter distance:
    the best split into several clusters, the single-cluster reading, and last the whole pool
    as one cluster (the root, which HDBSCAN's selection does not return when one part's tracks
    spread out, e.g. at high noise; the joint fit's RANSAC copes with the few others)."""
    D = _distance_matrix(fits, p, vis, config)
    # Distances below cluster_merge_distance are compressed smoothly (no ties) so HDBSCAN does
    # not split a part at scales below its own track scatter. HDBSCAN never returns its root
    # unless allow_single_cluster, and with it eom prefers the root over real splits, so both
    # readings are returned: the caller tries the split first (several parts), then the root
    # (one part whose split gave only small, degenerate pieces). A part split into several
    # clusters is re-joined by the caller, as one cluster's joint absorbs its siblings' tracks.
    D = np.sqrt(D**2 + config.cluster_merge_distance**2)
    np.fill_diagonal(D, 0.0)
    return [
        HDBSCAN(
            min_cluster_size=config.min_part_tracks,
            min_samples=config.hdbscan_min_samples,
            allow_single_cluster=single,
            metric="precomputed",
            copy=True,
        ).fit_predict(D)
        for single in (False, True)
    ] + [np.zeros(len(D), dtype=np.int64)]


def _extract_part(
    seed: IntArray, moving: IntArray, free: BoolArray, p: FloatArray, vis: BoolArray, config: ArticulationConfig,
    rng: np.random.Generator,
) -> tuple[dict, IntArray] | None:
    """Fit a joint to the seed tracks, grow it to every free moving track it explains, refit
    once on that set; None when fewer than min_part_tracks are explained."""
    joint = _fit_joint(p[:, moving[seed]], vis[:, moving[seed]], config, rng)
    members = np.zeros(0, dtype=np.int64)
    for _ in range(2):
        if joint is None:
            return None
        members = np.flatnonzero(free & (_joint_track_error(p[:, moving], vis[:, moving], joint) < config.fit_error_m))
        if len(members) < config.min_part_tracks:
            return None
        if _ == 0:
            joint = _fit_joint(p[:, moving[members]], vis[:, moving[members]], config, rng) or joint
    return joint, members


def _evidence_scores(tracks: PointTracks, parts: list[PartEstimate], evidence: InteractionEvidence, stride: int) -> FloatArray:
    """Paper score s_gamma = sum_l sum_i o_li C_i e_i(uv_li), one mask read per frame."""
    members = np.concatenate([p.track_indices for p in parts])
    labels = np.concatenate([np.full(len(p.track_indices), k) for k, p in enumerate(parts)])
    scores = np.zeros(len(parts))
    for i in range(0, tracks.num_frames, stride):
        if evidence.confidence[i] <= 0:
            continue
        seen = tracks.visible[i, members] & np.isfinite(tracks.uv[i, members]).all(-1)
        if seen.any():
            e = np.asarray(evidence.lookup(i, tracks.uv[i, members[seen]]), dtype=np.float64)
            scores += evidence.confidence[i] * np.bincount(labels[seen], weights=e, minlength=len(parts))
    return scores


def estimate_articulation(
    tracks: PointTracks,
    evidence: InteractionEvidence | None = None,
    config: ArticulationConfig = ArticulationConfig(),  # noqa: B008 (frozen, immutable default)
    rng: np.random.Generator | None = None,
) -> ArticulationEstimate:
    """Find the independently moving parts in world-frame point tracks and initialise their joints.

    Args:
        tracks: N tracks over F frames (world frame, NaN where invisible).
        evidence: interaction evidence; None ranks parts by size x motion coherence.
        config: thresholds.
        rng: generator for RANSAC sampling; None uses ``np.random.default_rng(0)`` so results
            are reproducible.

    Returns:
        :class:`ArticulationEstimate`; its parts are sorted by score, the interacted part first.
        No part is returned when nothing moves by more than eps_s in a joint-consistent way.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    p, vis = tracks.p_world, tracks.visible & np.isfinite(tracks.p_world).all(-1)
    if evidence is not None and np.shape(evidence.confidence) != (tracks.num_frames,):
        raise ValueError(f"evidence.confidence must be ({tracks.num_frames},), got {np.shape(evidence.confidence)}")
    moving = _moving_tracks(p, vis, config)
    empty = ArticulationEstimate((), moving, np.zeros(0, np.int64), np.zeros(0, np.int64))
    if len(moving) < config.min_part_tracks:
        logger.info("%d moving tracks (< %d): no part", len(moving), config.min_part_tracks)
        return empty
    fits = fit_track_motions(p[:, moving], vis[:, moving])
    keep = np.flatnonzero(fits["error"] < config.fit_error_m)
    if len(keep) < config.min_part_tracks:
        return empty
    free = np.ones(len(moving), dtype=bool)
    parts: list[PartEstimate] = []
    first_labels = None
    # Peel parts off: cluster the free well-fitted tracks, extract every cluster a joint explains
    # (its members leave the pool), and re-cluster what is left until nothing new is found.
    for _ in range(config.max_parts):
        pool = keep[free[keep]]
        if len(pool) < config.min_part_tracks:
            break
        sub = {k: (v[:, pool] if k == "states" else v[pool]) for k, v in fits.items()}
        found = False
        for labels in _cluster(sub, p[:, moving[pool]], vis[:, moving[pool]], config):
            first_labels = labels if first_labels is None else first_labels
            for k in sorted((k for k in set(labels.tolist()) if k >= 0), key=lambda k: -np.sum(labels == k)):
                seed = pool[(labels == k) & free[pool]]
                if len(seed) < config.min_part_tracks:
                    continue
                extracted = _extract_part(seed, moving, free, p, vis, config, rng)
                if extracted is not None:
                    joint, members = extracted
                    free[members] = False
                    coherence = float(np.mean(np.isin(seed, members)))
                    parts.append(_make_part(joint, moving[members], len(members) * coherence))
                    logger.info("part %s with %d tracks (coherence %.2f)", joint["joint_type"], len(members), coherence)
                    found = True
            if found:
                break
        if not found:
            break
    if evidence is not None and parts:
        scores = _evidence_scores(tracks, parts, evidence, config.evidence_stride)
        parts = [PartEstimate(**{**part.__dict__, "evidence_score": float(s)}) for part, s in zip(parts, scores, strict=True)]
    parts.sort(key=lambda q: (-(q.evidence_score or 0.0), -q.size_score))
    labels = np.full(len(keep), -1) if first_labels is None else first_labels
    return ArticulationEstimate(tuple(parts), moving, moving[keep].astype(np.int64), labels.astype(np.int64))


__all__ = [
    "ArticulationConfig",
    "ArticulationEstimate",
    "InteractionEvidence",
    "JointEvidence",
    "PartEstimate",
    "estimate_articulation",
]
