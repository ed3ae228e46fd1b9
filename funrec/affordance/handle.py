"""Handle snapping: the front plane of a part around a first contact estimate, the protruding
handle geometry nearest to it (or the bar under the hand when that does not fit the hold), and
the grasp frame on that handle.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from funrec.affordance.types import AffordanceConfig
from funrec.formats.twin import ArticulatedPart
from funrec.geometry.fitting import fit_circles
from funrec.geometry.transforms import make_transform
from funrec.typed import BoolArray, FloatArray

_CIRCLE_REFITS = 2
"""Refits of a held bar's cross-section circle on the points close to it: the first moves the
synthetic test bar's axis 1 cm (off the rim), later ones move the three mw_* contacts under 0.3 mm
(measured)."""

_EXTENT_PERCENTILES = (1.0, 99.0)
"""Percentiles of the handle points along the handle that give its extent (ends robust to a few
stray points fused onto it)."""


def grasp_at_handle(
    part: ArticulatedPart,
    p_local: FloatArray,
    c_first: FloatArray,
    p_hand: FloatArray,
    up: FloatArray,
    config: AffordanceConfig,
    rng: np.random.Generator,
) -> tuple[FloatArray, FloatArray, bool]:
    """Contact point (3,), T_world_grasp (4, 4) and whether handle geometry was found, from
    (N, 3) part surface points around the first estimate ``c_first``.

    The front surface around the first estimate is the front-most wide layer parallel to the
    RANSAC plane of the points visible from the hand's side (:func:`front_plane`); points within
    ``handle_search_radius_m`` standing out of it towards the hand are handle geometry, and the
    linked piece of it nearest to the estimate (per point) is the handle: its centre (or, on a long handle,
    the centre of its part near the estimate) is the contact point, its direction the x axis.
    When that contact does not fit the hold (:func:`_fits_the_hold`), the plane was the top of the
    held bar seen from above: the contact is the bar's axis level with the estimate
    (:func:`_bar_under_hand`), approached from the hand's side.
    """
    towards_hand = p_hand - c_first if np.linalg.norm(p_hand - c_first) > 1e-9 else up
    front, origin, normal, inliers = front_plane(p_local, c_first, towards_hand, config, rng)
    plane_points = front[inliers]
    # Handle points: all points standing out of the front within the (wider) handle search, not
    # only the front layer: a bar fused a little off in height (after-release views with a state
    # error) lies partly under itself, and that part links its pieces into one handle.
    radius = config.handle_radius_m
    nearby = p_local[np.linalg.norm(p_local - c_first, axis=1) < radius]
    height = (nearby - origin) @ normal
    candidate = (height > config.handle_min_height_m) & (height < config.handle_max_height_m)
    handle = _nearest_handle(nearby[candidate], c_first, config)
    handle_found = len(handle) >= config.min_handle_points
    contact = c_first
    if handle_found:
        centre, direction = handle.mean(axis=0), principal_direction(handle)
        along = (handle - centre) @ direction
        # The middle of the handle's extent, not the mean of its points: the fused part may
        # lack a stretch of the handle that the hand hid. The extent is the 1-99 % range: three
        # stray points 3 cm beyond the end of pri_drawer_00's lip moved its centre 1.1 cm.
        lo, hi = np.percentile(along, _EXTENT_PERCENTILES)
        contact = centre + 0.5 * (lo + hi) * direction
        cut = np.linalg.norm(handle - c_first, axis=1).max() > radius - 2 * config.handle_link_m
        if cut or hi - lo > config.max_handle_length_m:  # long, or reaching out of the search
            # Where the hand was along the handle: its far end is centred on the grip (the
            # fingers wrap the bar on both sides), closer than the surface votes when the
            # fused part has a hole under the hand (measured: 0.5 cm against 2.7 cm).
            contact = centre + np.clip((p_hand - centre) @ direction, lo, hi) * direction
    z = -normal
    x = _handle_axis(part, handle if handle_found else np.zeros((0, 3)), plane_points, z, config)
    if not _fits_the_hold(part, contact, normal, p_hand, config):
        bar = _bar_under_hand(p_local, c_first, config)
        if bar is not None:
            point, direction = bar
            approach = (point - p_hand) - ((point - p_hand) @ direction) * direction
            if np.linalg.norm(approach) > 1e-9:  # from the hand's side towards the bar's axis
                contact, x, z, handle_found = point, direction, approach / np.linalg.norm(approach), True
    y = np.cross(z, x)
    # Sign: of x and y, whichever is closer to the camera's up direction points up.
    if abs(y @ up) >= abs(x @ up):
        if y @ up < 0:
            x, y = -x, -y
    elif x @ up < 0:
        x, y = -x, -y
    return contact, make_transform(np.stack([x, y, z], axis=1), contact), handle_found


def _fits_the_hold(part: ArticulatedPart, contact: FloatArray, normal: FloatArray, p_hand: FloatArray, config: AffordanceConfig) -> bool:
    """Whether a contact (3,) snapped with the front plane's unit ``normal`` (3,) agrees with the hold:
    the hand's far end ``p_hand`` (3,) is within ``max_hand_distance_m`` of it (the hand wraps the
    handle), and a revolute part's front contains its hinge (``max_front_hinge_cos``)."""
    if np.linalg.norm(contact - p_hand) > config.max_hand_distance_m:
        return False
    return part.joint_type != "revolute" or abs(normal @ part.axis_world) <= config.max_front_hinge_cos


