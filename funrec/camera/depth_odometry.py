"""Frame-to-keyframe registration from depth alone: the fallback of camera tracking where corners
are too few, as on plain painted walls and doors.

Projective point-to-plane ICP (KinectFusion's data association: a source point is matched to the
keyframe pixel it projects to), coarse to fine, from the pose the feature tracker last had, with a
Tukey kernel set by the sensor's depth noise so that the moving hand and part do not drag the
camera. Two more terms pin what point-to-plane leaves free along a plain front: grey levels and
occluding contours (each near-side depth-edge point's distance to the keyframe's edges, through
a distance transform). A learned dense matcher (the paper's RoMa) could fill the same signature:
``register_depth(source, target, T_init) -> DepthFit``.

Written here rather than with Open3D's ICP: its k-d-tree association cost 0.3-0.4 s per frame at
the density the plain bench scenes need (stride 4, 18k points; a sparser stride 8 slid 1-3 cm
along walls), and its RGB-D odometry (projective, photometric + depth) drifted 7-180 cm over 14
frames of the dark bench family (measured, /tmp/prof_odo.py). Projective association is one
vectorised gather per iteration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from funrec.camera.features import DepthNoiseModel
from funrec.geometry.camera import backproject
from funrec.geometry.transforms import pose_difference, transform_points
from funrec.typed import BoolArray, FloatArray, IntArray, UInt8Array


@dataclass(frozen=True)
class DepthOdometryConfig:
    """Settings of :func:`depth_view` and :func:`register_depth`."""

    enabled: bool = True
    """Use depth where corners fail (off: corners only; ablation)."""

    map_stride: int = 2
    """The keyframe's vertex and normal maps keep every k-th pixel (320x240 at 640x480)."""
    coarse_distances_m: tuple[float, ...] = (0.08, 0.04)
    """Correspondence distances of the coarse rounds, metres: the first must exceed the motion
    between two frames that the guess misses (a few cm at 15-30 fps). A final round uses the
    noise-derived distance."""
    coarse_strides: tuple[int, ...] = (8, 4)
    """Source pixel stride of each coarse round."""
    final_stride: int = 4
    """Source pixel stride of the final round (19k points at 640x480: sparser strides slid along
    plain walls, measured)."""
    photometric_weight: float = 0.2
    """Weight of a grey-level residual (grey in [0, 1]) against a point-to-plane residual in
    metres: (depth noise / grey noise)^2 ~ (3 mm / 0.007)^2. Grey edges (a cabinet's outline, a
    counter's lip) pin the slides along plain walls that point-to-plane ICP leaves free
    (measured on the dark family's first frame against itself from a 2 cm offset: ICP alone
    stopped 10-26 mm off, 0.2 returned to 0.0 mm; 0.02 was too weak to help)."""
    grey_in_final_round: bool = False
    """Grey levels steer the coarse rounds only: they pin the slides, but on noise-free planes
    they left the fine round 2.4 mm off where point-to-plane alone ended 0.1 mm off (measured,
    tests/test_depth_odometry.py). The final round's covariance still counts them."""
    contour_weight: float = 1.0
    """Weight of an occluding-contour residual (the image distance, as metres at the point's depth,
    from a source point on the near side of a depth edge to the keyframe's nearest such edge)
    against a point-to-plane residual: an edge is located to about a pixel, which at 1-2 m is the
    depth noise. Occluding contours (a cabinet's outline against the wall behind it) pin the slide
    along a plain front that neither point-to-plane ICP (the points that slid over the edge leave
    the kernel) nor grey levels (a pale cabinet on a pale wall: 8 grey levels apart) pin: measured
    on geo_angled_rev_wall_00, a plain wall-cabinet front filling the view, where ICP started 2-5
    cm off along the front stayed 1.6-4.8 cm off. A direct edge alignment (Canny-VO's distance
    transform) on depth edges rather than grey edges. 0: no contour term (ablation)."""
    contour_bridge_px: int = 3
    """A near-side pixel is on an occluding contour where, along an image axis, holes and then a pixel farther by
    ``max_edge_ratio`` follow it within this many pixels. The bench's depth (and a Kinect's) drops 75 % of the
    pixels along an edge and 30 % of their neighbours; without the bridge a plain wall cabinet's outline kept 75
    edgels of ~400 (light_changing_static_00_r5: the camera slid 11 cm per frame along the front, camera-only ATE
    136 cm; with a 3-pixel bridge 0.95 cm). 1: the far side must be next to the pixel."""
    min_contour_points: int = 20
    """Fewer source contour points than this: no contour term in that registration."""
    min_grey_spread: float = 0.01
    """An image whose usable grey levels spread less than this (standard deviation, 0-1 scale) is
    flat: no grey-level term (a covered lens; 8-bit noise alone is ~0.004)."""
    grey_tukey: float = 0.1
    """Tukey scale of grey-level residuals: a hand or a shadow changes grey by more."""
    projective_below_m: float = 0.2
    """Rounds whose correspondence distance is below this use projective association, the
    others nearest neighbours."""
    noise_sigmas: float = 3.0
    """The final round's correspondence distance and the Tukey scale, in standard deviations of
    the depth noise at the median depth of both views (never below ``min_distance_m``)."""
    min_distance_m: float = 0.01
    """Floor of the final correspondence distance, metres."""
    iterations: int = 10
    """Gauss-Newton steps per round."""
    max_edge_ratio: float = 0.05
    """Neighbouring depths differing by more than this fraction of the depth are a depth edge:
    no normal there."""
    min_fitness: float = 0.5
    """A registration is accepted only when at least this fraction of the frame's usable points
    meets the keyframe's surface within the final distance: the static scene must dominate the
    view (the hand and a moving door together cover well under half of a frame in every bench
    family)."""
    max_step_m: float = 0.15
    """... and when it moves the camera at most this far from the guess, metres: a hand-held
    camera does not move 15 cm in one frame; a larger step is a slide into a wrong minimum."""
    max_step_rad: float = math.radians(15.0)
    """... and turns it at most this much from the guess, radians."""
    max_std_m: float = 0.001
    """... and when the surfaces and grey edges pin the camera's position to this standard
    deviation along every direction, metres (sigma^2 A^-1 with the depth noise): a plain wall
    and door with no grey level (lens covered) measured 1.0-1.6 mm and slid 1.5 cm per frame;
    registered frames of the dark, plain and lighting families measured at most 0.74 mm."""
    max_std_rad: float = math.radians(0.05)
    """... and its orientation to this, radians (those same cases: 0.06 deg against at most
    0.015 deg)."""
    min_points: int = 300
    """A view with fewer usable points at the final stride is not registered."""
    changed_min_fraction: float = 0.02
    """After a first registration, source pixels off the keyframe's surface that form a connected
    region larger than this fraction of the usable view are a change (a door turning, an arm, a
    drawer) and are left out, with ``changed_margin_px`` around them, when the registration is run
    again: the strip of a turning door by its hinge stays within the kernel and dragged the camera
    with it, 1.7 cm per frame where the door gave the only surfaces across the slide (measured on
    geo_island_rev_wall_00: a wall cabinet seen from below). Slivers that the camera's own motion
    uncovers at depth edges stay. 0: no second registration (ablation)."""
    changed_margin_px: int = 12
    """Margin around a changed region, pixels at the map's stride (24 px at 640x480): the hinge strip."""
    changed_at_guess: bool = False
    """Also look for the changes where the guess puts the frame (the last pose moved on by the last motion, or the
    corners' pose), and leave out those found at either pose; where that leaves too little to register, the changes at
    the first registration alone. Meant for a door that fills much of a plain view and drags the first registration
    with it: at the dragged pose the door lies on the keyframe's surface, no change is found there, and the second
    registration keeps the door. Off by default: it held on the scenes it was made for and not on fresh ones
    (camera-only ATE, cm, `docs/camera_changed_at_guess.md`). Reseeds 5 and 6 (tuned on): geo_island_rev_wall_00_r6
    9.57 -> 0.60, person_elbow_pri_wardrobe_00_r5 9.75 -> 0.71, light_harsh_rev_wall_00_r6 4.66 -> 3.79; captures over
    1 cm 10 -> 8 of 56. Reseed 7 (held out, first run): light_changing_static_00_r7 8.69 -> 2.08, but
    plain_rev_wall_cabinet_00_r7 0.94 -> 5.28 (a guess carried on from frames already 1 cm off, 2.5 cm off itself,
    made the static scene's edges look changed and left them out) and dark_rev_fridge_00_r7 0.87 -> 2.80; over 1 cm
    6 -> 9 of 28."""
    depth_noise: DepthNoiseModel = DepthNoiseModel()
    """Sensor noise that sets the final distance and the Tukey kernel."""


