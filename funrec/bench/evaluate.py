"""Score a twin folder (FORMATS.md section 2) against synthetic ground truth (section 4) with
the metrics of section 5, after mapping each side into its own camera-0 frame.

Where FORMATS.md leaves room, this module decides (see :func:`evaluate_twin`): how parts are
matched, at which joint state the scene chamfer distance is taken, and what ATE means.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from scipy.optimize import linear_sum_assignment

from funrec.bench import metrics
from funrec.errors import FormatError, FunrecError
from funrec.formats.affordances import AFFORDANCES_FILE, TWIN_HAND_MASKS, Affordances, read_affordances
from funrec.formats.camera_poses import read_camera_poses
from funrec.formats.capture import read_mask
from funrec.formats.ground_truth import GroundTruth, read_ground_truth
from funrec.formats.meshes import load_ply
from funrec.formats.twin import ArticulatedPart, read_articulation
from funrec.geometry.joints import joint_transform
from funrec.geometry.transforms import invert_transform, transform_points
from funrec.typed import BoolArray, FloatArray

LOGGER = logging.getLogger(__name__)


@dataclass(frozen=True)
class EvalConfig:
    """Settings of :func:`evaluate_twin`."""

    surface_spacing_m: float = 0.005
    """Predicted meshes are sampled uniformly over their faces with one point per
    ``surface_spacing_m**2`` of area, metres; 5 mm matches the voxel size of funrec.synth's
    true points, so both sides of the chamfer distance have the same density."""
    max_surface_samples: int = 2_000_000
    """Cap on the samples of one predicted mesh (memory bound; 2M covers 50 m^2 at 5 mm)."""
    max_part_points: int = 10000
    """Random subset size of each true part's points for ADD / ADD-S (both poses move the
    same subset, so a perfect prediction still scores exactly 0 error)."""
    match_gate_m: float = 0.25
    """A pair whose part chamfer distance (at the first common frame) exceeds this is not a
    match, metres. About half a cabinet-door width: a rough reconstruction of the right part
    passes, while a neighbouring door or drawer (centres typically 0.3-0.6 m apart) mostly does not."""
    overlap_weight_m: float = 0.05
    """Match cost added, in metres, per unit of predicted tracked frames that the true part
    does not share; breaks ties between parts at similar places tracked at different times."""
    add_max_threshold_m: float = metrics.ADD_AUC_MAX_THRESHOLD_M
    """End of the ADD / ADD-S accuracy-threshold curve, metres."""
    seed: int = 0
    """Seed of the random subsets and surface samples (results are deterministic)."""

    def __post_init__(self) -> None:
        counts = (self.max_surface_samples, self.max_part_points)
        positive = (self.surface_spacing_m, self.match_gate_m, self.add_max_threshold_m)
        if min(counts) < 1 or min(positive) <= 0 or self.overlap_weight_m < 0:
            raise ValueError(f"EvalConfig needs positive counts, gate and threshold and a non-negative overlap weight, got {self}")


@dataclass(frozen=True)
class PartEvaluation:
    """Scores of one true part; metric fields are None when the part failed or has no data."""

    true_name: str
    """Name of the true part in gt.json."""
    joint_type: str
    """True joint type, "revolute" or "prismatic"."""
    predicted_name: str | None = None
    """Name of the matched predicted part, or None."""
    failure: str | None = None
    """Why the part counts as failed (no part found, wrong joint type, no twin); None if scored."""
    match_cost_m: float | None = None
    """Matching cost of the pair, metres."""
    common_frames: int = 0
    """Number of frames tracked in both the prediction and the ground truth."""
    axis_error_deg: float | None = None
    """Axis direction error, degrees in [0, 90]."""
    pivot_error_m: float | None = None
    """Distance between the axis lines, metres; revolute only."""
    state_error: float | None = None
    """Mean state error over the common frames: degrees (revolute) or metres (prismatic)."""
    adds_auc: float | None = None
    """ADD-S area under the 0-10 cm accuracy curve, percent."""
    add_auc: float | None = None
    """ADD area under the 0-10 cm accuracy curve, percent."""
    miou: float | None = None
    """Mean mask IoU over the common tracked frames with a non-empty true mask, percent."""
    contact_error_m: float | None = None
    """Distance from the part's contact point (affordances.json) to the true handle centre,
    metres, both posed at the first common tracked frame (camera-0 frames); None when the
    twin has no affordance for the part."""

    @property
    def failed(self) -> bool:
        return self.failure is not None

    @property
    def state_unit(self) -> str:
        return "deg" if self.joint_type == "revolute" else "m"


@dataclass(frozen=True)
class TwinEvaluation:
    """Scores of one twin against its ground truth."""

    twin_dir: Path
    """The twin folder scored."""
    gt_dir: Path
    """The gt/ folder scored against."""
    parts: tuple[PartEvaluation, ...]
    """One entry per true part, in gt.json order."""
    failure: str | None = None
    """Why the whole twin could not be scored (unreadable twin or ground truth); None if scored."""
    invented_parts: tuple[str, ...] = ()
    """Names of predicted parts matched to no true part."""
    chamfer_cm: float | None = None
    """Scene chamfer distance, cm; None if the twin has no geometry."""
    camera_ate_cm: float | None = None
    """Camera ATE in the camera-0 frame (see :func:`funrec.bench.metrics.camera_ate`), cm."""
    warnings: tuple[str, ...] = ()
    """Non-fatal remarks (predicted part without a mesh, frames without a pose, ...)."""
    hand_iou: float | None = None
    """Mean IoU of the twin's detected hand masks (``masks/hand/``) and the true hand masks over
    the frames where either is non-empty, percent; None when the twin has no detected hand masks
    (none written, or affordances.json says they are the capture's own)."""

    @property
    def ok(self) -> bool:
        return self.failure is None


@dataclass(frozen=True)
class _Part:
    """A part in its side's camera-0 frame with its canonical-state points."""

    articulated: ArticulatedPart
    """The part as read; its axis, pivot and files are in its own world frame."""
    axis: FloatArray
    """(3,) unit joint axis, camera-0 frame."""
    pivot: FloatArray | None
    """(3,) point on a revolute axis, camera-0 frame; None if prismatic."""
    points: FloatArray
    """(N, 3) canonical-state points, camera-0 frame: true visible points, or predicted mesh
    surface samples (vertices of a point-only PLY; N = 0 if the predicted part has no mesh)."""

    def T_posed_canonical(self, frame: int) -> FloatArray:
        """(4, 4) motion from the canonical state to the state at tracked ``frame``, camera-0 frame."""
        index = int(np.searchsorted(self.articulated.frames, frame))
        state = float(self.articulated.states[index])
        return joint_transform(self.articulated.joint_type, self.axis, self.pivot, state)


def _in_camera0(part: ArticulatedPart, T_camera0_world: FloatArray) -> tuple[FloatArray, FloatArray | None]:
    """The part's (3,) axis and (3,) pivot (None if prismatic) mapped into the camera-0 frame."""
    axis = T_camera0_world[:3, :3] @ part.axis_world
    pivot = None if part.pivot_world is None else transform_points(T_camera0_world, part.pivot_world[None])[0]
    return axis, pivot


def _surface_points(path: Path, T_camera0_world: FloatArray, config: EvalConfig, rng: np.random.Generator) -> FloatArray:
    """(N, 3) camera-0 points of a predicted PLY: uniform surface samples of a mesh with faces
    (one per ``surface_spacing_m**2``), or all vertices of a point-only PLY."""
    loaded = load_ply(path)
    if isinstance(loaded, trimesh.Trimesh):
        area = float(loaded.area)
        if not area > 0.0:  # only degenerate faces: nothing to sample
            return transform_points(T_camera0_world, np.asarray(loaded.vertices, dtype=np.float64))
        count = int(min(config.max_surface_samples, max(1, math.ceil(area / config.surface_spacing_m**2))))
        samples = np.asarray(trimesh.sample.sample_surface(loaded, count, seed=rng)[0], dtype=np.float64)
        return transform_points(T_camera0_world, samples)
    return transform_points(T_camera0_world, loaded)


def _load_points(path: Path) -> FloatArray:
    """(N, 3) vertices of a ground-truth point PLY (faces, if any, are ignored)."""
    loaded = load_ply(path)
    return np.asarray(loaded.vertices, dtype=np.float64) if isinstance(loaded, trimesh.Trimesh) else loaded


def _subset(points: FloatArray, count: int, rng: np.random.Generator) -> FloatArray:
    if len(points) <= count:
        return points
    return points[rng.choice(len(points), size=count, replace=False)]


def _mask_files(folder: Path) -> dict[int, Path]:
    """Frame index -> mask file for ``folder/<frame:06d>.png`` (any integer stem); {} if absent."""
    if not folder.is_dir():
        return {}
    files = {}
    for path in folder.glob("*.png"):
        try:
            files[int(path.stem)] = path
        except ValueError:
            continue
    return files


def _load_truth(gt: GroundTruth) -> tuple[list[_Part], FloatArray, FloatArray]:
    """True parts and static points in the GT camera-0 frame, and T_camera0_camera (F, 4, 4)."""
    T_camera0_world = invert_transform(gt.T_world_camera[0])
    parts = []
    for gt_part in gt.parts:
        axis, pivot = _in_camera0(gt_part.part, T_camera0_world)
        points = transform_points(T_camera0_world, _load_points(gt.points_path(gt_part.part.name)))
        parts.append(_Part(gt_part.part, axis, pivot, points))
    static_path = gt.points_path("static")
    static = transform_points(T_camera0_world, _load_points(static_path)) if static_path.is_file() else np.zeros((0, 3))
    return parts, static, T_camera0_world @ gt.T_world_camera


def _load_prediction(
    twin_dir: Path, config: EvalConfig, rng: np.random.Generator, warnings: list[str]
) -> tuple[list[_Part], FloatArray, dict[int, FloatArray]]:
    """Predicted parts and static surface points in the twin camera-0 frame, and T_camera0_camera per frame."""
    articulation = read_articulation(twin_dir / "articulation.json")
    poses_path = twin_dir / "camera_poses.txt"
    poses = read_camera_poses(poses_path)
    if poses.frames[0] != 0:
        raise FormatError(poses_path, "no pose of frame 0, which every comparison maps through")
    T_camera0_world = invert_transform(poses.T_world_camera[0])
    T_camera0_camera = dict(zip(poses.frames.tolist(), T_camera0_world @ poses.T_world_camera))
    parts = []
    for part in articulation.parts:
        axis, pivot = _in_camera0(part, T_camera0_world)
        points = np.zeros((0, 3))
        if part.mesh is None:
            warnings.append(f"predicted {part.name} has no mesh and cannot be matched")
        else:
            points = _surface_points(twin_dir / part.mesh, T_camera0_world, config, rng)
        parts.append(_Part(part, axis, pivot, points))
    static = np.zeros((0, 3))
    if articulation.static_mesh is not None:
        static = _surface_points(twin_dir / articulation.static_mesh, T_camera0_world, config, rng)
    return parts, static, T_camera0_camera


def _match(truth: list[_Part], pred: list[_Part], config: EvalConfig) -> tuple[dict[int, tuple[int, float]], list[str]]:
    """Hungarian matching (see :func:`evaluate_twin`).

    Returns:
        matches: true index -> (predicted index, cost in metres).
        reasons: per true part, why it would be unmatched ("no part found (...)").
    """
    infeasible = 1e6
    cost = np.full((len(truth), len(pred)), infeasible)
    reasons = []
    for k, true_part in enumerate(truth):
        nearest: tuple[float, str] | None = None
        for j, pred_part in enumerate(pred):
            frames, _, _ = metrics.common_frames(pred_part.articulated.frames, true_part.articulated.frames)
            if len(frames) == 0 or len(pred_part.points) == 0:
                continue
            first = int(frames[0])
            p_true = transform_points(true_part.T_posed_canonical(first), true_part.points)
            p_pred = transform_points(pred_part.T_posed_canonical(first), pred_part.points)
            distance = metrics.chamfer_distance(p_pred, p_true)
            if nearest is None or distance < nearest[0]:
                nearest = (distance, pred_part.articulated.name)
            if distance <= config.match_gate_m:
                unshared = 1.0 - len(frames) / len(pred_part.articulated.frames)
                cost[k, j] = distance + config.overlap_weight_m * unshared
        if not pred:
            reasons.append("no part found (the twin has no parts)")
        elif nearest is None:
            reasons.append("no part found (no predicted part with a mesh shares a tracked frame)")
        elif nearest[0] > config.match_gate_m:
            reasons.append(f"no part found (nearest predicted part {nearest[1]} is {nearest[0]:.2f} m away; gate {config.match_gate_m} m)")
        else:
            reasons.append("no part found (its candidates matched other true parts better)")
    if not truth or not pred:
        return {}, reasons
    rows, cols = linear_sum_assignment(cost)
    return {int(k): (int(j), float(cost[k, j])) for k, j in zip(rows, cols) if cost[k, j] < infeasible}, reasons


def _miou_percent(twin_dir: Path, frames: list[int], true_part: _Part, pred_part: _Part, gt: GroundTruth) -> float | None:
    """Mean IoU (%) over ``frames`` whose true mask exists and is non-empty; None if there are none."""
    true_masks = _mask_files(gt.root / "masks" / true_part.articulated.name)
    pred_folder = None if pred_part.articulated.masks is None else twin_dir / pred_part.articulated.masks
    pred_masks = {} if pred_folder is None else _mask_files(pred_folder)
    ious = []
    for frame in frames:
        if frame not in true_masks:
            continue
        mask_true = read_mask(true_masks[frame])
        if not mask_true.any():
            continue
        if frame not in pred_masks:
            ious.append(0.0)
            continue
        mask_pred: BoolArray = read_mask(pred_masks[frame])
        if mask_pred.shape != mask_true.shape:
            raise FormatError(pred_masks[frame], f"mask is {mask_pred.shape}, true mask is {mask_true.shape}")
        ious.append(metrics.mask_iou(mask_pred, mask_true))
    return 100.0 * float(np.mean(ious)) if ious else None


def _score_pair(
    twin_dir: Path, gt: GroundTruth, true_part: _Part, pred_part: _Part, cost: float, config: EvalConfig, rng: np.random.Generator
) -> PartEvaluation:
    true_art, pred_art = true_part.articulated, pred_part.articulated
    frames, index_pred, index_true = metrics.common_frames(pred_art.frames, true_art.frames)
    base = PartEvaluation(true_art.name, true_art.joint_type, pred_art.name, None, cost, len(frames))
    if pred_art.joint_type != true_art.joint_type:
        return replace(base, failure=f"wrong joint type: predicted {pred_art.joint_type}, true {true_art.joint_type}")
    sign = metrics.axis_sign(pred_part.axis, true_part.axis)
    states_pred, states_true = pred_art.states[index_pred], true_art.states[index_true]
    state_error = metrics.state_error(states_pred, states_true, sign)
    revolute = true_art.joint_type == "revolute"
    pivot_error = None
    if revolute:
        assert true_part.pivot is not None and pred_part.pivot is not None
        pivot_error = metrics.line_distance(pred_part.pivot, pred_part.axis, true_part.pivot, true_part.axis)
    points_first = transform_points(
        true_part.T_posed_canonical(int(frames[0])), _subset(true_part.points, config.max_part_points, rng)
    )
    T_true = metrics.relative_part_poses(true_art.joint_type, true_part.axis, true_part.pivot, states_true)
    T_pred = metrics.relative_part_poses(pred_art.joint_type, pred_part.axis, pred_part.pivot, states_pred)
    return replace(
        base,
        axis_error_deg=metrics.axis_error_deg(pred_part.axis, true_part.axis),
        pivot_error_m=pivot_error,
        state_error=math.degrees(state_error) if revolute else state_error,
        adds_auc=metrics.auc_percent(metrics.adds_errors(points_first, T_true, T_pred), config.add_max_threshold_m),
        add_auc=metrics.auc_percent(metrics.add_errors(points_first, T_true, T_pred), config.add_max_threshold_m),
        miou=_miou_percent(twin_dir, frames.tolist(), true_part, pred_part, gt),
    )


def _scene_chamfer_cm(
    truth: list[_Part], true_static: FloatArray, pred: list[_Part], pred_static: FloatArray, matches: dict[int, tuple[int, float]]
) -> float | None:
    """Scene CD with matched parts at their first common frame and other parts canonical, cm."""
    T_true = [np.eye(4) for _ in truth]
    T_pred = [np.eye(4) for _ in pred]
    for k, (j, _) in matches.items():
        frames, _, _ = metrics.common_frames(pred[j].articulated.frames, truth[k].articulated.frames)
        T_true[k] = truth[k].T_posed_canonical(int(frames[0]))
        T_pred[j] = pred[j].T_posed_canonical(int(frames[0]))
    true_points = np.concatenate([true_static] + [transform_points(T, p.points) for T, p in zip(T_true, truth)])
    pred_points = np.concatenate([pred_static] + [transform_points(T, p.points) for T, p in zip(T_pred, pred)])
    if len(pred_points) == 0 or len(true_points) == 0:
        return None
    return 100.0 * metrics.chamfer_distance(pred_points, true_points)


def _camera_ate_cm(T_camera0_camera_pred: dict[int, FloatArray], T_camera0_camera_true: FloatArray, warnings: list[str]) -> float:
    frames = [f for f in sorted(T_camera0_camera_pred) if f < len(T_camera0_camera_true)]
    missing = len(T_camera0_camera_true) - len(frames)
    if missing:
        warnings.append(f"camera ATE over {len(frames)} frames: {missing} frames have no predicted pose")
    T_pred = np.stack([T_camera0_camera_pred[f] for f in frames])
    return 100.0 * metrics.camera_ate(T_pred, T_camera0_camera_true[frames])


def _read_affordances(twin_dir: Path, warnings: list[str]) -> Affordances | None:
    """The twin's affordances.json, or None without one; a malformed file is a warning (the
    articulation is still scored)."""
    path = twin_dir / AFFORDANCES_FILE
    if not path.is_file():
        return None
    try:
        return read_affordances(path)
    except FunrecError as exc:
        warnings.append(f"affordances not scored: {exc}")
        return None


def _contact_errors(
    twin_dir: Path, gt: GroundTruth, truth: list[_Part], pred: list[_Part], matches: dict[int, tuple[int, float]], affordances: Affordances
) -> dict[int, float]:
    """True part index -> distance (m) from the matched twin part's contact point to the true
    handle centre, both moved to their state at the first common tracked frame (camera-0
    frames), so that the two sides' canonical states do not matter."""
    T_camera0_twin = invert_transform(read_camera_poses(twin_dir / "camera_poses.txt").T_world_camera[0])
    T_camera0_gt = invert_transform(gt.T_world_camera[0])
    errors = {}
    for k, (j, _) in matches.items():
        affordance = affordances.part(pred[j].articulated.name)
        if affordance is None:
            continue
        first = int(metrics.common_frames(pred[j].articulated.frames, truth[k].articulated.frames)[0][0])
        p_contact = transform_points(pred[j].T_posed_canonical(first) @ T_camera0_twin, affordance.contact_point[None])[0]
        p_handle = transform_points(truth[k].T_posed_canonical(first) @ T_camera0_gt, gt.parts[k].handle_world[None])[0]
        errors[k] = float(np.linalg.norm(p_contact - p_handle))
    return errors


def _hand_iou_percent(twin_dir: Path, gt: GroundTruth, affordances: Affordances | None) -> float | None:
    """Mean IoU (%) of the twin's detected hand masks and the true ones over the frames where
    either is non-empty (a missing file is an empty mask); None without detected masks."""
    pred_masks = _mask_files(twin_dir / TWIN_HAND_MASKS)
    if not pred_masks or (affordances is not None and affordances.hand_source != "detected"):
        return None
    true_masks = _mask_files(gt.root / "masks" / "hand")
    ious = []
    for frame in range(gt.frame_count):
        mask_true = read_mask(true_masks[frame]) if frame in true_masks else None
        mask_pred = read_mask(pred_masks[frame]) if frame in pred_masks else None
        if mask_true is None or not mask_true.any():
            if mask_pred is not None and mask_pred.any():
                ious.append(0.0)
            continue
        if mask_pred is None:
            ious.append(0.0)
            continue
        if mask_pred.shape != mask_true.shape:
            raise FormatError(pred_masks[frame], f"mask is {mask_pred.shape}, true hand mask is {mask_true.shape}")
        ious.append(metrics.mask_iou(mask_pred, mask_true))
    return 100.0 * float(np.mean(ious)) if ious else None


def _true_part_names(gt_dir: Path) -> tuple[tuple[str, str], ...]:
    try:
        gt = read_ground_truth(gt_dir)
    except FunrecError:
        return ()
    return tuple((p.part.name, p.part.joint_type) for p in gt.parts)


def failed_evaluation(twin_dir: str | Path, gt_dir: str | Path, reason: str) -> TwinEvaluation:
    """A twin that could not be scored: every true part fails with ``reason``.

    Args:
        twin_dir: the twin folder (may not exist).
        gt_dir: the gt/ folder or the capture folder holding it; if unreadable, no parts are listed.
        reason: why, e.g. "reconstruction timed out after 600 s".
    """
    parts = tuple(PartEvaluation(name, joint_type, failure=reason) for name, joint_type in _true_part_names(Path(gt_dir)))
    return TwinEvaluation(Path(twin_dir), Path(gt_dir), parts, failure=reason)


def evaluate_twin(twin_dir: str | Path, gt_dir: str | Path, config: EvalConfig = EvalConfig()) -> TwinEvaluation:
    """Score a twin against ground truth with the metrics of FORMATS.md section 5.

    Both sides are mapped into their own camera-0 frame through the frame-0 pose of their
    camera_poses.txt, so the twin may use any world frame.

    - Matching (FORMATS.md leaves it open): true and predicted parts are paired one-to-one by
      the Hungarian algorithm (scipy ``linear_sum_assignment``). For a pair with a common
      tracked frame, both parts are moved to their own state at the first common frame and
      the cost is the chamfer distance (m) between the predicted part's surface samples and
      the true part's points, plus ``overlap_weight_m * (1 - common / predicted tracked
      frames)``. Pairs without a common frame, with a chamfer distance above
      ``config.match_gate_m``, or whose predicted part has no mesh cannot match. A true part
      left unmatched or matched with the wrong joint type fails; unmatched predicted parts
      are counted as invented.
    - Per true part: failure reason, or axis error (deg), pivot error (m, revolute), state
      error (deg or m) over the common tracked frames, ADD-S / ADD AUC (%) of the true part
      points (posed at the first common frame) moved by the true and by the predicted motion
      relative to that frame, and mIoU (%) over the common tracked frames whose true mask
      exists and is non-empty (frames outside the true mask set are ignored; a missing
      predicted mask at such a frame scores IoU 0).
    - Scene chamfer distance (cm) between samples of the predicted surfaces (static + parts;
      a PLY without faces is used as a point cloud) and the true visible points (static +
      parts). Each matched pair is posed at the state of its first common tracked frame, so
      that the two sides' canonical-state conventions do not matter; unmatched parts stay at
      their canonical state.
    - Camera ATE (cm): RMSE of camera positions in the camera-0 frame without further
      alignment, over the frames with a predicted pose (FORMATS.md does not define ATE).
    - Affordances, when the twin has affordances.json: per matched part (right joint type)
      ``contact_error_m``, the distance from its contact point to the true handle centre with
      both moved to their state at the first common tracked frame (camera-0 frames); per
      sequence ``hand_iou`` (%), when the twin holds detected hand masks in
      ``masks/hand/`` (:data:`funrec.surfaces.hands.TWIN_HAND_MASKS`): mean IoU with gt/masks/hand over
      the frames where either mask is non-empty. A malformed affordances.json is a warning.

    Never raises on a bad twin: a missing or malformed file (any FunrecError, including a
    predicted mask whose size differs from the true mask) yields an evaluation whose
    ``failure`` names the file and problem, and every true part fails with that reason.

    Args:
        twin_dir: the twin folder.
        gt_dir: the gt/ folder, or the capture folder holding it.
        config: evaluation settings.
    """
    twin_dir, gt_dir = Path(twin_dir), Path(gt_dir)
    rng = np.random.default_rng(config.seed)
    try:
        gt = read_ground_truth(gt_dir)
        truth, true_static, T_camera0_camera_true = _load_truth(gt)
    except FunrecError as exc:
        return TwinEvaluation(twin_dir, gt_dir, (), failure=f"ground truth unreadable: {exc}")
    warnings: list[str] = []
    try:
        pred, pred_static, T_camera0_camera_pred = _load_prediction(twin_dir, config, rng, warnings)
        matches, reasons = _match(truth, pred, config)
        affordances = _read_affordances(twin_dir, warnings)
        contact = {} if affordances is None else _contact_errors(twin_dir, gt, truth, pred, matches, affordances)
        part_evaluations = []
        for k, true_part in enumerate(truth):
            if k in matches:
                j, cost = matches[k]
                scored = _score_pair(twin_dir, gt, true_part, pred[j], cost, config, rng)
                part_evaluations.append(scored if scored.failed else replace(scored, contact_error_m=contact.get(k)))
            else:
                part_evaluations.append(PartEvaluation(true_part.articulated.name, true_part.articulated.joint_type, failure=reasons[k]))
        matched = {j for j, _ in matches.values()}
        invented = tuple(p.articulated.name for j, p in enumerate(pred) if j not in matched)
        chamfer_cm = _scene_chamfer_cm(truth, true_static, pred, pred_static, matches)
        ate_cm = _camera_ate_cm(T_camera0_camera_pred, T_camera0_camera_true, warnings)
        hand_iou = _hand_iou_percent(twin_dir, gt, affordances)
    except FunrecError as exc:
        return failed_evaluation(twin_dir, gt.root, f"twin unreadable: {exc}")
    for warning in warnings:
        LOGGER.warning("%s: %s", twin_dir, warning)
    return TwinEvaluation(twin_dir, gt.root, tuple(part_evaluations), None, invented, chamfer_cm, ate_cm, tuple(warnings), hand_iou)


def _fmt(value: float | None, digits: int, unit: str = "") -> str:
    return "-" if value is None else f"{value:.{digits}f}{unit}"


def format_evaluation(evaluation: TwinEvaluation) -> str:
    """A readable multi-line report of one evaluation (for the CLI)."""
    ev = evaluation
    lines = [f"twin {ev.twin_dir}  vs  ground truth {ev.gt_dir}"]
    if ev.failure is not None:
        lines.append(f"  FAILED: {ev.failure}")
    else:
        lines.append(
            f"  camera ATE {_fmt(ev.camera_ate_cm, 2, ' cm')} | scene CD {_fmt(ev.chamfer_cm, 2, ' cm')} | "
            f"invented parts {len(ev.invented_parts)}{' (' + ', '.join(ev.invented_parts) + ')' if ev.invented_parts else ''}"
            + ("" if ev.hand_iou is None else f" | hand IoU {ev.hand_iou:.1f} %")
        )
    for part in ev.parts:
        head = f"  {part.true_name} ({part.joint_type})"
        if part.predicted_name is not None:
            head += f" <- {part.predicted_name}"
        if part.failed:
            lines.append(f"{head}: FAILED - {part.failure}")
            continue
        pivot = f"pivot {_fmt(part.pivot_error_m, 3, ' m')}, " if part.joint_type == "revolute" else ""
        lines.append(
            f"{head}: axis {_fmt(part.axis_error_deg, 2, ' deg')}, {pivot}"
            f"state {_fmt(part.state_error, 3 if part.state_unit == 'm' else 2, ' ' + part.state_unit)}, "
            f"ADD-S {_fmt(part.adds_auc, 1, ' %')}, ADD {_fmt(part.add_auc, 1, ' %')}, mIoU {_fmt(part.miou, 1, ' %')}, "
            f"contact {_fmt(None if part.contact_error_m is None else 100.0 * part.contact_error_m, 1, ' cm')} "
            f"({part.common_frames} common frames)"
        )
    if not ev.parts and ev.failure is None:
        lines.append("  (no true parts)")
    lines.extend(f"  note: {w}" for w in ev.warnings)
    return "\n".join(lines)


def evaluation_to_json(evaluation: TwinEvaluation) -> dict[str, Any]:
    """A JSON-serialisable dictionary of one evaluation (paths as strings, no NaN)."""
    data = asdict(evaluation)
    data["twin_dir"] = str(evaluation.twin_dir)
    data["gt_dir"] = str(evaluation.gt_dir)
    data["invented_parts"] = list(evaluation.invented_parts)
    data["warnings"] = list(evaluation.warnings)
    data["parts"] = [{**asdict(p), "failed": p.failed, "state_unit": p.state_unit} for p in evaluation.parts]
    data["ok"] = evaluation.ok
    return data


__all__ = [
    "EvalConfig",
    "PartEvaluation",
    "TwinEvaluation",
    "evaluate_twin",
    "evaluation_to_json",
    "failed_evaluation",
    "format_evaluation",
]
