"""Stage 3: moving parts in point tracks, their joint type and a joint fitted to their tracks.

Parts are seeded from the tracks that moved together between two nearby frames (RANSAC), grown
to the tracks that watched the part move and followed its joint, and fitted as one joint with
per-frame states (:mod:`funrec.geometry.joint_tracks`); the joint type is chosen between both
grown explanations. The paper's interaction-consistency score ranks the parts. The paper's
per-track line/circle fits clustered by HDBSCAN were replaced: on rendered captures a fast
door's tracks live a few frames each, too short for their own fits, while KLT drift made a few
percent of the static tracks look moving and formed clusters of their own.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from funrec.geometry.fitting import fit_prismatic_motions, fit_revolute_motions, ransac_rigid
from funrec.geometry.joint_tracks import canonical_points, fit_joint_to_tracks, track_groups
from funrec.geometry.track_paths import despike, distance_spread, first_visible, jitter, joint_consistency
from funrec.parts.point_tracks import PointTracks
from funrec.typed import BoolArray, FloatArray, IntArray

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ArticulationConfig:
    """Thresholds of stage 3; lengths in metres, angles in radians."""

    min_track_frames: int = 8
    """Visible frames a track needs to count as moving (its spike filter and jitter need a few)."""
    static_motion_m: float = 0.03
    """eps_s: tracks whose displacement stays below it are static. Depth noise is a few mm at 1 m
    (~1 cm at 2 m) per frame, so a static track's largest deviation over ~100 frames reaches
    ~2 cm; 3 cm keeps it out while a 12 deg door still moves its outer half by more."""
    noise_multiple: float = 4.0
    """A moving track's displacement must also exceed this multiple of its median frame-to-frame
    jitter: a static track reaches ~2x (its q95 deviation ~4 sigma, jitter ~2.2 sigma), so eps_s
    need not be raised for far, noisier points."""
    fit_error_m: float = 0.015
    """eps_f: mean distance between a track and its fitted line/circle (and later the part's
    joint model). A correct fit leaves ~1.3 sigma (off-model part of 3D noise): 1.5 cm admits
    sigma up to ~1 cm and rejects random walks and hand points, which deviate by several cm."""
    min_part_tracks: int = 10
    """Smallest track set accepted as a part (also HDBSCAN's min_cluster_size)."""
    min_visible_tracks: int = 6
    """Part tracks that must be visible in a frame (and shared with its keyframe) to fit its motion."""
    keyframe_overlap: float = 0.5
    """Switch keyframe once fewer than this fraction of its tracks remain visible."""
    ransac_inlier_m: float = 0.025
    """RANSAC inlier distance between two frames' points: ~3.5 sigma of the difference of two
    3 mm-noise samples (sqrt(2) * 3 mm * 3 axes)."""
    ransac_iterations: int = 48
    """Three-point hypotheses per frame; 99.9 % success at 50 % outliers needs ~52."""
    min_rotation_rad: float = np.deg2rad(2.0)
    """A revolute explanation needs the part to turn by more than this, so camera-drift rotations
    of a drawer never make it revolute."""
    max_pivot_distance_m: float = 1.5
    """...and its axis to pass within this distance of one of its tracks (a hinge is on the
    part's edge; a translation is also a tiny rotation about a far-away axis)."""
    track_noise_m: float = 0.01
    """Scale of the robust (Cauchy) weights of track residuals when fitting a joint, metres: KLT
    tracks on rendered and real RGB-D slip by up to ~1-2 cm (measured on funrec.synth kitchens:
    median 0.8 cm, 90 % under 2.2 cm over a track's life)."""
    max_part_nonrigidity_m: float = 0.008
    """A part whose track pairs change their distance by more than this (median over pairs of
    the standard deviation over time) is not rigid and is dropped, metres: measured 1.4-3.3 mm
    for door and drawer tracks on funrec.synth captures, 15 mm for a wiggling hand."""
    max_backward_fraction: float = 0.3
    """A part whose states go below -max_backward_fraction x its largest state is dropped: a
    capture starts with the part at rest at one end of its motion (closed, or open and then
    closed, which the sign convention makes positive), while KLT drift of static tracks under
    camera motion wanders both ways (measured: -0.03..+0.06 m on a funrec.synth walk; real
    openings stay above -5 % of their range)."""
    merge_axis_rad: float = np.deg2rad(10.0)
    """Two parts whose axes differ by less than this (and whose revolute axis lines pass within
    merge_pivot_m) are one part seen by disjoint tracks, e.g. a door's front and inside."""
    merge_explained_fraction: float = 0.8
    """A part whose tracks follow another part's motion at this fraction is merged into it."""
    merge_pivot_m: float = 0.05
    """Largest distance between the axis lines of two revolute parts that are merged, metres."""
    min_part_motion_m: float = 0.05
    """A part whose tracks (90th percentile) travel less than this is dropped, metres: slow KLT
    drift of static tracks under a fast approaching camera forms coherent 2-4 cm "parts"
    (measured on funrec.synth walks), while an opened drawer or door moves by decimetres."""
    rigidity_frame_stride: int = 3
    """Frames between samples of the pairwise-distance rigidity term (motion is smooth; O(N^2)
    per sampled frame)."""
    hypothesis_lags: tuple[int, ...] = (3, 6)
    """Frame offsets of the frame pairs whose rigid motions seed joint hypotheses: 3 frames turn a
    door at 4 deg per frame by 12 deg (a well-defined screw axis) while most of its short tracks
    survive."""
    hypothesis_stride: int = 2
    """Every n-th frame starts a hypothesis pair (bounds the cost: one RANSAC per pair)."""
    join_fraction: float = 0.3
    """A track joins a part only if it watched at least this fraction of the part's travel (90th
    percentile over the part's tracks) while following it: one that saw only the first
    centimetres is as likely a static track drifting."""
    bic_margin_factor: float = 1.0
    """The revolute model (two more parameters) must lower the robust cost by this factor x
    log(scalar residual count): 1 is BIC for a negative log-likelihood (ln n / 2 per parameter)."""
    type_extent_ratio: float = 1.5
    """A joint type whose grown part travels this many times farther than the other type's wins
    outright (see :func:`_extract_part`); closer travels are decided by the robust cost."""
    min_seed_coherence: float = 0.5
    """A part is extracted only when at least this fraction of its seed (the tracks that moved
    together between two frames) follows its grown joint: a part's seed is the part (measured
    0.75-1.0 on bench doors, drawers and the hand), while KLT drift under a fast-walking camera
    gathered a 10-track, 6 cm "drawer" from a seed it kept 12 % of (smoke_static_00)."""
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
    """(K,) the moving tracks again (kept for callers of the clustering version)."""
    cluster_labels: IntArray
    """(K,) index of the extracted part each moving track joined (-1 = none), in extraction
    order (before merging and ranking)."""

    @property
    def interacted(self) -> PartEstimate | None:
        return self.parts[0] if self.parts else None


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


def _initial_joints(p: FloatArray, vis: BoolArray, config: ArticulationConfig,
                    rng: np.random.Generator) -> tuple[dict, dict, float, float] | None:
    """Revolute and prismatic initialisations from rigid motions of the best observed group of
    tracks (RANSAC against keyframes), their largest rotation and the rigid residual (m).
    None when the motion cannot be followed over two frames."""
    _, track_group = track_groups(vis)
    sizes = np.bincount(track_group[track_group >= 0], weights=vis.sum(0)[track_group >= 0])
    if len(sizes) == 0:
        return None
    main = track_group == int(np.argmax(sizes))
    p_main, vis_main = p[:, main], vis[:, main]
    T_rigid, have = _part_motions(p_main, vis_main, config, rng)
    if have.sum() < 2:
        return None
    f0 = int(np.argmax(have))
    centre = np.nanmean(np.where(vis_main[f0][:, None], p_main[f0], np.nan), axis=0)
    Th = T_rigid[have]
    # Frames weighted by their motion: a few-track rigid fit at a static frame is a random
    # rotation of a few degrees, which would otherwise tilt the axis and pull the pivot.
    angle = Rotation.from_matrix(Th[:, :3, :3]).magnitude()
    shift = np.linalg.norm(Th[:, :3, :3] @ centre + Th[:, :3, 3] - centre, axis=1)
    axis_r, pivot_r, theta = fit_revolute_motions(Th, angle**2 + 1e-12, centre)
    axis_p, lam = fit_prismatic_motions(Th, shift**2 + 1e-12, centre)
    states_r, states_p = np.zeros(len(p)), np.zeros(len(p))
    states_r[have], states_p[have] = theta, lam
    # hold the states after the last motion (the rigid chain stops where its tracks end)
    last = np.flatnonzero(have)[-1]
    states_r[last:], states_p[last:] = theta[-1], lam[-1]
    residual = _rigid_residual(p_main, vis_main & have[:, None], T_rigid)
    max_rotation = float(Rotation.from_matrix(Th[:, :3, :3]).magnitude().max())
    return ({"axis": axis_r, "pivot": pivot_r, "states": states_r}, {"axis": axis_p, "pivot": None, "states": states_p},
            max_rotation, residual)


def _rigid_residual(p: FloatArray, vis: BoolArray, T: FloatArray) -> float:
    """RMS distance (m) of the tracks to their least-squares canonical points moved by T (F, 4, 4)."""
    x = canonical_points(T, p, vis.astype(np.float64))
    pred = np.einsum("fij,nj->fni", T[:, :3, :3], np.nan_to_num(x)) + T[:, None, :3, 3]
    r2 = np.where(vis, ((np.where(vis[..., None], p, 0.0) - pred) ** 2).sum(-1), 0.0)
    return float(np.sqrt(r2.sum() / max(vis.sum(), 1)))


def _robust_cost(residual: FloatArray, scale_m: float) -> float:
    """Sum of log(1 + (r / scale)^2) over the observed residuals (NaN = unobserved): the
    negative log-likelihood of Cauchy noise, so that outlier tracks cannot decide the model."""
    r = residual[np.isfinite(residual)]
    return float(np.sum(np.log1p((r / scale_m) ** 2)))


def _fit_joint(p: FloatArray, vis: BoolArray, config: ArticulationConfig, rng: np.random.Generator,
               joint_type: str | None = None, previous: dict | None = None, polish: bool = True) -> dict | None:
    """Both joint explanations of one track set, fitted to the tracks themselves
    (:func:`~funrec.geometry.joint_tracks.fit_joint_to_tracks`), and model selection.

    The revolute model is chosen when its robust cost is lower by more than a BIC-style margin
    (two more parameters, ``log`` of the observation count each) and the door turned by more than
    ``min_rotation_rad``: a drawer is also a rotation about a far-away pivot by a tiny angle.

    Returns None when the motion cannot be followed, else a dict with the joint (joint_type, axis,
    pivot, states (F,), have (F,) frames from the first to the last observed frame, interpolated
    (F,) frames without support), used (N,) tracks it explains and JointEvidence. ``previous``
    (a result of this function on a related track set) is a second starting point of its joint
    type; the better fit of the two starts is kept (alternation finds local minima).
    """
    types = ("revolute", "prismatic") if joint_type is None else (joint_type,)
    # Growing a part, its previous joint is the start; the rigid-chain start is added for the
    # final (polished) fit only, as alternation from either can stall in a local minimum.
    continuing = previous is not None and types == (previous["joint_type"],) and not polish
    if continuing:
        init_r = init_p = None
        max_rotation_rigid, residual_rigid = previous["evidence"].max_rotation_rad, previous["evidence"].residual_rigid_m
    else:
        init = _initial_joints(p, vis, config, rng)
        if init is None:
            return None
        init_r, init_p, max_rotation_rigid, residual_rigid = init
    fits, costs = {}, {}
    for kind in types:
        starts = [] if continuing else [init_r if kind == "revolute" else init_p]
        if previous is not None and previous["joint_type"] == kind:
            held = previous["states"].copy()
            known = np.flatnonzero(np.isfinite(held))
            held = np.interp(np.arange(len(held)), known, held[known])
            starts.append({"axis": previous["axis"], "pivot": previous["pivot"], "states": held})
        for start in starts:
            fit = fit_joint_to_tracks(kind, start["axis"], start["pivot"], start["states"], p, vis,
                                      config.track_noise_m, config.fit_error_m, polish=False)
            cost = _robust_cost(np.where(vis, fit["residual"], np.nan), config.track_noise_m)
            logger.debug("%s start %d: cost %.1f, %d tracks used", kind, len(fits), cost, int(fit["used"].sum()))
            if kind not in fits or cost < costs[kind]:
                fits[kind], costs[kind] = fit, cost
        if polish:
            best = fits[kind]
            fit = fit_joint_to_tracks(kind, best["axis"], best["pivot"], best["states"], p, vis, config.track_noise_m,
                                      config.fit_error_m, polish=True)
            cost = _robust_cost(np.where(vis, fit["residual"], np.nan), config.track_noise_m)
            if cost < costs[kind]:
                fits[kind], costs[kind] = fit, cost
    if joint_type is None:
        rev = fits["revolute"]
        rotation = float(np.nanmax(np.abs(rev["states"][rev["support"] > 0]), initial=0.0))
        near = np.linalg.norm(rev["x"][rev["used"]] - rev["pivot"], axis=1) if rev["pivot"] is not None else np.zeros(0)
        plausible = len(near) > 0 and float(np.min(near)) < config.max_pivot_distance_m
        # Both costs on the tracks both fits kept: a fit that dropped a track it explains badly
        # would otherwise win by the dropped track's cost (measured: a drop-down oven door typed
        # prismatic because its revolute fit kept one more, poorer track).
        common = vis & (fits["revolute"]["used"] & fits["prismatic"]["used"])[None, :]
        shared = {kind: _robust_cost(np.where(common, f["residual"], np.nan), config.track_noise_m) for kind, f in fits.items()}
        margin = config.bic_margin_factor * np.log(3 * max(int(common.sum()), 1))
        joint_type = ("revolute" if shared["revolute"] < shared["prismatic"] - margin
                      and rotation > config.min_rotation_rad and plausible else "prismatic")
        logger.debug("joint choice: costs rev %.1f pri %.1f (margin %.1f), rotation %.3f rad, pivot plausible %s, "
                     "tracks %d -> %s", shared["revolute"], shared["prismatic"], margin, rotation, plausible,
                     p.shape[1], joint_type)
    fit = fits[joint_type]
    support = fit["support"] > 0
    if support.sum() < 2:
        return None
    frames = np.flatnonzero(support)
    have = np.zeros(len(p), dtype=bool)
    have[frames[0] : frames[-1] + 1] = True
    axis, states = fit["axis"], np.where(have, fit["states"] - fit["states"][frames[0]], np.nan)
    if states[have][np.argmax(np.abs(states[have]))] < 0:
        axis, states = -axis, -states
    rms = {kind: float(np.sqrt(np.nanmean(np.where(vis & f["used"], f["residual"], np.nan) ** 2))) for kind, f in fits.items()}
    evidence = JointEvidence(
        residual_prismatic_m=rms.get("prismatic", float("nan")),
        residual_revolute_m=rms.get("revolute", float("nan")),
        residual_rigid_m=residual_rigid,
        bic_prismatic=costs.get("prismatic", float("nan")),
        bic_revolute=costs.get("revolute", float("nan")),
        max_rotation_rad=max_rotation_rigid,
        rotation_noise_rad=float(config.track_noise_m / max(np.sqrt(np.mean(np.sum((fit["x"] - fit["x"].mean(0)) ** 2, 1))), 1e-6)),
    )
    return {"joint_type": joint_type, "axis": axis, "pivot": fit["pivot"], "states": states, "have": have,
            "interpolated": have & ~support, "used": fit["used"], "evidence": evidence}


def _make_part(joint: dict, members: IntArray, size_score: float) -> PartEstimate:
    have = joint["have"]
    frames = np.flatnonzero(have)
    pivot = joint["pivot"]
    return PartEstimate(
        joint_type=joint["joint_type"],
        axis_world=np.asarray(joint["axis"], dtype=np.float64),
        pivot_world=None if pivot is None else np.asarray(pivot, dtype=np.float64),
        frames=frames.astype(np.int64),
        states=joint["states"][frames],
        interpolated=joint["interpolated"][frames],
        track_indices=np.sort(members).astype(np.int64),
        evidence=joint["evidence"],
        size_score=float(size_score),
        evidence_score=None,
    )


def _moving_tracks(p: FloatArray, vis: BoolArray, config: ArticulationConfig) -> IntArray:
    """Tracks seen long enough whose displacement from their first position exceeds eps_s and
    noise_multiple times their own jitter (depth noise grows with distance).

    The displacement is the largest one of the track's spike-filtered path (see :func:`despike`),
    not a quantile: a track followed over 70 static frames and then 5 frames of a fast door
    opening has its motion in its last 7 % of samples, which a 95 % quantile discards. The jitter
    is the median second difference of the path (scaled to a first difference of white noise),
    so a short track on a fast, smoothly moving part does not count its own motion as noise."""
    long_enough = np.flatnonzero(vis.sum(0) >= config.min_track_frames)
    if len(long_enough) == 0:
        return np.zeros(0, dtype=np.int64)
    p, vis = p[:, long_enough], vis[:, long_enough]
    smooth = despike(p, vis)
    first = first_visible(smooth, vis)
    disp = np.where(vis, np.linalg.norm(np.where(vis[..., None], smooth - first, 0.0), axis=-1), 0.0).max(0)
    noise = jitter(p, vis)
    return long_enough[(disp > config.static_motion_m) & (disp > config.noise_multiple * noise)].astype(np.int64)


def _hypothesis_seeds(p: FloatArray, vis: BoolArray, config: ArticulationConfig,
                      rng: np.random.Generator) -> list[IntArray]:
    """Seeds of parts: for frame pairs a few frames apart, the tracks that moved by more than
    eps_s between them and agree on one rigid motion (RANSAC), largest first.

    Over a few frames a static track drifts by millimetres while an opening door or drawer
    moves by centimetres, so the movers of a pair are the interacted part (and the hand), even
    where slow KLT drift over a whole track makes a few percent of the static tracks look moving.
    A rigid motion between two nearby frames needs only three shared tracks, so a fast door whose
    tracks last a few frames each still gets a seed.
    """
    F = len(p)
    found: list[IntArray] = []
    for lag in config.hypothesis_lags:
        for i in range(0, F - lag, config.hypothesis_stride):
            j = i + lag
            both = np.flatnonzero(vis[i] & vis[j])
            moved = both[np.linalg.norm(p[j, both] - p[i, both], axis=1) > config.static_motion_m]
            if len(moved) < config.min_visible_tracks:
                continue
            fit = ransac_rigid(p[i, moved], p[j, moved], np.ones(len(moved)), config.ransac_inlier_m, rng,
                               config.ransac_iterations)
            if fit.inliers.sum() >= config.min_visible_tracks:
                found.append(moved[fit.inliers])
    found.sort(key=len, reverse=True)
    return found


def _extract_part(
    seed: IntArray, moving: IntArray, free: BoolArray, p: FloatArray, vis: BoolArray, config: ArticulationConfig,
    rng: np.random.Generator,
) -> tuple[dict, IntArray] | None:
    """Grow a part from seed tracks under each joint type and keep the better explanation.

    For each type: fit the joint to the seed, add every free moving track that watched the part
    move and followed it, refit on that set (dropping tracks the joint does not explain), twice.
    The seed alone rarely decides the type (a door seed may have turned by a few degrees while
    seen), the grown parts do: the wrong type can only follow the part while it barely moves
    (a turning door is a straight slide for its first few degrees) and then collects nearly
    static tracks, so the type whose part travels clearly farther wins; similar travels (a
    drawer is also a tiny turn about a far-away axis) are decided by the lower BIC-style cost on
    the union of both track sets (see :func:`_fit_joint`).
    None when neither type keeps min_part_tracks tracks.
    """
    grown = {kind: _grow(seed, moving, free, p, vis, config, rng, kind) for kind in ("revolute", "prismatic")}
    grown = {kind: g for kind, g in grown.items() if g is not None}
    if "revolute" in grown and not _plausible_revolute(grown["revolute"][0], p[:, moving[grown["revolute"][1]]], config):
        del grown["revolute"]
    if not grown:
        return None
    if len(grown) == 1:
        return next(iter(grown.values()))
    (j_r, m_r), (j_p, m_p) = grown["revolute"], grown["prismatic"]
    both = dataclasses.replace(j_r["evidence"], residual_prismatic_m=j_p["evidence"].residual_prismatic_m,
                               bic_prismatic=j_p["evidence"].bic_prismatic)
    j_r["evidence"] = j_p["evidence"] = both
    extent_r = _motion_extent(_make_part(j_r, moving[m_r], 0.0), p)
    extent_p = _motion_extent(_make_part(j_p, moving[m_p], 0.0), p)
    if extent_r > config.type_extent_ratio * extent_p:
        return grown["revolute"]
    if extent_p > config.type_extent_ratio * extent_r:
        return grown["prismatic"]
    union = np.union1d(m_r, m_p)
    decided = _fit_joint(p[:, moving[union]], vis[:, moving[union]], config, rng, previous=j_r)
    return grown["revolute"] if decided is not None and decided["joint_type"] == "revolute" else grown["prismatic"]


def _plausible_revolute(joint: dict, p: FloatArray, config: ArticulationConfig) -> bool:
    """A revolute part must turn by more than ``min_rotation_rad`` about an axis passing within
    ``max_pivot_distance_m`` of one of its tracks: a translation is also a tiny rotation about a
    far-away axis, and camera drift turns a drawer by a degree."""
    states = joint["states"][joint["have"]]
    if np.ptp(states) <= config.min_rotation_rad:
        return False
    x = np.nanmedian(np.where(np.isfinite(p), p, np.nan), axis=0)
    x = x[np.isfinite(x).all(1)]
    v = x - joint["pivot"]
    distance = np.linalg.norm(v - np.outer(v @ joint["axis"], joint["axis"]), axis=1)
    return bool(len(distance) and distance.min() < config.max_pivot_distance_m)


def _grow(seed: IntArray, moving: IntArray, free: BoolArray, p: FloatArray, vis: BoolArray, config: ArticulationConfig,
          rng: np.random.Generator, joint_type: str) -> tuple[dict, IntArray] | None:
    """Seed -> joint of the given type -> add the free moving tracks it explains -> refit, twice."""
    members = seed
    joint = _fit_joint(p[:, moving[members]], vis[:, moving[members]], config, rng, joint_type, polish=False)
    for round_index in range(2):
        if joint is None:
            return None
        members = members[joint["used"]]
        error, swept, witnessed = joint_consistency(p[:, moving], vis[:, moving], joint)
        # Only tracks that watched the part move (and followed it) join: a static track that
        # drifts is also on some circle or line, and one seen only where the part's states are
        # unknown joins through its own group of tracks (see _merge_parts).
        travel = np.quantile(witnessed[members], 0.9)
        needed = max(config.static_motion_m, config.join_fraction * travel)
        joins = (error < config.fit_error_m) & (swept > config.static_motion_m) & (witnessed > needed)
        members = np.union1d(members, np.flatnonzero(free & joins))
        if len(members) < config.min_part_tracks:
            return None
        joint = _fit_joint(p[:, moving[members]], vis[:, moving[members]], config, rng, joint_type, joint,
                           polish=round_index == 1)
    if joint is None or joint["used"].sum() < config.min_part_tracks:
        return None
    return joint, members[joint["used"]]


def _compatible(a: PartEstimate, b: PartEstimate, config: ArticulationConfig) -> bool:
    """Two revolute parts whose axes differ by less than ``merge_axis_rad`` and whose axis
    lines pass within ``merge_pivot_m``: one door seen by tracks that share no frame, e.g. its
    front before and its inside after it turned edge-on to the camera."""
    if a.joint_type != "revolute" or b.joint_type != "revolute":
        return False  # parallel slides are as likely two drawers of one cabinet
    if np.arccos(min(1.0, abs(float(a.axis_world @ b.axis_world)))) > config.merge_axis_rad:
        return False
    n = np.cross(a.axis_world, b.axis_world)
    delta = b.pivot_world - a.pivot_world
    if np.linalg.norm(n) < 1e-9:
        distance = np.linalg.norm(np.cross(delta, a.axis_world))
    else:
        distance = abs(delta @ n) / np.linalg.norm(n)
    return bool(distance < config.merge_pivot_m)


def _explains(a: PartEstimate, b: PartEstimate, p: FloatArray, vis: BoolArray, config: ArticulationConfig) -> bool:
    """Part a's joint and states explain most of part b's tracks (a door split into a part that
    turned and a few tracks that, seen only at its start, looked like a slide)."""
    F = len(p)
    have = np.zeros(F, dtype=bool)
    have[a.frames] = True
    interpolated = np.zeros(F, dtype=bool)
    interpolated[a.frames] = a.interpolated
    states = np.full(F, np.nan)
    states[a.frames] = a.states
    joint = {"joint_type": a.joint_type, "axis": a.axis_world, "pivot": a.pivot_world, "have": have,
             "interpolated": interpolated, "states": states}
    error, _, witnessed = joint_consistency(p[:, b.track_indices], vis[:, b.track_indices], joint)
    follows = (error < config.fit_error_m) & (witnessed > config.static_motion_m)
    return bool(np.mean(follows) >= config.merge_explained_fraction)


def _merge_parts(parts: list[PartEstimate], p: FloatArray, vis: BoolArray, config: ArticulationConfig,
                 rng: np.random.Generator) -> list[PartEstimate]:
    """Merge parts that are one joint: seen by disjoint track groups (:func:`_compatible`; their
    states are joined by :func:`~funrec.geometry.joint_tracks.bridge_states`) or with one's
    tracks following the other's motion (:func:`_explains`); the union is refitted with the
    joint type of the part that explains the other."""
    merged = True
    while merged:
        merged = False
        for i in range(len(parts)):
            for j in range(len(parts)):
                if i == j or not (_compatible(parts[i], parts[j], config) or _explains(parts[i], parts[j], p, vis, config)):
                    continue
                members = np.union1d(parts[i].track_indices, parts[j].track_indices)
                joint = _fit_joint(p[:, members], vis[:, members], config, rng, parts[i].joint_type)
                if joint is None or joint["used"].sum() < config.min_part_tracks:
                    continue
                size = parts[i].size_score + parts[j].size_score
                parts = [q for k, q in enumerate(parts) if k not in (i, j)] + [_make_part(joint, members[joint["used"]], size)]
                merged = True
                break
            if merged:
                break
    return parts


def _rigid(part: PartEstimate, p: FloatArray, vis: BoolArray, config: ArticulationConfig) -> bool:
    """The median over track pairs of the spread of their distance (see :func:`distance_spread`) is
    below ``max_part_nonrigidity_m``: a hand following a handle also moves about the hinge."""
    idx = part.track_indices
    stride = config.rigidity_frame_stride
    spread = distance_spread(p[::stride, idx], vis[::stride, idx])[np.triu_indices(len(idx), 1)]
    spread = spread[np.isfinite(spread)]
    return len(spread) == 0 or float(np.median(spread)) < config.max_part_nonrigidity_m


def _motion_extent(part: PartEstimate, p: FloatArray) -> float:
    """Largest distance (m) a part's tracks travel under its states: the 90th percentile over
    tracks, so a single track far from the axis cannot make a drifting part look opened."""
    x = p[:, part.track_indices][part.frames]
    x = np.nanmedian(np.where(np.isfinite(x), x, np.nan), axis=0)
    x = x[np.isfinite(x).all(1)]
    if len(x) == 0:
        return 0.0
    if part.joint_type == "prismatic":
        return float(np.ptp(part.states))
    v = x - part.pivot_world
    lever = np.linalg.norm(v - np.outer(v @ part.axis_world, part.axis_world), axis=1)
    return float(np.ptp(part.states) * np.quantile(lever, 0.9))


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
    free = np.ones(len(moving), dtype=bool)
    parts: list[PartEstimate] = []
    labels = np.full(len(moving), -1)
    for seed in _hypothesis_seeds(p[:, moving], vis[:, moving], config, rng):
        if len(parts) >= config.max_parts:
            break
        seed = seed[free[seed]]
        if len(seed) < config.min_visible_tracks:
            continue
        extracted = _extract_part(seed, moving, free, p, vis, config, rng)
        if extracted is None:
            continue
        joint, members = extracted
        coherence = float(np.mean(np.isin(seed, members)))
        if coherence < config.min_seed_coherence:
            logger.info("%s part of %d tracks kept %.2f of its seed: not extracted", joint["joint_type"], len(members), coherence)
            continue
        free[members] = False
        labels[members] = len(parts)
        parts.append(_make_part(joint, moving[members], len(members) * coherence))
        logger.info("part %s with %d tracks (seed coherence %.2f)", joint["joint_type"], len(members), coherence)
    parts = _merge_parts(parts, p, vis, config, rng)
    kept = [q for q in parts if _motion_extent(q, p) >= config.min_part_motion_m and _rigid(q, p, vis, config)
            and -q.states.min() <= config.max_backward_fraction * q.states.max()]
    if len(kept) < len(parts):
        logger.info("%d of %d parts moved less than %.2f m, were not rigid or moved both ways from rest: dropped",
                    len(parts) - len(kept), len(parts), config.min_part_motion_m)
    parts = kept
    if evidence is not None and parts:
        scores = _evidence_scores(tracks, parts, evidence, config.evidence_stride)
        parts = [PartEstimate(**{**part.__dict__, "evidence_score": float(s)}) for part, s in zip(parts, scores, strict=True)]
    parts.sort(key=lambda q: (-(q.evidence_score or 0.0), -q.size_score))
    return ArticulationEstimate(tuple(parts), moving, moving.astype(np.int64), labels.astype(np.int64))


def fit_part(tracks: PointTracks, track_indices: IntArray, joint_type: str,
             config: ArticulationConfig = ArticulationConfig(),  # noqa: B008 (frozen)
             size_score: float = 0.0, evidence_score: float | None = None) -> PartEstimate | None:
    """The part made of the given tracks, explained by ``joint_type`` (fitted to them alone);
    None when that joint cannot follow them."""
    p = tracks.p_world[:, track_indices]
    vis = tracks.visible[:, track_indices] & np.isfinite(p).all(-1)
    joint = _fit_joint(p, vis, config, np.random.default_rng(0), joint_type=joint_type)
    if joint is None:
        return None
    return dataclasses.replace(_make_part(joint, np.asarray(track_indices)[joint["used"]], size_score),
                               evidence_score=evidence_score)


def refit_joint(part: PartEstimate, tracks: PointTracks, joint_type: str,
                config: ArticulationConfig = ArticulationConfig()) -> PartEstimate | None:  # noqa: B008 (frozen)
    """The tracks of ``part`` explained by ``joint_type``, fitted on their own (the other
    explanation of the same motion, for a decision made on other evidence, e.g. depth); None
    when that joint cannot follow them. ``part.track_indices`` index ``tracks``."""
    return fit_part(tracks, part.track_indices, joint_type, config, part.size_score, part.evidence_score)


__all__ = [
    "fit_part",
    "refit_joint",
    "ArticulationConfig",
    "ArticulationEstimate",
    "InteractionEvidence",
    "JointEvidence",
    "PartEstimate",
    "estimate_articulation",
]