@dataclass(frozen=True, eq=False)
class DepthView:
    """One frame's usable depth as vertex and normal maps, in its camera frame."""

    K: FloatArray
    """(3, 3) intrinsics of the full-resolution image."""
    stride: int
    """Pixel stride of the maps."""
    p_map: FloatArray
    """(h, w, 3) point of every kept pixel, NaN where unusable."""
    n_map: FloatArray
    """(h, w, 3) unit normal facing the camera, NaN where there is none (edges, holes)."""
    median_depth_m: float
    p_tree: FloatArray
    """(M, 3) points with a normal at the final stride: the targets of correspondences."""
    n_tree: FloatArray
    """(M, 3) their normals."""
    intensity: FloatArray
    """(H, W) grey level in [0, 1], lightly smoothed, full resolution; NaN everywhere when the
    image is flat."""
    contour_uv2: IntArray
    """(N, 2) occluding-contour edgels (:func:`_contour`), full resolution, in half pixels."""
    contour_p: FloatArray
    """(N, 3) their points in the camera frame."""

    # Only a keyframe (the target of a registration) needs these: built on first use, once.
    @cached_property
    def tree(self) -> cKDTree:
        """k-d tree over ``p_tree``."""
        return cKDTree(self.p_tree)

    @cached_property
    def gradient(self) -> FloatArray:
        """(2, H, W) derivative of ``intensity`` along u and v, per pixel."""
        return np.stack([cv2.Sobel(self.intensity, cv2.CV_32F, 1, 0, ksize=3) / 8.0,
                         cv2.Sobel(self.intensity, cv2.CV_32F, 0, 1, ksize=3) / 8.0])

    @cached_property
    def contour_distance(self) -> FloatArray:
        """(3, 2H, 2W) distance from each half pixel to the nearest contour edgel, in half pixels,
        and its derivatives along u and v."""
        h, w = self.intensity.shape
        free = np.ones((2 * h, 2 * w), dtype=np.uint8)
        free[self.contour_uv2[:, 1], self.contour_uv2[:, 0]] = 0
        distance = cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        return np.stack([distance, cv2.Sobel(distance, cv2.CV_32F, 1, 0, ksize=3) / 8.0,
                         cv2.Sobel(distance, cv2.CV_32F, 0, 1, ksize=3) / 8.0])

    def contour_points(self, keep: BoolArray | None = None) -> FloatArray:
        """(N, 3) points of the contour pixels, only where ``keep`` ((h, w) at the map's stride) is
        True, when given."""
        if keep is None:
            return self.contour_p
        u, v = self.contour_uv2.T // (2 * self.stride)
        return self.contour_p[keep[v, u]]

    def points(self, stride: int, keep: BoolArray | None = None) -> tuple[FloatArray, FloatArray]:
        """(N, 3) usable points at a pixel stride that is a multiple of the map's, and their (N,)
        grey levels; only where ``keep`` ((h, w) at the map's stride) is True, when given."""
        step = max(1, stride // self.stride)
        p = self.p_map[::step, ::step].reshape(-1, 3)
        grey = self.intensity[:: self.stride * step, :: self.stride * step][: self.p_map[::step].shape[0],
                                                                           : self.p_map[:, ::step].shape[1]]
        valid = np.isfinite(p[:, 2])
        if keep is not None:
            valid &= keep[::step, ::step].reshape(-1)
        return p[valid], grey.reshape(-1)[valid]


def _normals(p_map: FloatArray, max_edge_ratio: float) -> FloatArray:
    """Normals from central differences of the vertex map; NaN at holes and depth edges."""
    n = np.full(p_map.shape, np.nan)
    dx = p_map[1:-1, 2:] - p_map[1:-1, :-2]
    dy = p_map[2:, 1:-1] - p_map[:-2, 1:-1]
    centre = p_map[1:-1, 1:-1]
    z = centre[..., 2]
    with np.errstate(invalid="ignore"):
        smooth = (np.abs(dx[..., 2]) < 2 * max_edge_ratio * z) & (np.abs(dy[..., 2]) < 2 * max_edge_ratio * z)
    # Per coordinate plane: np.cross's products, the norm's and the facing sum's additions in
    # their order (the same bits as those calls on (h, w, 3) maps) in 60 % of their time.
    (a0, a1, a2), (b0, b1, b2) = np.moveaxis(dx, -1, 0), np.moveaxis(dy, -1, 0)
    cross = (a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0)
    norm = np.sqrt(cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2])
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = [c / norm for c in cross]
        facing = unit[0] * centre[..., 0] + unit[1] * centre[..., 1] + unit[2] * centre[..., 2] > 0
    keep = smooth & (norm > 0)
    for k in range(3):
        n[1:-1, 1:-1, k] = np.where(keep, np.where(facing, -unit[k], unit[k]), np.nan)
    return n


