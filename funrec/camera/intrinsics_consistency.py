"""Whether a capture's video agrees with its intrinsics.json: a self-calibration from the camera's own motion.

Intrinsics that pass the plausibility test of :mod:`funrec.formats.intrinsics_check` can still be wrong (fx
off by 30 %, the principal point's coordinates swapped): the reconstruction then runs, exits 0 and writes a
twin whose geometry and joints are silently wrong. The video itself tells: lifted with wrong intrinsics, the
depth of one frame is sheared or stretched sideways, and no rigid camera motion maps it onto the depth and
the pixels of another frame taken after a rotation (a translation alone cannot tell).

:func:`check_intrinsics_in_video` tracks corners between frame pairs spread over the video (pyramidal KLT
with a forward-backward check, hand pixels and depth edges left out), fits a rigid motion per pair with
RANSAC, then fits fx, fy, cx, cy jointly with every pair's motion (robust least squares on the reprojection in
pixels and the depth in the second frame). It refuses intrinsics that the video places outside
``max_focal_error`` / ``max_centre_error`` by more than ``sigmas`` standard errors (jackknife over the pairs),
and says it cannot tell when the camera barely rotated (too few usable pairs, or standard errors too large).
Lens distortion is not modelled: on real Kinect v1 data with its true intrinsics it moves the estimate by
a few percent, within the tolerances.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix
from scipy.spatial.transform import Rotation

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class IntrinsicsCheckConfig:
    """Settings of the check of intrinsics against the video (:func:`check_intrinsics_in_video`)."""

    enabled: bool = True
    """Refuse a capture whose video disagrees with its intrinsics.json (off: trust intrinsics.json)."""
    pairs: int = 24
    """Frame pairs, anchored evenly over the video (12 left three of 15 synthetic captures undecided)."""
    jackknife_groups: int = 6
    """Groups of pairs left out in turn to measure the estimate's standard error."""
    gaps: tuple[int, ...] = (3, 6, 10, 15, 22, 30, 45)
    """Frame gaps tried per anchor; the widest one still tracked well is used."""
    max_flow_px: float = 90.0
    """Widest median image motion of a pair, pixels (wider: KLT loses points)."""
    min_flow_px: float = 4.0
    """Narrowest median image motion of a pair, pixels (less: the pair shows no rotation worth fitting)."""
    corners: int = 500
    """Corners detected per pair."""
    min_points: int = 40
    """Fewest rigidly consistent points a pair needs."""
    max_pair_misfit: float = 1.5
    """A pair whose median residual exceeds this (and three times the pairs' median) is dropped, noise units."""
    max_points: int = 150
    """Most points of a pair used in the fit (a random subset of its consistent points)."""
    min_pairs: int = 4
    """Fewest usable pairs for a verdict."""
    max_focal_error: float = 0.12
    """Largest relative error of fx or fy tolerated."""
    max_centre_error: float = 0.07
    """Largest error of cx (cy) tolerated, as a fraction of the image width (height)."""
    sigmas: float = 3.0
    """An error counts only beyond this many standard errors."""
    max_sigma_fraction: float = 0.34
    """A parameter whose standard error exceeds this fraction of its tolerance cannot be judged."""
    pixel_sigma: float = 1.0
    """Reprojection noise, pixels."""
    depth_sigma: tuple[float, float] = (0.004, 0.004)
    """Depth noise a + b z^2, metres."""


@dataclass(frozen=True)
class IntrinsicsVerdict:
    """What the video says of the intrinsics."""

    verdict: str
    """"consistent", "inconsistent" or "cannot tell"."""
    reason: str
    """One sentence for the user."""
    given: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    """fx, fy, cx, cy of intrinsics.json."""
    estimated: tuple[float, float, float, float] | None = None
    """fx, fy, cx, cy the video measures."""
    standard_error: tuple[float, float, float, float] | None = None
    """Jackknife standard errors of ``estimated``."""
    pairs: list[tuple[int, int, int]] = field(default_factory=list)
    """(first frame, second frame, points) of each pair used."""


