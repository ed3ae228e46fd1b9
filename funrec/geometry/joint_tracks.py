"""A one-joint motion model fitted directly to point tracks, and smooth bridging of joint states.

A part's tracks are modelled as ``p_fm = J(s_f) x_m``: canonical points ``x_m`` (M, 3) moved by
the joint transform of a per-frame state ``s_f``. With the axis (and pivot) fixed, the state of
each frame and the canonical points have closed forms, so the model can be fitted by alternation
with robust weights. Unlike free per-frame rigid motions (six unknowns, three or more shared
tracks per frame) one frame's state needs a single track away from the axis, which keeps a fast
door, whose tracks last a few frames each, followed.

Tracks split into groups that share no frame (the front of a door seen until it turns edge-on,
its inside afterwards) each fix the states only up to their own offset;
:func:`bridge_states` chooses the offsets and the states of unobserved frames that make the
whole state sequence smoothest (least squared jerk, the model of human reaching motions).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components

from funrec.geometry.joints import closest_point_on_axis_to_origin, joint_transforms
from funrec.geometry.transforms import invert_transform, rotation_about_axis
from funrec.typed import BoolArray, FloatArray, IntArray

_MIN_LEVER_M = 0.02
"""Tracks closer than this to a revolute axis carry no angle information (their motion is
below typical depth noise for any angle) and are left out of the closed-form angle."""


def joint_states(joint_type: str, axis: FloatArray, pivot: FloatArray | None, x: FloatArray, p: FloatArray,
                 w: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Least-squares state of each frame given the joint and the canonical points.

    For a prismatic joint ``s_f`` is the weighted mean of ``(p_fm - x_m) . a``; for a revolute
    joint the angle minimising ``sum_m w |R(a, s) (x_m - c) + c - p_fm|^2`` is
    ``atan2(sum w a . (u x v), sum w u . v)`` with u, v the parts of ``x - c`` and ``p - c``
    orthogonal to the axis.

    Args:
        joint_type: "revolute" or "prismatic".
        axis: (3,) unit axis, world frame. pivot: (3,) point on a revolute axis (None for prismatic).
        x: (M, 3) canonical points, world frame, metres.
        p: (F, M, 3) observed points (any value where ``w`` is 0), world frame, metres.
        w: (F, M) non-negative observation weights; 0 where unobserved.

    Returns:
        states: (F,) rad or m (0 where a frame has no support);
        support: (F,) information of each state (sum of w, times the squared lever arm for a
        revolute joint), 0 where undetermined.
    """
    p = np.where(w[..., None] > 0, p, 0.0)
    if joint_type == "prismatic":
        support = w.sum(1)
        s = np.einsum("fm,fmi,i->f", w, p - x, axis) / np.maximum(support, 1e-300)
        return np.where(support > 0, s, 0.0), support
    u = x - pivot
    u = u - np.outer(u @ axis, axis)
    v = p - pivot
    v = v - (v @ axis)[..., None] * axis
    lever2 = (u**2).sum(-1)
    w = np.where(lever2 > _MIN_LEVER_M**2, w, 0.0)
    sin = np.einsum("fm,fmi,i->f", w, np.cross(u, v), axis)
    cos = np.einsum("fm,fmi,mi->f", w, v, u)
    support = w @ lever2
    return np.where(support > 0, np.arctan2(sin, cos), 0.0), support


def canonical_points(T: FloatArray, p: FloatArray, w: FloatArray) -> FloatArray:
    """(M, 3) weighted mean of the observations moved back by the part poses T (F, 4, 4);
    NaN for a track with no weight. p: (F, M, 3), w: (F, M)."""
    T_inv = invert_transform(T)
    back = np.where(w[..., None] > 0, p, 0.0) @ np.swapaxes(T_inv[:, :3, :3], 1, 2) + T_inv[:, None, :3, 3]
    total = w.sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.einsum("fm,fmi->mi", w, back) / total[:, None]


def residuals(joint_type: str, axis: FloatArray, pivot: FloatArray | None, states: FloatArray, x: FloatArray,
              p: FloatArray, observed: BoolArray) -> FloatArray:
    """(F, M) distance |J(s_f) x_m - p_fm| in metres; NaN where not observed."""
    T = joint_transforms(joint_type, axis, pivot, states)
    pred = np.nan_to_num(x)[None] @ np.swapaxes(T[:, :3, :3], 1, 2) + T[:, None, :3, 3]
    return np.where(observed, np.linalg.norm(np.where(observed[..., None], p, 0.0) - pred, axis=-1), np.nan)