def _contour(depth: FloatArray, max_edge_ratio: float, bridge_px: int) -> tuple[IntArray, FloatArray]:
    """The near side of the occluding contours: pixels with a neighbour (8-neighbourhood) that has
    depth and is farther by more than ``max_edge_ratio`` of theirs, or, along one of the four axis
    directions, holes (depth 0) and then such a farther pixel within ``bridge_px``: a depth sensor
    drops the readings along an edge (the near side's edge pixel and the far side's shadow), and a
    contour that needed the far side next to it kept only the gaps in that band. Holes are never the
    far side on their own (the dropouts of a plain surface are no contour). Returns (N, 2) edgel
    positions in half pixels, ``2 (u, v)`` moved one half pixel towards each axis direction in which
    the far side lies (where the edge lies: an outline rounded to whole pixels put a straight edge's
    every pixel half a pixel off the same way), and (N,) their depths."""
    farther = depth * (1.0 + max_edge_ratio)
    valid = depth > 0
    depth32 = depth.astype(np.float32)
    # Only pixels with a farther pixel within the bridge can be on a contour: the axis walks below run on those
    # few (a per-pixel walk over the whole image took 12 ms a frame, this 1 ms).
    size = 2 * max(bridge_px, 1) + 1
    v, u = np.nonzero(valid & (cv2.dilate(depth32, np.ones((size, size), np.uint8)) > farther))
    h, w = depth.shape
    z_far = farther[v, u]
    step = np.zeros((len(v), 2), dtype=np.int64)
    for du, dv in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        holes = np.ones(len(v), dtype=bool)
        far = np.zeros(len(v), dtype=bool)
        for k in range(1, bridge_px + 1):
            un, vn = u + k * du, v + k * dv
            inside = (un >= 0) & (un < w) & (vn >= 0) & (vn < h)
            beyond = np.where(inside, depth[np.clip(vn, 0, h - 1), np.clip(un, 0, w - 1)], 0.0)  # outside: a hole
            far |= holes & (beyond > z_far)
            holes &= beyond <= 0
        step[far] += (du, dv)
    near = step.any(axis=1) | (cv2.dilate(depth32, np.ones((3, 3), np.uint8)) > farther)[v, u]
    v, u, step = v[near], u[near], step[near]
    return np.stack([2 * u, 2 * v], axis=1) + np.clip(step, -1, 1), depth[v, u]