def _bar_under_hand(p: FloatArray, c: FloatArray, config: AffordanceConfig) -> tuple[FloatArray, FloatArray] | None:
    """The bar the hand held when no front explains the hold: the point (3,) of its axis level
    with ``c`` and its unit direction (3,), from the (N, 3) points within ``bar_fit_radius_m`` of
    ``c`` (their principal direction, and a least-squares circle through them across it); None when
    they are too few or their circle is wider than a handle (``handle_max_height_m``).

    A bar seen from above (mw_drawer_00: the camera 0.9 m above a drawer's bar) shows its top, level
    with the part's rim: the largest plane around the estimate is that top, and what stands out of
    it is not the handle."""
    near = p[np.linalg.norm(p - c, axis=1) < config.bar_fit_radius_m]
    if len(near) < config.min_handle_points:
        return None
    centre = near.mean(axis=0)
    direction = np.linalg.eigh((near - centre).T @ (near - centre))[1][:, 2]
    section = (near - centre) - np.outer((near - centre) @ direction, direction)
    # Kasa's algebraic circle (no geometric refinement), as fit_circles does it for tracks
    m, _, radius = fit_circles(section, np.ones(len(section)), refine_iterations=0)
    # Refitted on the points within the plane tolerance of the circle: the rim next to a drawer's
    # bar is in the fit radius too (it pulled the synthetic bar's axis 1 cm towards itself).
    for _ in range(_CIRCLE_REFITS):
        on_circle = np.abs(np.linalg.norm(section - m, axis=1) - radius) < config.plane_tolerance_m
        if np.count_nonzero(on_circle) < config.min_handle_points:
            break
        m, _, radius = fit_circles(section, on_circle.astype(np.float64), refine_iterations=0)
    radius = float(radius)
    if not 0.0 < radius <= config.handle_max_height_m:
        return None
    axis_point = centre + m
    return axis_point + ((c - axis_point) @ direction) * direction, direction


def front_plane(
    p: FloatArray, c: FloatArray, towards_hand: FloatArray, config: AffordanceConfig, rng: np.random.Generator
) -> tuple[FloatArray, FloatArray, FloatArray, BoolArray]:
    """The part's front around ``c``: the points within ``search_radius_m`` visible from the hand's
    side (m, 3), a point on their RANSAC plane (3,), its unit normal towards the hand (3,) and the
    plane's inliers (m,). With fewer than 3 points the plane faces the hand through ``c``."""
    near = p[np.linalg.norm(p - c, axis=1) < config.search_radius_m]
    front = near[_front_layer(near - c, towards_hand, config)]
    if len(front) < 3:
        return front, c, towards_hand / np.linalg.norm(towards_hand), np.ones(len(front), dtype=bool)
    origin, normal, inliers = _plane_ransac(front, config, rng)
    normal = normal if normal @ towards_hand >= 0 else -normal
    origin = _front_most_layer(front, origin, normal, config)
    return front, origin, normal, np.abs((front - origin) @ normal) < config.plane_tolerance_m