def track_groups(observed: BoolArray) -> tuple[IntArray, IntArray]:
    """Groups of tracks linked through shared frames (connected components of the frame-track
    visibility graph); states of different groups are unrelated without a motion prior.

    Args:
        observed: (F, M) bool.

    Returns:
        frame_group: (F,) group of each frame, -1 for a frame without observation;
        track_group: (M,) group of each track, -1 for a track without observation.
        Groups are numbered in order of their first frame.
    """
    F, M = observed.shape
    f, m = np.nonzero(observed)
    graph = coo_matrix((np.ones(len(f)), (f, F + m)), shape=(F + M, F + M))
    _, label = connected_components(graph, directed=False)
    frame_label, track_label = label[:F], label[F:]
    has_f, has_m = observed.any(1), observed.any(0)
    order = {}
    for lab in frame_label[has_f]:
        order.setdefault(int(lab), len(order))
    frame_group = np.array([order[int(lab)] if h else -1 for lab, h in zip(frame_label, has_f)], dtype=np.int64)
    track_group = np.array([order.get(int(lab), -1) if h else -1 for lab, h in zip(track_label, has_m)], dtype=np.int64)
    return frame_group, track_group


def bridge_states(states: FloatArray, frame_group: IntArray, order: int = 3) -> FloatArray:
    """Join the state sequences of separate track groups and fill unobserved frames smoothly.

    The states of group g > 0 are shifted by an unknown offset d_g (group 0 keeps its own) and
    the states of unobserved frames are free; both are chosen to minimise the sum of squared
    ``order``-th differences of the whole sequence (order 3: least jerk, the classical model of
    a human reaching motion, Flash and Hogan 1985). Observed frames keep their values up to
    their group's offset. States before the first and after the last observed frame are held.

    Args:
        states: (F,) states of the observed frames (any value elsewhere), rad or m.
        frame_group: (F,) group of each frame from :func:`track_groups`, -1 if unobserved.
        order: difference order of the smoothness measure.

    Returns:
        (F,) bridged states.
    """
    F = len(states)
    seen = np.flatnonzero(frame_group >= 0)
    if len(seen) == 0:
        return np.zeros(F)
    inner = slice(seen[0], seen[-1] + 1)
    if seen[0] > 0 or seen[-1] < F - 1:
        # Before the first and after the last observed frame nothing constrains the motion; a
        # smooth extrapolation would run away, so the first and last states are held.
        out = np.empty(F)
        out[inner] = bridge_states(states[inner], frame_group[inner], order)
        out[: seen[0]] = out[seen[0]]
        out[seen[-1] + 1 :] = out[seen[-1]]
        return out
    groups = int(frame_group.max(initial=-1)) + 1
    free = np.flatnonzero(frame_group < 0)
    n = len(free) + max(groups - 1, 0)
    base = np.where(frame_group >= 0, states, 0.0).astype(np.float64)
    if n == 0 or F <= order:
        return base if F > order or n == 0 else np.interp(np.arange(F), np.flatnonzero(frame_group >= 0), base[frame_group >= 0])
    M = np.zeros((F, n))
    M[free, np.arange(len(free))] = 1.0
    for g in range(1, groups):
        M[frame_group == g, len(free) + g - 1] = 1.0
    D = np.diff(np.eye(F), order, axis=0)
    solution = np.linalg.lstsq(D @ M, -D @ base, rcond=None)[0]
    return base + M @ solution