def depth_view(gray: UInt8Array, depth_m: FloatArray, usable: BoolArray, K: FloatArray,
               config: DepthOdometryConfig = DepthOdometryConfig()) -> DepthView | None:  # noqa: B008
    """A frame's depth as vertex and normal maps and its grey level; None when fewer than
    ``config.min_points`` usable points remain at the final stride.

    Args:
        gray: (H, W) grey image.
        depth_m: (H, W) depth in metres, 0 where missing.
        usable: (H, W) True where a pixel may be used (no hand, no moving part).
        K: (3, 3) intrinsics.
    """
    s = config.map_stride
    usable_depth = np.where(usable, depth_m, 0.0)
    depth = usable_depth[::s, ::s]
    K_map = np.array(K, dtype=np.float64)
    K_map[:2] /= s  # map pixel (u/s, v/s) is image pixel (u, v)
    p_map = backproject(depth, K_map).reshape(*depth.shape, 3)
    n_map = _normals(p_map, config.max_edge_ratio)
    step = max(1, config.final_stride // s)
    p_tree, n_tree = p_map[::step, ::step].reshape(-1, 3), n_map[::step, ::step].reshape(-1, 3)
    keep = np.isfinite(n_tree[:, 0]) & np.isfinite(p_tree[:, 2])
    if keep.sum() < config.min_points:
        return None
    # A flat image (lens covered, black frame) has no grey-level term at all. Grey levels are not
    # standardised per frame: the arm entering the view shifts a frame's mean and spread, and
    # standardising then cost the dark family 1-8 cm of drift (measured).
    grey = gray.astype(np.float32) / 255.0
    flat = not usable.any() or float(grey[usable].std()) < config.min_grey_spread
    intensity = np.full_like(grey, np.nan) if flat else cv2.GaussianBlur(grey, (5, 5), 1.0)
    # Occluding contours at full resolution: at the map's stride an outline is found only to 2
    # pixels, and a straight edge's pixels all share that rounding.
    if config.contour_weight > 0:
        uv2, z = _contour(usable_depth, config.max_edge_ratio, config.contour_bridge_px)
    else:
        uv2, z = np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    contour_p = np.stack([(uv2[:, 0] / 2 - K[0, 2]) * z / K[0, 0], (uv2[:, 1] / 2 - K[1, 2]) * z / K[1, 1], z], axis=1)
    return DepthView(np.asarray(K, dtype=np.float64), s, p_map, n_map, float(np.median(depth[depth > 0])),
                     p_tree[keep], n_tree[keep], intensity, uv2, contour_p)


@dataclass(frozen=True)
class DepthFit:
    """One accepted depth registration."""

    T_target_source: FloatArray
    """(4, 4) pose of the source camera in the target (keyframe) camera."""
    fitness: float
    """Fraction of the source's usable points on the target's surface within ``distance_m``."""
    rmse_m: float
    """RMS point-to-plane distance of those points, metres."""
    distance_m: float
    """Correspondence distance of the final round, metres."""
    p_source_matched: FloatArray
    """(N, 3) source points on the target's surface, in the source camera frame (for the pose
    graph's information matrix)."""


def _associate(p_source: FloatArray, target: DepthView, T: FloatArray, distance_m: float,
               nearest: bool) -> tuple[FloatArray, FloatArray, FloatArray, BoolArray]:
    """Source points in the target frame, their partners in the target, the partners' normals, and
    which have a partner within ``distance_m``: the nearest target point (k-d tree) when
    ``nearest``, else the target pixel the point projects to (KinectFusion's projective
    association, ~10x cheaper)."""
    # (3, 3) @ (3, N): the same bits as (N, 3) @ (3, 3) in a quarter of its time, with contiguous
    # coordinate rows; p is returned as their (N, 3) transpose.
    rows = T[:3, :3] @ p_source.T + T[:3, 3, None]
    p = rows.T
    if nearest:
        _, index = target.tree.query(p, k=1, distance_upper_bound=distance_m)
        has = index < len(target.p_tree)
        index = np.where(has, index, 0)
        return p, target.p_tree[index], target.n_tree[index], has
    h, w = target.p_map.shape[:2]
    x, y, z = rows
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.rint((target.K[0, 0] * x / z + target.K[0, 2]) / target.stride)
        v = np.rint((target.K[1, 1] * y / z + target.K[1, 2]) / target.stride)
    inside = (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    # One flat take of pixel v w + u (exact in float64), 4x faster than indexing with (v, u); pixel 0
    # outside the map, whose entries are never used (``has`` is False there).
    index = np.where(inside, v * w + u, 0.0).astype(np.intp)
    q, n = target.p_map.reshape(-1, 3).take(index, axis=0), target.n_map.reshape(-1, 3).take(index, axis=0)
    has = inside & np.isfinite(n[:, 0]) & np.isfinite(q[:, 2])
    d = p - q
    with np.errstate(invalid="ignore"):  # |p - q| summed as np.linalg.norm does (same bits), 3x faster
        has &= np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]) < distance_m
    return p, q, n, has