def _front_most_layer(p: FloatArray, origin: FloatArray, normal: FloatArray, config: AffordanceConfig) -> FloatArray:
    """(3,) a point on the front-most layer of (N, 3) points parallel to the plane (``origin``,
    ``normal``) and up to ``handle_max_height_m`` in front of it that is wide in both directions
    (``front_min_width_m``, ``front_min_area_m2``); ``origin`` when none is.

    RANSAC keeps the plane with the most points, which is not always the front: a part fused
    with states a few cm off holds a second copy of its front behind the real one, and the
    copy can be the larger (multi_kitchen_01 drawer: 4,700 points 2.8 cm behind a front of
    2,300, so its bar counted as 6 cm proud and the front panel as the handle). A handle is
    narrow in one direction (bar, lip) or both (knob), a front is not.
    """
    height = (p - origin) @ normal
    tol = config.plane_tolerance_m
    above = (height > config.handle_min_height_m) & (height < config.handle_max_height_m)
    if np.count_nonzero(above) < 3:
        return origin
    # Layer heights: local maxima of the count within +-tol, front-most first.
    levels = np.arange(config.handle_min_height_m, config.handle_max_height_m + tol, tol / 2)
    ordered = np.sort(height[above])
    count = np.searchsorted(ordered, levels + tol) - np.searchsorted(ordered, levels - tol)
    peaks = [i for i in range(len(levels)) if count[i] > 0 and count[i] >= count[max(i - 1, 0)] and count[i] >= count[min(i + 1, len(levels) - 1)]]
    e1 = np.cross(normal, np.eye(3)[int(np.argmin(np.abs(normal)))])
    e1 /= np.linalg.norm(e1)
    basis = np.stack([e1, np.cross(normal, e1)], axis=1)
    for i in sorted(peaks, reverse=True):
        layer = np.abs(height - levels[i]) < tol
        if np.count_nonzero(layer) < 3:
            continue
        uv = (p[layer] - origin) @ basis
        uv -= uv.mean(axis=0)
        minor = np.linalg.eigh(uv.T @ uv)[1][:, 0]
        width = np.subtract(*np.percentile(uv @ minor, [95, 5]))
        area = len(np.unique(np.floor(uv / config.front_cell_m).astype(np.int64), axis=0)) * config.front_cell_m**2
        if width >= config.front_min_width_m and area >= config.front_min_area_m2:
            return origin + float(np.median(height[layer])) * normal
    return origin


def _front_layer(p: FloatArray, view: FloatArray, config: AffordanceConfig) -> BoolArray:
    """(N,) points (relative to a centre) within ``front_depth_m`` of the front-most point of
    their cell, seen along ``view`` (a z-buffer on a grid of ``front_cell_m`` cells)."""
    u = view / np.linalg.norm(view)
    e1 = np.cross(u, np.eye(3)[int(np.argmin(np.abs(u)))])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    cells = np.floor(np.stack([p @ e1, p @ e2], axis=1) / config.front_cell_m).astype(np.int64)
    _, cell = np.unique(cells, axis=0, return_inverse=True)
    cell = cell.ravel()
    height = p @ u
    top = np.full(cell.max() + 1 if len(cell) else 0, -np.inf)
    np.maximum.at(top, cell, height)
    return height >= top[cell] - config.front_depth_m