def fit_joint_to_tracks(joint_type: str, axis: npt.ArrayLike, pivot: npt.ArrayLike | None, states: FloatArray,
                        p: FloatArray, observed: BoolArray, noise_m: float, max_track_error_m: float = np.inf,
                        min_frame_tracks: int = 2, iterations: int = 8, refine_axis: bool = True,
                        polish: bool = True) -> dict:
    """Robust alternating fit of ``p_fm = J(s_f) x_m`` from an initial joint and states.

    Each round: canonical points from the current poses; per-frame states in closed form
    (:func:`joint_states`); optionally the axis (and pivot) by a small Gauss-Newton problem
    with states and points fixed; Cauchy weights from the residuals (scale ``noise_m``), so a
    track slipping on an occluder or the hand loses its pull. States of frames without any
    observation, and the offsets between groups of tracks sharing no frame, are bridged with
    :func:`bridge_states`.

    Args:
        joint_type: "revolute" or "prismatic".
        axis: (3,) initial axis. pivot: (3,) initial revolute pivot, None for prismatic.
        states: (F,) initial states (rad or m).
        p: (F, M, 3) track positions, world frame, metres (any value where not observed).
        observed: (F, M) bool.
        noise_m: scale of the Cauchy weights, metres (about the track noise).
        max_track_error_m: a track whose mean residual exceeds this is dropped and the fit
            repeated (once): a track dragged by the hand is consistent with itself, and in a
            frame where only such tracks are seen no weighting can recover the state.
        min_frame_tracks: a frame's state counts as observed only when this many tracks see
            it; elsewhere it is bridged. One track can be a static point slipping by a few
            centimetres.
        iterations: alternation rounds.
        refine_axis: also refine the axis and pivot.
        polish: finish the axis with a joint robust least-squares step (:func:`_polish`).

    Returns:
        dict with ``axis`` (3,), ``pivot`` (3,) or None, ``states`` (F,) with states[first
        observed frame] = 0, ``x`` (M, 3), ``weights`` (F, M), ``support`` (F,),
        ``frame_group`` (F,), ``residual`` (F, M) (NaN where not observed), ``used`` (M,)
        bool, the tracks kept.
    """
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    pivot = None if pivot is None else np.asarray(pivot, dtype=np.float64)
    s = np.asarray(states, dtype=np.float64).copy()
    used = observed.any(0)
    for attempt in range(2):
        axis, pivot, s, result = _fit(joint_type, axis, pivot, s, p, observed & used, noise_m, min_frame_tracks, iterations,
                                      refine_axis, polish and attempt == 1)
        seen = observed & used & np.isfinite(result["residual"])
        # RMS: a track that left the part for a few frames (slipped onto the hand) must go
        error = np.where(seen.any(0), np.sqrt((np.where(seen, result["residual"], 0.0) ** 2).sum(0) / np.maximum(seen.sum(0), 1)), np.inf)
        bad = used & (error > max_track_error_m)
        if attempt == 1:
            break
        if (used & ~bad).sum() >= 2:
            used &= ~bad
    return {**result, "used": used}


def _fit(joint_type: str, axis: FloatArray, pivot: FloatArray | None, s: FloatArray, p: FloatArray,
         observed: BoolArray, noise_m: float, min_frame_tracks: int, iterations: int,
         refine_axis: bool, polish: bool) -> tuple[FloatArray, FloatArray | None, FloatArray, dict]:
    """One fit of :func:`fit_joint_to_tracks` on the given observations."""
    frame_group, track_group = track_groups(observed)
    sizes = np.bincount(track_group[track_group >= 0], weights=observed.sum(0)[track_group >= 0])
    main = int(np.argmax(sizes)) if len(sizes) else 0
    # The joint comes from the best observed group alone: the other groups' states start
    # unknown, and a canonical point from wrong states would drag the axis.
    in_main = observed & (track_group == main)[None, :]
    axis, pivot, s, _ = _alternate(joint_type, axis, pivot, s, p, in_main, frame_group, noise_m, min_frame_tracks,
                                   iterations, refine_axis)
    if refine_axis and polish:
        axis, pivot, s = _polish(joint_type, axis, pivot, s, p, in_main, noise_m)
    if (track_group[observed.any(0)] == main).all():
        w = _alternate(joint_type, axis, pivot, s, p, observed, frame_group, noise_m, min_frame_tracks, 1, False)[3]
    else:
        axis, pivot, s, w = _alternate(joint_type, axis, pivot, s, p, observed, frame_group, noise_m, min_frame_tracks,
                                       iterations, False)
    x = canonical_points(joint_transforms(joint_type, axis, pivot, s), p, w)
    known = np.isfinite(x).all(1)
    _, support = _supported_states(joint_type, axis, pivot, np.nan_to_num(x), p, np.where(known, w, 0.0), min_frame_tracks)
    first = int(np.argmax(observed.any(1)))
    T0 = joint_transforms(joint_type, axis, pivot, s[first : first + 1])[0]
    x = np.nan_to_num(x) @ T0[:3, :3].T + T0[:3, 3]
    s = s - s[first]
    result = {"axis": axis, "pivot": None if pivot is None else closest_point_on_axis_to_origin(axis, pivot),
              "states": s, "x": x, "weights": w, "support": support,
              "frame_group": np.where(support > 0, frame_group, -1),
              "residual": residuals(joint_type, axis, pivot, s, x, p, observed & known)}
    return axis, pivot, s, result


def _supported_states(joint_type: str, axis: FloatArray, pivot: FloatArray | None, x: FloatArray, p: FloatArray,
                      w: FloatArray, min_frame_tracks: int) -> tuple[FloatArray, FloatArray]:
    """:func:`joint_states` with the support of frames seen by fewer than ``min_frame_tracks``
    tracks set to 0."""
    states, support = joint_states(joint_type, axis, pivot, x, p, w)
    # Counted by observation, not by weight: counting only well-fitting tracks feeds back (a
    # poor start leaves frames unsupported, their bridged states fit worse, and so on).
    return states, np.where((w > 0).sum(1) >= min_frame_tracks, support, 0.0)