def _projected(p: FloatArray, K: FloatArray, images: tuple[np.ndarray, ...], scale: float = 1.0
               ) -> tuple[BoolArray, FloatArray, FloatArray]:
    """Points (N, 3) projected with ``K`` into images of ``scale`` pixels per pixel of K (value, d/du,
    d/dv): which land inside, the value there and its gradient d value / d p (N, 3); the grey-level
    and the contour residuals both step through it."""
    z = np.maximum(p[:, 2], 1e-6)
    h, w = images[0].shape
    u, v = scale * (K[0, 0] * p[:, 0] / z + K[0, 2]), scale * (K[1, 1] * p[:, 1] / z + K[1, 2])
    inside = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    value, gu, gv = _bilinear(images, u, v)
    grad = scale * np.stack([gu * K[0, 0] / z, gv * K[1, 1] / z, -(gu * K[0, 0] * p[:, 0] + gv * K[1, 1] * p[:, 1]) / z**2], axis=1)
    return inside, value, grad


def _has_grey(target: DepthView, grey_source: FloatArray) -> bool:
    """Whether both images carry grey levels to compare (a flat image's intensity is NaN everywhere)."""
    return bool(np.isfinite(target.intensity[0, 0]) and np.isfinite(grey_source).all())


def _photometric(p: FloatArray, grey_source: FloatArray, target: DepthView) -> tuple[FloatArray, FloatArray]:
    """Grey-level residuals I_target(project(p)) - I_source and their gradients d r / d p (N, 3);
    zero for points that project outside the target image."""
    inside, intensity, grad = _projected(p, target.K, (target.intensity, *target.gradient))
    r = intensity - grey_source
    return np.where(inside, r, 0.0), np.where(inside[:, None], grad, 0.0)


