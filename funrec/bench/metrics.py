"""Evaluation metrics of FORMATS.md section 5 as pure functions on arrays.

Every function works in whatever frame its inputs share; :mod:`funrec.bench.evaluate` puts both
sides in the camera-0 frame first. Lengths are metres and angles radians unless a name says
otherwise (``_deg``); the reporting layer converts to cm and percent.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from funrec.geometry.joints import joint_transforms
from funrec.geometry.transforms import invert_transform, transform_points
from funrec.typed import FloatArray, IntArray

PARALLEL_SIN_TOL = 1e-9
"""Below this sine of the angle between two lines they are treated as parallel: the
skew-line formula divides by |a x b|, and at 1e-9 the float64 cross product of unit
vectors is still accurate to ~1e-7 relative, so the switch costs no precision."""
ADD_AUC_MAX_THRESHOLD_M = 0.10
"""Upper end of the accuracy-threshold curve for ADD / ADD-S AUC (10 cm, FORMATS.md section 5)."""


def _unit(vector: npt.ArrayLike, name: str) -> FloatArray:
    v = np.asarray(vector, dtype=np.float64)
    if v.shape != (3,):
        raise ValueError(f"{name} must be (3,), got {v.shape}")
    norm = np.linalg.norm(v)
    if not np.isfinite(norm) or norm == 0.0:
        raise ValueError(f"{name} must be a finite non-zero vector, got {v}")
    return v / norm


def _points(points: npt.ArrayLike, name: str) -> FloatArray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
        raise ValueError(f"{name} must be a non-empty (N, 3) array, got {p.shape}")
    return p


def axis_error_deg(axis_pred: npt.ArrayLike, axis_true: npt.ArrayLike) -> float:
    """Angle between two joint axes, ignoring direction: min(e, 180 - e).

    Args:
        axis_pred: (3,) predicted axis (any non-zero length).
        axis_true: (3,) true axis, same frame.

    Returns:
        Error in degrees, in [0, 90].
    """
    a = _unit(axis_pred, "axis_pred")
    b = _unit(axis_true, "axis_true")
    # atan2 of |cross| and dot is accurate near 0 and 180 deg, where arccos(dot) is not.
    e = float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), float(a @ b))))
    return min(e, 180.0 - e)


def axis_sign(axis_pred: npt.ArrayLike, axis_true: npt.ArrayLike) -> float:
    """+1.0 if the two axes point the same way (non-negative dot product), else -1.0."""
    return 1.0 if float(_unit(axis_pred, "axis_pred") @ _unit(axis_true, "axis_true")) >= 0.0 else -1.0


def line_distance(
    point_a: npt.ArrayLike, direction_a: npt.ArrayLike, point_b: npt.ArrayLike, direction_b: npt.ArrayLike
) -> float:
    """Shortest distance between two infinite 3D lines (the pivot error of FORMATS.md).

    Skew lines use ``|(p_b - p_a) . (a x b)| / |a x b|``; lines whose directions are parallel
    (sine of the angle below :data:`PARALLEL_SIN_TOL`) use the distance of ``point_b`` to
    line a, which is then the same everywhere along the lines.

    Args:
        point_a: (3,) a point on line a, metres.
        direction_a: (3,) direction of line a (any non-zero length).
        point_b: (3,) a point on line b, same frame.
        direction_b: (3,) direction of line b.

    Returns:
        Distance in metres (>= 0).
    """
    pa = np.asarray(point_a, dtype=np.float64).reshape(3)
    pb = np.asarray(point_b, dtype=np.float64).reshape(3)
    a = _unit(direction_a, "direction_a")
    b = _unit(direction_b, "direction_b")
    n = np.cross(a, b)
    sin_angle = float(np.linalg.norm(n))
    d = pb - pa
    if sin_angle < PARALLEL_SIN_TOL:
        return float(np.linalg.norm(d - a * float(d @ a)))
    return float(abs(d @ n) / sin_angle)


def common_frames(frames_pred: npt.ArrayLike, frames_true: npt.ArrayLike) -> tuple[IntArray, IntArray, IntArray]:
    """Frames tracked on both sides and where they sit in each side's list.

    Args:
        frames_pred: (F_p,) increasing frame indices of the prediction.
        frames_true: (F_t,) increasing frame indices of the ground truth.

    Returns:
        frames: (F_c,) common frame indices, increasing.
        index_pred: (F_c,) positions of those frames in ``frames_pred``.
        index_true: (F_c,) positions of those frames in ``frames_true``.
    """
    frames, index_pred, index_true = np.intersect1d(
        np.asarray(frames_pred, dtype=np.int64), np.asarray(frames_true, dtype=np.int64), return_indices=True
    )
    return frames, index_pred, index_true


def state_error(states_pred: npt.ArrayLike, states_true: npt.ArrayLike, sign: float) -> float:
    """Mean joint-state error of FORMATS.md section 5 over frames tracked on both sides.

    ``mean_i |(s_i - s_first)_pred * sign - (s_i - s_first)_true|``, where "first" is the
    first common tracked frame, so that each side's choice of canonical state cancels.

    Args:
        states_pred: (F_c,) predicted states at the common frames, radians or metres.
        states_true: (F_c,) true states at the same frames, same unit.
        sign: +1 if the predicted and true axes agree in direction, else -1
            (see :func:`axis_sign`); a flipped axis with flipped states is the same motion.

    Returns:
        Mean absolute error in the unit of the states.
    """
    sp = np.asarray(states_pred, dtype=np.float64)
    st = np.asarray(states_true, dtype=np.float64)
    if sp.shape != st.shape or sp.ndim != 1 or len(sp) == 0:
        raise ValueError(f"states must be equal-length non-empty (F_c,), got {sp.shape} and {st.shape}")
    return float(np.mean(np.abs((sp - sp[0]) * sign - (st - st[0]))))


def relative_part_poses(
    joint_type: str, axis: npt.ArrayLike, pivot: npt.ArrayLike | None, states: npt.ArrayLike
) -> FloatArray:
    """Part motion from the first of the given frames to each of them.

    Args:
        joint_type: "revolute" or "prismatic".
        axis: (3,) joint axis.
        pivot: (3,) point on a revolute axis, same frame; None for prismatic.
        states: (F,) joint states at the frames, radians or metres.

    Returns:
        (F, 4, 4) ``T(s_i) @ inv(T(s_0))``, mapping the part at frame 0 of the list to the part
        at frame i, in the frame of ``axis``; the first is the identity.
    """
    T_posed_canonical = joint_transforms(joint_type, axis, pivot, states)
    return T_posed_canonical @ invert_transform(T_posed_canonical[0])


def _check_pose_stacks(T_true: npt.ArrayLike, T_pred: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    T_true = np.asarray(T_true, dtype=np.float64)
    T_pred = np.asarray(T_pred, dtype=np.float64)
    if T_true.shape != T_pred.shape or T_true.ndim != 3 or T_true.shape[1:] != (4, 4):
        raise ValueError(f"pose stacks must both be (F, 4, 4), got {T_true.shape} and {T_pred.shape}")
    return T_true, T_pred


def add_errors(points: npt.ArrayLike, T_true: npt.ArrayLike, T_pred: npt.ArrayLike) -> FloatArray:
    """Per-frame ADD: mean distance between the points moved by the true and by the predicted pose.

    Args:
        points: (N, 3) true part points at the reference frame, metres.
        T_true: (F, 4, 4) true relative part poses (reference frame -> frame i).
        T_pred: (F, 4, 4) predicted relative part poses, same frame.

    Returns:
        (F,) mean point distance per frame, metres.
    """
    p = _points(points, "points")
    T_true, T_pred = _check_pose_stacks(T_true, T_pred)
    # Both poses act on the same points, so the per-point offset is (T_true - T_pred) p.
    delta = T_true - T_pred
    offsets = np.einsum("fij,nj->fni", delta[:, :3, :3], p) + delta[:, None, :3, 3]
    return np.linalg.norm(offsets, axis=2).mean(axis=1)


def adds_errors(points: npt.ArrayLike, T_true: npt.ArrayLike, T_pred: npt.ArrayLike) -> FloatArray:
    """Per-frame ADD-S: mean distance from each truly moved point to the closest predicted one.

    For frame i this is ``mean_p min_q |T_true p - T_pred q|``. Since ``|T_true p - T_pred q|
    = |inv(T_pred) T_true p - q|``, one KD-tree over the reference points serves every frame.

    Args:
        points: (N, 3) true part points at the reference frame, metres.
        T_true: (F, 4, 4) true relative part poses (reference frame -> frame i).
        T_pred: (F, 4, 4) predicted relative part poses, same frame.

    Returns:
        (F,) mean closest-point distance per frame, metres.
    """
    p = _points(points, "points")
    T_true, T_pred = _check_pose_stacks(T_true, T_pred)
    tree = cKDTree(p)
    T_back = invert_transform(T_pred) @ T_true
    errors = np.empty(len(T_true))
    for i, T in enumerate(T_back):
        distances, _ = tree.query(transform_points(T, p))
        errors[i] = float(np.mean(distances))
    return errors


def auc_percent(errors_m: npt.ArrayLike, max_threshold_m: float = ADD_AUC_MAX_THRESHOLD_M) -> float:
    """Area under the accuracy-threshold curve from 0 to ``max_threshold_m``, in percent.

    Accuracy at threshold t is the fraction of errors below t; the area is normalised by
    ``max_threshold_m``. The integral is taken in closed form: each error e contributes
    ``max(0, 1 - e / max_threshold_m)``, so a constant error e < 10 cm scores ``100 (1 - e / 0.1)``
    (no threshold discretisation, unlike the 1000-step sums of some ADD implementations).

    Args:
        errors_m: (F,) per-frame errors in metres (ADD or ADD-S), non-empty.
        max_threshold_m: curve end in metres.

    Returns:
        AUC in percent, in [0, 100].
    """
    e = np.asarray(errors_m, dtype=np.float64).reshape(-1)
    if len(e) == 0:
        raise ValueError("auc_percent needs at least one error")
    if not max_threshold_m > 0.0:
        raise ValueError(f"max_threshold_m must be positive, got {max_threshold_m}")
    return float(100.0 * np.mean(np.clip(1.0 - e / max_threshold_m, 0.0, 1.0)))


def chamfer_distance(points_a: npt.ArrayLike, points_b: npt.ArrayLike) -> float:
    """Chamfer distance: mean of the two directed mean nearest-neighbour distances.

    ``0.5 * (mean_a min_b |a - b| + mean_b min_a |a - b|)`` (distances, not squared).

    Args:
        points_a: (N, 3) points, e.g. predicted surface samples, metres.
        points_b: (M, 3) points in the same frame, e.g. true visible points.

    Returns:
        Distance in metres (the report shows cm).
    """
    a = _points(points_a, "points_a")
    b = _points(points_b, "points_b")
    d_ab, _ = cKDTree(b).query(a)
    d_ba, _ = cKDTree(a).query(b)
    return float(0.5 * (np.mean(d_ab) + np.mean(d_ba)))


def mask_iou(mask_pred: npt.ArrayLike, mask_true: npt.ArrayLike) -> float:
    """Intersection over union of two boolean masks.

    Args:
        mask_pred: (H, W) bool (non-zero = inside).
        mask_true: (H, W) bool.

    Returns:
        IoU in [0, 1]; 1.0 when both masks are empty (they agree). The evaluation never asks
        for that case: it scores only frames with a non-empty true mask.
    """
    pred = np.asarray(mask_pred).astype(bool)
    true = np.asarray(mask_true).astype(bool)
    if pred.shape != true.shape or pred.ndim != 2:
        raise ValueError(f"masks must both be (H, W), got {pred.shape} and {true.shape}")
    union = int(np.count_nonzero(pred | true))
    if union == 0:
        return 1.0
    return float(np.count_nonzero(pred & true) / union)


def camera_ate(T_world_camera_pred: npt.ArrayLike, T_world_camera_true: npt.ArrayLike) -> float:
    """Absolute trajectory error of camera positions in the camera-0 frame.

    FORMATS.md does not define ATE; FunREC uses this definition: each trajectory is mapped
    through its own frame 0 (``T_camera0_camera = inv(T_world_camera[0]) @ T_world_camera``), so
    the world frames need not agree, and the error is the RMSE of the camera positions with
    no further alignment (no Umeyama/similarity fit, so drift and scale errors count in full).

    Args:
        T_world_camera_pred: (F, 4, 4) predicted camera-to-world poses, row 0 = frame 0.
        T_world_camera_true: (F, 4, 4) true camera-to-world poses of the same frames.

    Returns:
        RMSE in metres (0 for a single frame).
    """
    T_pred, T_true = _check_pose_stacks(T_world_camera_pred, T_world_camera_true)
    t_pred = (invert_transform(T_pred[0]) @ T_pred)[:, :3, 3]
    t_true = (invert_transform(T_true[0]) @ T_true)[:, :3, 3]
    return float(np.sqrt(np.mean(np.sum((t_pred - t_true) ** 2, axis=1))))


__all__ = [
    "ADD_AUC_MAX_THRESHOLD_M",
    "PARALLEL_SIN_TOL",
    "add_errors",
    "adds_errors",
    "auc_percent",
    "axis_error_deg",
    "axis_sign",
    "camera_ate",
    "chamfer_distance",
    "common_frames",
    "line_distance",
    "mask_iou",
    "relative_part_poses",
    "state_error",
]