def _alternate(joint_type: str, axis: FloatArray, pivot: FloatArray | None, s: FloatArray, p: FloatArray,
               observed: BoolArray, frame_group: IntArray, noise_m: float, min_frame_tracks: int, iterations: int,
               refine_axis: bool) -> tuple[FloatArray, FloatArray | None, FloatArray, FloatArray]:
    """Rounds of canonical points -> states (bridged) -> [axis] -> Cauchy weights."""
    w = observed.astype(np.float64)
    for round_index in range(iterations):
        x = canonical_points(joint_transforms(joint_type, axis, pivot, s), p, w)
        known = np.isfinite(x).all(1)
        w_known = np.where(known, w, 0.0)
        s_new, support = _supported_states(joint_type, axis, pivot, np.nan_to_num(x), p, w_known, min_frame_tracks)
        s = bridge_states(s_new, np.where(support > 0, frame_group, -1))
        if refine_axis and round_index % 3 == 0 and round_index < iterations - 1:
            axis, pivot = _refine_axis(joint_type, axis, pivot, s, np.nan_to_num(x), p, w_known)
        r = residuals(joint_type, axis, pivot, s, np.nan_to_num(x), p, observed & known)
        w = np.where(observed & known, 1.0 / (1.0 + (np.nan_to_num(r) / noise_m) ** 2), 0.0)
    return axis, pivot, s, w