def _contour_residuals(p: FloatArray, target: DepthView) -> tuple[FloatArray, FloatArray]:
    """Distance from each point's projection to the target's nearest occluding contour, in metres
    at the point's depth, and its gradient d r / d p (N, 3); zero outside the target image."""
    inside, distance, grad = _projected(p, target.K, tuple(target.contour_distance), scale=2.0)
    metres = np.maximum(p[:, 2], 1e-6) / (2.0 * target.K[0, 0])  # per half pixel, held fixed within a step
    return np.where(inside, distance * metres, 0.0), np.where(inside[:, None], metres[:, None] * grad, 0.0)


def _bilinear(images: tuple[np.ndarray, ...], u: FloatArray, v: FloatArray) -> list[np.ndarray]:
    """Each (H, W) image (float32, C-contiguous) at pixels (u, v) (N,), bilinear, edges extended: the
    bits of scipy's ``map_coordinates(image, [v, u], order=1, mode="nearest")`` (the corners' values
    times their v and u weights, summed in its order, in float64, returned in the image's dtype) for
    every point inside the image (points outside are clamped to its edge), at a third of its time,
    the corner weights shared by the images. Written here because no library lookup fits: scipy's
    computes the weights again per image, and OpenCV's ``remap`` rounds sub-pixel positions to
    1/32 pixel (other bits, another trajectory)."""
    h, w = images[0].shape
    u, v = np.clip(u, 0, w - 1), np.clip(v, 0, h - 1)
    u0, v0 = np.floor(u), np.floor(v)
    fu, fv = u - u0, v - v0
    wu0, wv0 = 1.0 - fu, 1.0 - fv
    i0, j0 = u0.astype(np.intp), v0.astype(np.intp)
    i1, j1 = np.minimum(i0 + 1, w - 1), np.minimum(j0 + 1, h - 1)
    corners = ((j0 * w + i0, wv0, wu0), (j0 * w + i1, wv0, fu), (j1 * w + i0, fv, wu0), (j1 * w + i1, fv, fu))
    out = []
    for image in images:
        flat = image.ravel()
        value = flat[corners[0][0]] * corners[0][1] * corners[0][2]
        for index, weight_v, weight_u in corners[1:]:
            value += flat[index] * weight_v * weight_u
        out.append(value.astype(image.dtype))
    return out


def _tukey(r: FloatArray, k: float) -> FloatArray:
    return np.where(np.abs(r) < k, (1.0 - (r / k) ** 2) ** 2, 0.0)