def _depth_at(depth: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Depth at rounded pixels; 0 where missing, outside, or on a depth edge (3x3 spread over 3 %)."""
    h, w = depth.shape
    u, v = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
    inside = (u >= 1) & (v >= 1) & (u < w - 1) & (v < h - 1)
    out = np.zeros(len(uv))
    u, v = np.clip(u, 1, w - 2), np.clip(v, 1, h - 2)
    patch = np.stack([depth[v + dv, u + du] for dv in (-1, 0, 1) for du in (-1, 0, 1)], axis=1)
    centre = patch[:, 4]
    ok = inside & np.all(patch > 0, axis=1) & (patch.max(axis=1) - patch.min(axis=1) < 0.03 * centre)
    out[ok] = centre[ok]
    return out


def _lift(uv: np.ndarray, z: np.ndarray, k: np.ndarray) -> np.ndarray:
    fx, fy, cx, cy = k
    return np.stack([(uv[:, 0] - cx) * z / fx, (uv[:, 1] - cy) * z / fy, z], axis=1)


def _kabsch(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ca, cb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, cb - r @ ca


def _kabsch_batch(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rigid maps of many point sets at once: a, b (m, k, 3) -> R (m, 3, 3), t (m, 3)."""
    ca, cb = a.mean(1), b.mean(1)
    u, _, vt = np.linalg.svd(np.einsum("mki,mkj->mij", a - ca[:, None], b - cb[:, None]))
    v, ut = np.swapaxes(vt, 1, 2), np.swapaxes(u, 1, 2)
    d = np.sign(np.linalg.det(v @ ut))
    r = v @ (np.eye(3) * np.stack([np.ones_like(d), np.ones_like(d), d], axis=1)[:, None, :]) @ ut
    return r, cb - np.einsum("mij,mj->mi", r, ca)


def _rigid_ransac(a: np.ndarray, b: np.ndarray, rng: np.random.Generator, iterations: int = 300) -> np.ndarray:
    """Inliers of the best rigid map a -> b (tolerance 2 cm + 5 % of depth: loose, as wrong intrinsics bend)."""
    tol = 0.02 + 0.05 * a[:, 2]
    samples = np.stack([rng.choice(len(a), 3, replace=False) for _ in range(iterations)])
    r, t = _kabsch_batch(a[samples], b[samples])
    errors = np.linalg.norm(np.einsum("mij,nj->mni", r, a) + t[:, None] - b[None], axis=2)
    best = errors[int(np.argmax((errors < tol).sum(1)))] < tol
    if best.sum() >= 3:
        r1, t1 = _kabsch(a[best], b[best])
        best = np.linalg.norm(a @ r1.T + t1 - b, axis=1) < tol
    return best


@dataclass
class _Pair:
    first: int
    second: int
    uv_a: np.ndarray
    z_a: np.ndarray
    uv_b: np.ndarray
    z_b: np.ndarray
    rotvec: np.ndarray
    t: np.ndarray


def _small(gray: np.ndarray) -> np.ndarray:
    return cv2.resize(gray, (gray.shape[1] // 4, gray.shape[0] // 4), interpolation=cv2.INTER_AREA).astype(np.float32)


def _track(gray_a: np.ndarray, gray_b: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """KLT a -> b with a forward-backward check; (points in a, points in b) that survived."""
    params = {"winSize": (21, 21), "maxLevel": 4, "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)}
    p0 = corners.reshape(-1, 1, 2).astype(np.float32)
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(gray_a, gray_b, p0, None, **params)
    p0r, st2, _ = cv2.calcOpticalFlowPyrLK(gray_b, gray_a, p1, None, **params)
    ok = (st1[:, 0] == 1) & (st2[:, 0] == 1) & (np.linalg.norm((p0r - p0)[:, 0], axis=1) < 0.5)
    return p0[ok, 0].astype(float), p1[ok, 0].astype(float)


def _pair(capture, a: int, config: IntrinsicsCheckConfig, k0: np.ndarray, rng: np.random.Generator) -> _Pair | None:  # noqa: ANN001
    """The widest well-tracked pair anchored at frame ``a``, with its rigid inliers and motion."""
    n = len(capture)
    gray_a, depth_a = capture.gray(a), capture.depth_m(a)
    mask = (depth_a > 0).astype(np.uint8)
    hand = capture.mask("hand", a) if "hand" in capture.mask_paths else None
    if hand is not None:
        mask[cv2.dilate(hand.astype(np.uint8), np.ones((15, 15), np.uint8)) > 0] = 0
    corners = cv2.goodFeaturesToTrack(gray_a, config.corners, 0.005, 8, mask=mask)
    if corners is None or len(corners) < config.min_points:
        return None
    corners = corners[:, 0]
    # the widest gap whose global image shift (phase correlation at a quarter of the size: cheap) stays trackable
    small_a = _small(gray_a)
    b = None
    for gap in config.gaps:
        if a + gap >= n:
            break
        shift = np.hypot(*cv2.phaseCorrelate(small_a, _small(capture.gray(a + gap)))[0]) * 4.0
        if shift > config.max_flow_px:
            break
        b = a + gap
    if b is None:
        return None
    uv_a, uv_b = _track(gray_a, capture.gray(b), corners)
    if len(uv_a) < config.min_points or np.median(np.linalg.norm(uv_b - uv_a, axis=1)) < config.min_flow_px:
        return None
    z_a, z_b = _depth_at(depth_a, uv_a), _depth_at(capture.depth_m(b), uv_b)
    if hand is not None:
        hand_b = capture.mask("hand", b)
        if hand_b is not None:
            u = np.clip(np.round(uv_b).astype(int), 0, [hand_b.shape[1] - 1, hand_b.shape[0] - 1])
            z_b[hand_b[u[:, 1], u[:, 0]]] = 0.0
    ok = (z_a > 0) & (z_b > 0)
    uv_a, uv_b, z_a, z_b = uv_a[ok], uv_b[ok], z_a[ok], z_b[ok]
    if len(uv_a) < config.min_points:
        return None
    pa, pb = _lift(uv_a, z_a, k0), _lift(uv_b, z_b, k0)
    inliers = _rigid_ransac(pa, pb, rng)
    if inliers.sum() < config.min_points:
        return None
    r, t = _kabsch(pa[inliers], pb[inliers])
    keep = np.flatnonzero(inliers)
    if len(keep) > config.max_points:  # enough for the fit; the least squares stays small
        keep = np.sort(rng.choice(keep, config.max_points, replace=False))
        inliers = np.zeros_like(inliers)
        inliers[keep] = True
    return _Pair(a, b, uv_a[inliers], z_a[inliers], uv_b[inliers], z_b[inliers], Rotation.from_matrix(r).as_rotvec(), t)


class _Problem:
    """Joint least squares of (fx, fy, cx, cy) and every pair's motion."""

    def __init__(self, pairs: list[_Pair], k0: np.ndarray, size: tuple[int, int], config: IntrinsicsCheckConfig) -> None:
        self.pairs, self.k0, self.size, self.config = pairs, k0, size, config
        self.counts = [len(p.uv_a) for p in pairs]
        self.index = np.repeat(np.arange(len(pairs)), self.counts)
        self.uv_a, self.z_a = np.concatenate([p.uv_a for p in pairs]), np.concatenate([p.z_a for p in pairs])
        self.uv_b, self.z_b = np.concatenate([p.uv_b for p in pairs]), np.concatenate([p.z_b for p in pairs])

    def intrinsics(self, x: np.ndarray) -> np.ndarray:
        w, h = self.size
        return np.array([self.k0[0] * np.exp(x[0]), self.k0[1] * np.exp(x[1]), self.k0[2] + w * x[2], self.k0[3] + h * x[3]])

    def residuals(self, x: np.ndarray) -> np.ndarray:
        k = self.intrinsics(x)
        a, b = self.config.depth_sigma
        motions = x[4:].reshape(-1, 6)
        rotations = Rotation.from_rotvec(motions[:, :3]).as_matrix()[self.index]
        q = np.einsum("nij,nj->ni", rotations, _lift(self.uv_a, self.z_a, k)) + motions[self.index, 3:]
        z = np.maximum(q[:, 2], 1e-3)
        return np.concatenate([(k[0] * q[:, 0] / z + k[2] - self.uv_b[:, 0]) / self.config.pixel_sigma,
                               (k[1] * q[:, 1] / z + k[3] - self.uv_b[:, 1]) / self.config.pixel_sigma,
                               (q[:, 2] - self.z_b) / (a + b * self.z_b**2)])

    def pair_misfit(self, x: np.ndarray) -> np.ndarray:
        """Each pair's median absolute residual (the worst of u, v and depth), in noise units."""
        r = np.abs(self.residuals(x)).reshape(3, -1)
        return np.array([np.median(r[:, self.index == i], axis=1).max() for i in range(len(self.pairs))])

    def sparsity(self) -> csr_matrix:
        """Which parameters each residual depends on: the intrinsics, and its own pair's motion."""
        n, m = len(self.index), len(self.pairs)
        rows = np.arange(3 * n)
        pair = np.tile(self.index, 3)
        cols = np.concatenate([np.tile(np.arange(4), (3 * n, 1)), 4 + 6 * pair[:, None] + np.arange(6)], axis=1)
        return csr_matrix((np.ones(cols.size, dtype=int), (np.repeat(rows, 10), cols.ravel())), shape=(3 * n, 4 + 6 * m))

    def solve(self, x0: np.ndarray | None = None) -> np.ndarray:
        if x0 is None:
            x0 = np.concatenate([np.zeros(4)] + [np.concatenate([p.rotvec, p.t]) for p in self.pairs])
        result = least_squares(self.residuals, x0, jac_sparsity=self.sparsity(), loss="soft_l1", f_scale=2.0,
                               x_scale="jac", max_nfev=100)
        return result.x


def check_intrinsics_in_video(capture, config: IntrinsicsCheckConfig = IntrinsicsCheckConfig()) -> IntrinsicsVerdict:  # noqa: ANN001, B008
    """What the capture's video says of its intrinsics (see the module docstring); never raises on a verdict."""
    k0_in = capture.intrinsics
    k0 = np.array([k0_in.fx, k0_in.fy, k0_in.cx, k0_in.cy], dtype=float)
    given = tuple(float(v) for v in k0)
    n = len(capture)
    rng = np.random.default_rng(0)
    anchors = sorted({int(a) for a in np.linspace(0, max(n - 1 - config.gaps[0], 0), config.pairs)})
    pairs = [p for p in (_pair(capture, a, config, k0, rng) for a in anchors if a + config.gaps[0] < n) if p is not None]
    used = [(p.first, p.second, len(p.uv_a)) for p in pairs]
    if len(pairs) < config.min_pairs:
        return IntrinsicsVerdict("cannot tell", f"only {len(pairs)} frame pairs with enough tracked motion "
                                 f"(at least {config.min_pairs} needed)", given, pairs=used)
    problem = _Problem(pairs, k0, (k0_in.width, k0_in.height), config)
    x = problem.solve()
    for _ in range(3):  # a pair the joint fit cannot explain (a moving part tracked, a bad match) is dropped
        misfit = problem.pair_misfit(x)
        bad = misfit > max(config.max_pair_misfit, 3.0 * float(np.median(misfit)))
        if not bad.any() or len(pairs) - int(bad.sum()) < config.min_pairs:
            break
        keep = np.flatnonzero(~bad)
        pairs = [pairs[i] for i in keep]
        problem = _Problem(pairs, k0, (k0_in.width, k0_in.height), config)
        x = problem.solve(np.concatenate([x[:4], x[4:].reshape(-1, 6)[keep].ravel()]))
    used = [(p.first, p.second, len(p.uv_a)) for p in pairs]
    estimate = problem.intrinsics(x)
    # delete-a-group jackknife over the pairs: the spread of the estimate when each group is left out
    groups = np.array_split(np.arange(len(pairs)), min(config.jackknife_groups, len(pairs)))
    leave_one = []
    for group in groups:
        keep = [i for i in range(len(pairs)) if i not in set(group.tolist())]
        sub = _Problem([pairs[i] for i in keep], k0, (k0_in.width, k0_in.height), config)
        x0 = np.concatenate([x[:4], x[4:].reshape(-1, 6)[keep].ravel()])
        leave_one.append(sub.intrinsics(sub.solve(x0)))
    leave_one_arr = np.array(leave_one)
    m, g = len(pairs), len(groups)
    se = np.sqrt((g - 1) / g * ((leave_one_arr - leave_one_arr.mean(0)) ** 2).sum(0))
    tolerance = np.array([config.max_focal_error * k0[0], config.max_focal_error * k0[1],
                          config.max_centre_error * k0_in.width, config.max_centre_error * k0_in.height])
    error = estimate - k0
    names = ("fx", "fy", "cx", "cy")
    result = {"given": given, "estimated": tuple(float(v) for v in estimate), "standard_error": tuple(float(v) for v in se),
              "pairs": used}
    wrong = [j for j in range(4) if abs(error[j]) > tolerance[j] + config.sigmas * se[j]]
    if wrong:
        parts = ", ".join(f"{names[j]} {k0[j]:g} px but the video measures {estimate[j]:.0f} +- {se[j]:.0f} px" for j in wrong)
        return IntrinsicsVerdict("inconsistent", f"{parts} (from the camera's own motion over {m} frame pairs; "
                                 f"tolerance {config.max_focal_error:.0%} of the focal length, "
                                 f"{config.max_centre_error:.0%} of the image size for the principal point)", **result)
    unsure = [j for j in range(4) if se[j] > config.max_sigma_fraction * tolerance[j]]
    if unsure:
        return IntrinsicsVerdict("cannot tell", "the camera's motion does not pin down " + ", ".join(names[j] for j in unsure)
                                 + " (too little rotation)", **result)
    return IntrinsicsVerdict("consistent", f"the video agrees with the intrinsics over {m} frame pairs", **result)


def require_consistent_intrinsics(capture, config: IntrinsicsCheckConfig = IntrinsicsCheckConfig()) -> IntrinsicsVerdict | None:  # noqa: ANN001, B008
    """Refuse a capture whose video disagrees with its intrinsics.json (None when the check is off).

    Raises:
        CaptureError: naming intrinsics.json, what the video measures, and how to go on.
    """
    from funrec.errors import CaptureError

    if not config.enabled:
        return None
    verdict = check_intrinsics_in_video(capture, config)
    if verdict.verdict == "inconsistent":
        raise CaptureError(capture.root / "intrinsics.json",
                           f"the video disagrees with these intrinsics: {verdict.reason}; fix intrinsics.json "
                           "(or pass --no-intrinsics-check-enabled to use them anyway)")
    level = logging.WARNING if verdict.verdict == "cannot tell" else logging.INFO
    log.log(level, "intrinsics: %s: %s", verdict.verdict, verdict.reason)
    return verdict


__all__ = ["IntrinsicsCheckConfig", "IntrinsicsVerdict", "check_intrinsics_in_video", "require_consistent_intrinsics"]