def _plane_ransac(p: FloatArray, config: AffordanceConfig, rng: np.random.Generator) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Dominant plane of (N, 3) points: RANSAC on 3-point samples (all scored in one (N, k)
    product), refitted on the inliers. Returns a point on it (3,), unit normal (3,), inliers (N,)."""
    sample = p[rng.integers(0, len(p), size=(config.plane_hypotheses, 3))]
    n = np.cross(sample[:, 1] - sample[:, 0], sample[:, 2] - sample[:, 0])
    length = np.linalg.norm(n, axis=1)
    ok = length > 1e-12
    if not ok.any():
        centre = p.mean(axis=0)
        return centre, _least_spread_direction(p), np.ones(len(p), dtype=bool)
    n = n[ok] / length[ok, None]
    # Signed distance of every point to every hypothesis: (N, k), never (k, N, 3).
    distance = np.abs(p @ n.T - np.einsum("kj,kj->k", sample[ok, 0], n))
    inliers = distance[:, int(np.argmax((distance < config.plane_tolerance_m).sum(axis=0)))] < config.plane_tolerance_m
    return p[inliers].mean(axis=0), _least_spread_direction(p[inliers]), inliers


def _nearest_handle(p: FloatArray, c: FloatArray, config: AffordanceConfig) -> FloatArray:
    """The handle among (N, 3) handle-height points: the piece (linked by distances below
    ``handle_link_m``, at least ``min_handle_points``) with the least squared distance to ``c``
    per point (a large piece beats a sliver slightly nearer), joined by the
    pieces lying along its axis when it is elongated (within ``handle_link_m`` of the line: one
    bar that the hand's hole in the fused part split). (0, 3) if there is none."""
    if len(p) < config.min_handle_points:
        return np.zeros((0, 3))
    pairs = cKDTree(p).query_pairs(config.handle_link_m, output_type="ndarray")
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(p), len(p)))
    _, label = connected_components(graph, directed=False)
    size = np.bincount(label)
    nearest = np.full(len(size), np.inf)
    np.minimum.at(nearest, label, np.linalg.norm(p - c, axis=1))
    # Nearness per point: squared distance (at least the link length) over the piece's size. A
    # thin sliver at the front's border 3 cm from an estimate that landed high loses to the solid
    # bar 4 cm away (pri_drawer_00 with detected hands: 8.8 cm off by the plain nearest piece,
    # 0.9 cm with this; unchanged on the other bench twins, measured).
    score = np.maximum(nearest, config.handle_link_m) ** 2 / size
    score[size < config.min_handle_points] = np.inf
    if not np.isfinite(score).any():
        return np.zeros((0, 3))
    chosen = int(np.argmin(score))
    first = p[label == chosen]
    centre, direction = first.mean(axis=0), principal_direction(first)
    spread = np.linalg.eigvalsh(np.cov((first - centre).T)) if len(first) > 3 else np.zeros(3)
    if not spread[2] > config.handle_anisotropy**2 * spread[1]:
        return first  # a knob or a blob has no axis to extend along
    offset = p - centre
    off_axis = np.linalg.norm(offset - np.outer(offset @ direction, direction), axis=1)
    median_off_axis = np.full(len(size), np.inf)
    for piece in np.flatnonzero(size >= config.min_handle_points):
        median_off_axis[piece] = np.median(off_axis[label == piece])
    # The chosen piece stays even when its own points lie off its axis (a bar fused in two
    # heights: multi_kitchen_01 lost its handle in half of the RANSAC seeds, measured).
    median_off_axis[chosen] = 0.0
    return p[median_off_axis[label] < config.handle_link_m]


def principal_direction(p: FloatArray) -> FloatArray:
    """(3,) unit direction of the largest spread of (N, 3) points."""
    q = p - p.mean(axis=0)
    return np.linalg.eigh(q.T @ q)[1][:, 2]


def _least_spread_direction(p: FloatArray) -> FloatArray:
    """(3,) unit direction of the smallest spread of (N, 3) points (a plane's normal), from the
    (3, 3) scatter matrix: an SVD of the (N, 3) points would build an (N, N) factor (800 MB at
    10,000 points, measured)."""
    q = p - p.mean(axis=0)
    return np.linalg.eigh(q.T @ q)[1][:, 0]


def _handle_axis(part: ArticulatedPart, handle: FloatArray, front: FloatArray, z: FloatArray, config: AffordanceConfig) -> FloatArray:
    """(3,) unit grasp x axis orthogonal to ``z``: the handle's principal direction when it is
    elongated, else the joint axis (revolute) or the front's wider direction (prismatic)."""
    project = np.eye(3) - np.outer(z, z)

    def principal(p: FloatArray) -> tuple[FloatArray, float]:
        q = (p - p.mean(axis=0)) @ project
        values, vectors = np.linalg.eigh(q.T @ q)
        return vectors[:, 2], float(np.sqrt(values[2] / max(values[1], 1e-18)))

    if len(handle) >= 3:
        axis, ratio = principal(handle)
        if ratio > config.handle_anisotropy:
            return axis / np.linalg.norm(axis)
    axis = project @ part.axis_world if part.joint_type == "revolute" else np.zeros(3)
    if np.linalg.norm(axis) < 0.1 and len(front) >= 3:
        axis = principal(front)[0]
    if np.linalg.norm(axis) < 1e-6:
        axis = project @ np.eye(3)[int(np.argmin(np.abs(z)))]
    return axis / np.linalg.norm(axis)


__all__ = ["front_plane", "grasp_at_handle", "principal_direction"]