def _gauss_newton(p_source: FloatArray, grey_source: FloatArray, p_contour: FloatArray, target: DepthView,
                  T: FloatArray, distance_m: float, iterations: int, config: DepthOdometryConfig,
                  grey_steps: bool) -> tuple[FloatArray, FloatArray] | None:
    """Gauss-Newton steps on point-to-plane distances (Tukey kernel of scale distance/2) plus,
    weighted by ``config.photometric_weight``, grey-level differences of the points whose surface
    correspondence holds (in the steps only when ``grey_steps``) and, weighted by
    ``config.contour_weight``, the distances of the source's occluding-contour points ``p_contour``
    to the target's contours. Returns the pose and the last
    step's (6, 6) normal matrix of both terms (rotation vector, translation; point-to-plane units),
    or None when fewer than 6 correspondences remain."""
    k = distance_m / 2.0
    for _ in range(iterations):
        p, q, n, has = _associate(p_source, target, T, distance_m, distance_m > config.projective_below_m)
        r = np.einsum("ij,ij->i", p - q, n)
        weight = np.where(has, _tukey(r, k), 0.0)
        use = weight > 0
        if use.sum() < 6:
            return None
        p, n, r, weight, grey = p[use], n[use], r[use], weight[use], grey_source[use]
        J = np.hstack([np.cross(p, n), n])  # d r / d (rotation vector, translation), left increment
        J_weighted = (J * weight[:, None]).T  # once for both products (same bits)
        A = J_weighted @ J
        b = J_weighted @ r
        if config.photometric_weight > 0 and _has_grey(target, grey):
            r_c, g = _photometric(p, grey, target)
            w_c = _tukey(r_c, config.grey_tukey) * config.photometric_weight
            J_c = np.hstack([np.cross(p, g), g])
            J_c_weighted = (J_c * w_c[:, None]).T
            A_grey = J_c_weighted @ J_c
            if grey_steps:
                A, b = A + A_grey, b + J_c_weighted @ r_c
        else:
            A_grey = np.zeros((6, 6))
        if len(p_contour):
            p_c = p_contour @ T[:3, :3].T + T[:3, 3]
            r_e, g_e = _contour_residuals(p_c, target)
            w_e = _tukey(r_e, k) * config.contour_weight
            J_e = np.hstack([np.cross(p_c, g_e), g_e])
            J_e_weighted = (J_e * w_e[:, None]).T
            A, b = A + J_e_weighted @ J_e, b + J_e_weighted @ r_e
        try:
            x = -np.linalg.solve(A, b)
        except np.linalg.LinAlgError:
            return None
        step = np.eye(4)
        step[:3, :3] = Rotation.from_rotvec(x[:3]).as_matrix()
        step[:3, 3] = x[3:]
        T = step @ T
        if np.linalg.norm(x[3:]) < 1e-4 and np.linalg.norm(x[:3]) < 1e-4:  # 0.1 mm, 0.1 mrad
            break
    return T, A if grey_steps else A + A_grey


def _rounds(source: DepthView, target: DepthView, T: FloatArray, rounds: list[tuple[int, float]],
            config: DepthOdometryConfig, keep: BoolArray | None = None) -> tuple[FloatArray, FloatArray] | None:
    """The coarse-to-fine rounds (stride, correspondence distance) from ``T``: the pose and the last
    round's normal matrix, or None."""
    T = np.asarray(T, dtype=np.float64)
    A = np.zeros((6, 6))
    p_contour = source.contour_points(keep) if config.contour_weight > 0 else np.zeros((0, 3))
    if len(p_contour) < config.min_contour_points:
        p_contour = np.zeros((0, 3))
    for k, (stride, distance) in enumerate(rounds):
        final_round = k == len(rounds) - 1
        result = _gauss_newton(*source.points(stride, keep), p_contour, target, T, distance, config.iterations, config,
                               grey_steps=not final_round or config.grey_in_final_round)
        if result is None:
            return None
        T, A = result
    return T, A


def _unchanged(source: DepthView, target: DepthView, T: FloatArray, distance_m: float,
               config: DepthOdometryConfig) -> BoolArray | None:
    """(h, w) map pixels of the source outside large regions that are off the target's surface
    at ``T`` (and a margin around them); None when there are none."""
    if config.changed_min_fraction <= 0:
        return None
    h, w = source.p_map.shape[:2]
    p = source.p_map.reshape(-1, 3)
    usable = np.isfinite(p[:, 2])
    p_t, q, n, has = _associate(np.where(usable[:, None], p, 0.0), target, T, np.inf, nearest=False)
    with np.errstate(invalid="ignore"):
        r = np.abs(np.einsum("ij,ij->i", p_t - q, n))
    off = usable & has & ~(r < distance_m)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(off.reshape(h, w).astype(np.uint8), connectivity=8)
    large = stats[:, cv2.CC_STAT_AREA] > config.changed_min_fraction * usable.sum()
    large[0] = False
    if not large.any():
        return None
    size = 2 * config.changed_margin_px + 1
    changed = cv2.dilate(large[labels].astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)))
    return changed == 0


def register_depth(source: DepthView, target: DepthView, T_init: FloatArray,
                   config: DepthOdometryConfig = DepthOdometryConfig()) -> DepthFit | None:  # noqa: B008
    """T_target_source by coarse-to-fine projective point-to-plane ICP from ``T_init``; None when
    it is not trustworthy (too little of the frame on the keyframe's surface at the noise-derived
    distance, or a jump from the guess)."""
    final = _final_distance(source, target, config)
    if len(config.coarse_strides) != len(config.coarse_distances_m):
        raise ValueError("coarse_strides and coarse_distances_m must have one entry per coarse round")
    rounds = [(s, d) for s, d in zip(config.coarse_strides, config.coarse_distances_m, strict=True) if d > final]
    rounds.append((config.final_stride, final))
    result = _rounds(source, target, T_init, rounds, config)
    if result is None:
        return None
    keep = _unchanged(source, target, result[0], final, config)
    if config.changed_at_guess:
        keep_guess = _unchanged(source, target, np.asarray(T_init, dtype=np.float64), final, config)
        if keep_guess is not None:
            fit = _checked(source, target, T_init, rounds, final, config, keep_guess if keep is None else keep & keep_guess)
            if fit is not None:
                return fit
    return _checked(source, target, T_init, rounds, final, config, keep, None if keep is not None else result)