def _polish(joint_type: str, axis: FloatArray, pivot: FloatArray | None, s: FloatArray, p: FloatArray,
            observed: BoolArray, noise_m: float, max_evaluations: int = 15) -> tuple[FloatArray, FloatArray | None, FloatArray]:
    """Joint robust least squares over axis, pivot, the states of the observed frames and the
    canonical points (scipy ``least_squares``, Cauchy loss, sparse finite-difference Jacobian),
    from the alternation's result: alternation converges slowly along the valley where pivot and
    angles trade off, which a joint step crosses directly. The first observed frame's state is
    held, fixing the gauge."""
    f_obs, m_obs = np.nonzero(observed)
    frames = np.unique(f_obs)
    tracks = np.unique(m_obs)
    if len(frames) < 3 or len(tracks) < 2:
        return axis, pivot, s
    revolute = joint_type == "revolute"
    n_joint = 4 if revolute else 2
    free_frames = frames[1:]
    col_s = np.full(len(s), -1)
    col_s[free_frames] = n_joint + np.arange(len(free_frames))
    col_x = np.full(observed.shape[1], -1)
    col_x[tracks] = n_joint + len(free_frames) + 3 * np.arange(len(tracks))
    B = np.linalg.svd(np.eye(3) - np.outer(axis, axis))[0][:, :2]
    x0 = canonical_points(joint_transforms(joint_type, axis, pivot, s), p, observed.astype(np.float64))[tracks]
    theta0 = np.concatenate([np.zeros(n_joint), s[free_frames], x0.ravel()])
    target = p[f_obs, m_obs]

    def unpack(theta: FloatArray) -> tuple[FloatArray, FloatArray | None, FloatArray, FloatArray]:
        a = axis + B @ theta[:2]
        a = a / np.linalg.norm(a)
        q = pivot + B @ theta[2:4] if revolute else None
        states = s.copy()
        states[free_frames] = theta[n_joint : n_joint + len(free_frames)]
        x = np.zeros((observed.shape[1], 3))
        x[tracks] = theta[n_joint + len(free_frames) :].reshape(-1, 3)
        return a, q, states, x

    def fun(theta: FloatArray) -> FloatArray:
        a, q, states, x = unpack(theta)
        T = joint_transforms(joint_type, a, q, states[f_obs])
        return (np.einsum("nij,nj->ni", T[:, :3, :3], x[m_obs]) + T[:, :3, 3] - target).ravel()

    n = len(f_obs)
    rows = np.arange(3 * n).reshape(n, 3)
    has_s = col_s[f_obs] >= 0

    def jac(theta: FloatArray) -> csr_matrix:
        a, q, states, x = unpack(theta)
        d_joint, d_s, d_x = _derivatives(joint_type, axis, B, theta[:2], a, q, states[f_obs], x[m_obs])
        r_idx = [np.repeat(rows.ravel(), n_joint), rows[has_s].ravel(), np.repeat(rows, 3, axis=1).ravel()]
        c_idx = [np.tile(np.arange(n_joint), 3 * n), np.repeat(col_s[f_obs][has_s], 3),
                 (col_x[m_obs][:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1).ravel()]
        vals = [d_joint.reshape(-1), d_s[has_s].ravel(), np.asarray(d_x).ravel()]
        return csr_matrix((np.concatenate(vals), (np.concatenate(r_idx), np.concatenate(c_idx))), shape=(3 * n, len(theta0)))

    result = least_squares(fun, theta0, jac=jac, loss="cauchy", f_scale=noise_m, method="trf", tr_solver="lsmr",
                           x_scale="jac", max_nfev=max_evaluations)
    a, q, states, _ = unpack(result.x)
    return a, q, states


def _derivatives(joint_type: str, axis0: FloatArray, B: FloatArray, u: FloatArray, a: FloatArray, q: FloatArray | None,
                 s: FloatArray, x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Derivatives of J(s_n) x_n for n observations with the axis a = normalise(axis0 + B u)
    and the pivot q = q0 + B w: (n, 3, 4 or 2) by (u, w), (n, 3) by s_n, (n, 3, 3) by x_n
    (the analytic form funrec.parts.part_motion uses for its track term)."""
    n = len(s)
    da_du = (np.eye(3) - np.outer(a, a)) @ B / np.linalg.norm(axis0 + B @ u)
    if joint_type == "revolute":
        R = rotation_about_axis(a, s)
        v = x - q
        c, sn = np.cos(s)[:, None, None], np.sin(s)[:, None, None]
        d_a = -_skew(v) * sn + (1 - c) * (a[None, :, None] * v[:, None, :] + (v @ a)[:, None, None] * np.eye(3))
        d_joint = np.concatenate([d_a @ da_du, (np.eye(3) - R) @ B], axis=-1)
        return d_joint, np.cross(a, np.einsum("nij,nj->ni", R, v)), R
    d_joint = s[:, None, None] * np.broadcast_to(da_du, (n, 3, 2))
    return d_joint, np.broadcast_to(a, (n, 3)), np.broadcast_to(np.eye(3), (n, 3, 3))


def _skew(v: FloatArray) -> FloatArray:
    """(..., 3, 3) cross-product matrices [v]x."""
    S = np.zeros((*v.shape[:-1], 3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return S - np.swapaxes(S, -1, -2)


def _refine_axis(joint_type: str, axis: FloatArray, pivot: FloatArray | None, s: FloatArray, x: FloatArray,
                 p: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray | None]:
    """Axis (two tangent parameters) and pivot (two, in the plane orthogonal to the axis) that
    minimise the weighted residuals with states and canonical points fixed."""
    f, m = np.nonzero(w > 0)
    if len(f) < 6:
        return axis, pivot
    sw = np.sqrt(w[f, m])[:, None]
    B = np.linalg.svd(np.eye(3) - np.outer(axis, axis))[0][:, :2]
    revolute = joint_type == "revolute"

    def unpack(theta: FloatArray) -> tuple[FloatArray, FloatArray | None]:
        a = axis + B @ theta[:2]
        return a / np.linalg.norm(a), (pivot + B @ theta[2:4]) if revolute else None

    def fun(theta: FloatArray) -> FloatArray:
        a, q = unpack(theta)
        T = joint_transforms(joint_type, a, q, s)
        pred = np.einsum("nij,nj->ni", T[f, :3, :3], x[m]) + T[f, :3, 3]
        return (sw * (pred - p[f, m])).ravel()

    def jac(theta: FloatArray) -> FloatArray:
        a, q = unpack(theta)
        d_joint = _derivatives(joint_type, axis, B, theta[:2], a, q, s[f], x[m])[0]
        return (sw[..., None] * d_joint).reshape(-1, d_joint.shape[-1])

    # A few damped Gauss-Newton steps on the 4 (2) parameters: scipy's general solvers spend
    # more in bookkeeping than in this 4x4 system.
    theta = np.zeros(4 if revolute else 2)
    r = fun(theta)
    for _ in range(5):
        J = jac(theta)
        H = J.T @ J
        step = -np.linalg.solve(H + 1e-6 * np.trace(H) * np.eye(len(theta)) + 1e-12 * np.eye(len(theta)), J.T @ r)
        r_new = fun(theta + step)
        if r_new @ r_new >= r @ r:
            break
        theta, r = theta + step, r_new
    return unpack(theta)


__all__ = ["bridge_states", "canonical_points", "fit_joint_to_tracks", "joint_states", "residuals", "track_groups"]