def _checked(source: DepthView, target: DepthView, T_init: FloatArray, rounds: list[tuple[int, float]], final: float,
             config: DepthOdometryConfig, keep: BoolArray | None,
             result: tuple[FloatArray, FloatArray] | None = None) -> DepthFit | None:
    """The registration from ``T_init`` on the source's ``keep`` pixels (``result``: already run), if trustworthy."""
    if result is None:
        result = _rounds(source, target, T_init, rounds, config, keep)
        if result is None:
            return None
    T, A = result
    # How well the surfaces (and grey edges) pin each direction: the pose covariance of residuals
    # with the depth noise, sigma^2 A^-1. A plain wall with a door leaves a slide along them free.
    try:
        covariance = (final / config.noise_sigmas) ** 2 * np.linalg.inv(A)
    except np.linalg.LinAlgError:
        return None
    std_rad = math.sqrt(max(np.linalg.eigvalsh(covariance[:3, :3]).max(), 0.0))
    std_m = math.sqrt(max(np.linalg.eigvalsh(covariance[3:, 3:]).max(), 0.0))
    step_m, step_rad = pose_difference(T_init, T)
    if (step_m > config.max_step_m or step_rad > config.max_step_rad or std_m > config.max_std_m
            or std_rad > config.max_std_rad):
        return None
    p_source, _ = source.points(config.final_stride, keep)
    r = _surface_distances(p_source, target, T, final)
    on_surface = r < final
    fitness = float(on_surface.mean())
    if fitness < config.min_fitness:
        return None
    return DepthFit(T, fitness, float(np.sqrt(np.mean(r[on_surface] ** 2))), final, p_source[on_surface])


def _final_distance(source: DepthView, target: DepthView, config: DepthOdometryConfig) -> float:
    """The final round's correspondence distance: ``noise_sigmas`` standard deviations of the depth noise of
    both views at their median depths, at least ``min_distance_m``."""
    noise = config.depth_noise
    sigma = math.hypot(*(noise.base_m + noise.quadratic_per_m * (z - noise.offset_m) ** 2
                         for z in (source.median_depth_m, target.median_depth_m)))
    return max(config.min_distance_m, config.noise_sigmas * sigma)


def _surface_distances(p_source: FloatArray, target: DepthView, T: FloatArray, distance_m: float) -> FloatArray:
    """Point-to-plane distance of each source point, moved by ``T``, to the target pixel it projects to; inf
    where it has none within ``distance_m``."""
    p, q, n, has = _associate(p_source, target, T, distance_m, nearest=False)
    r = np.full(len(p), np.inf)
    r[has] = np.abs(np.einsum("ij,ij->i", p[has] - q[has], n[has]))
    return r


def surface_agreement(source: DepthView, target: DepthView, T_target_source: FloatArray,
                      config: DepthOdometryConfig = DepthOdometryConfig(),  # noqa: B008
                      grey_tolerance: float | None = None) -> float:
    """Fraction of the source's usable points (final stride) that ``T_target_source`` puts on the target's
    surface, within the noise-derived distance of :func:`register_depth`: how well a pose found otherwise
    (ORB matches) explains the two views' depth. With ``grey_tolerance`` (grey levels in [0, 1]), a point
    must also land where the target's grey level is within it of its own, where both images have any: a
    slide along a textured floor or counter leaves the depth on its plane but not the texture."""
    final = _final_distance(source, target, config)
    p_source, grey = source.points(config.final_stride)
    agrees = _surface_distances(p_source, target, T_target_source, final) < final
    if grey_tolerance is not None and _has_grey(target, grey):
        residual, _ = _photometric(transform_points(T_target_source, p_source), grey, target)
        agrees &= np.abs(residual) < grey_tolerance
    return float(agrees.mean())


__all__ = ["DepthFit", "DepthOdometryConfig", "DepthView", "depth_view", "register_depth", "surface_agreement"]
