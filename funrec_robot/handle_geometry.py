"""How far a handle stands proud of its part's front, and whether it is a knob, measured on a twin's part mesh.

A twin's affordance gives the contact point and the approach but not the handle's standoff; the planner
needs it to keep the fingertips clear of the front (and to know how far the grasp may pitch for a low
handle). The front is the part's surface around the contact point: the part mesh's points in a ring about
the approach line through the contact, binned by depth along the approach. The nearest depth bin holding a
good share of the points is the front (the first, not the fullest: a door's glass or a recessed panel lies
deeper than the frame the fingertips would meet).

Measured on the 26 parts of the bench twins (session 4): within 4 mm of the true standoff wherever the
contact point lies on the handle (bars 1.6-2.1 cm, knobs and thick bars 2.9-3.7 cm).

The handle itself is what stands proud of that front near the contact: its extent along the handle axis
the affordance gives tells a knob (1.7-3.2 cm on the bench twins) from a bar (14-40 cm); a knob is grasped
with the fingers closing horizontally, which lets the grasp pitch far more for a low drawer. A knob is grasped
at its centre; a bar where the hand held it along the bar, but centred across it: the affordance's contact
can miss the bar sideways by more than the jaws forgive (4.4 cm on the 4988aea-era twin of
``plain_rev_cabinet_left_00``, where the fingertip then struck the bar at 157 N), while the part mesh shows
the bar itself where it is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from funrec.geometry.fitting import fit_circles
from funrec.typed import FloatArray

RING_M = (0.04, 0.15)
"""Inner and outer radius of the ring about the approach line whose points are the front, m: inside it lie
the handle and the hand's own reconstruction; beyond it other features of the part."""
DEPTH_WINDOW_M = 0.10
"""Points farther than this from the contact along the approach are not the front, m."""
BIN_M = 0.005
"""Depth bin, m (about the mesh's voxel size)."""
FRONT_SHARE = 0.25
"""The front is the nearest bin with at least this share of the fullest bin's points."""
MIN_POINTS = 200
"""Fewer ring points than this: no estimate."""
MAX_STANDOFF_M = 0.06
"""Standoffs beyond this are not believed (a contact floating in front of the part), m."""


def front_standoff(p_part: npt.ArrayLike, p_contact: npt.ArrayLike, approach: npt.ArrayLike) -> float | None:
    """Distance from the contact point to the part's front along the approach, m; None if it cannot be told.

    Args:
        p_part: (N, 3) points of the part (mesh vertices) at the state of the contact point.
        p_contact: (3,) contact point on the handle.
        approach: (3,) unit approach direction (into the part).

    Returns:
        The near edge of the front's depth bin (a conservative standoff: the fingertips err away from the
        front), or None with too few points around the contact, or a front behind the contact or beyond
        ``MAX_STANDOFF_M``.
    """
    approach = np.asarray(approach, dtype=np.float64)
    relative = np.asarray(p_part, dtype=np.float64) - np.asarray(p_contact, dtype=np.float64)
    depth = relative @ approach
    lateral = np.linalg.norm(relative - np.outer(depth, approach), axis=1)
    ring = (lateral >= RING_M[0]) & (lateral <= RING_M[1]) & (np.abs(depth) <= DEPTH_WINDOW_M)
    if int(ring.sum()) < MIN_POINTS:
        return None
    edges = np.arange(-DEPTH_WINDOW_M, DEPTH_WINDOW_M + BIN_M / 2, BIN_M)
    counts, _ = np.histogram(depth[ring], bins=edges)
    front = int(np.flatnonzero(counts >= FRONT_SHARE * counts.max())[0])
    standoff = float(edges[front])
    if not 0.0 <= standoff <= MAX_STANDOFF_M:
        return None
    return standoff


PROUD_M = 0.012
"""A point belongs to the handle when it stands at least this far proud of the front, m (beyond the front's
depth bin and the mesh's noise)."""
HANDLE_WINDOW_M = (0.20, 0.05)
"""Handle points lie within this distance of the contact along the handle axis and across it, m."""
MIN_HANDLE_POINTS = 20
"""Fewer handle points than this: the handle's shape is not told."""
KNOB_MAX_LENGTH_M = 0.06
"""A handle no longer than this along its axis is a knob, m."""
BAR_MAX_WIDTH_M = 0.05
"""A bar's points across it (5th to 95th percentile) span at most this, m: the bench's bars are 8-20 mm,
Meta-World's drawer bar 51 mm in its other direction; a wider spread of points proud of the front is not one
bar (the hand's own reconstruction, a frame), and the contact is then left where it is."""
BAR_SHIFT_MIN_M = 0.005
"""The contact is moved onto the bar's middle only when it lies farther than this off it, m: a twin's part is
fused on a 5 mm grid, so a smaller shift is the mesh's noise (a 0.3 mm shift of the 7120ead twin of
plain_rev_dishwasher_00's contact turned its base placement, at the edge of the reach window, from found to
not found)."""


@dataclass(frozen=True)
class HandleShape:
    """What the part mesh tells of the handle around a contact point."""

    standoff: float | None
    """Distance from the contact point to the front along the approach (``front_standoff``), m."""
    length: float | None
    """Extent of the handle's points along the handle axis, m; None if not told."""
    p_centre: FloatArray | None
    """(3,) centroid of the handle's points, moved along the approach to the contact's depth; None if not told."""
    p_bar: FloatArray | None = None
    """(3,) the contact moved across the handle axis to the median of the handle's points across it (a bar's
    middle, ``BAR_MAX_WIDTH_M``; not for less than ``BAR_SHIFT_MIN_M``), along the axis and in depth where it
    was; None if not told or not one bar."""
    thickness_max: float | None = None
    """Extent of a bar's points across it (across the approach and the handle axis), m: at most as thick as
    that, the fused surface lying a little outside the true one (on the 16 bench twins' bars 1.4-11.7 mm thicker
    than the true 8-15 mm bars); None if not told or not one bar."""

    @property
    def is_knob(self) -> bool:
        return self.length is not None and self.length < KNOB_MAX_LENGTH_M


def measure_handle(
    p_part: npt.ArrayLike, p_contact: npt.ArrayLike, approach: npt.ArrayLike, handle_axis: npt.ArrayLike
) -> HandleShape:
    """The standoff, length and centre of the handle at a contact point (see the module's docstring).

    Args:
        p_part: (N, 3) points of the part at the state of the contact point.
        p_contact: (3,) contact point.
        approach: (3,) unit approach direction (into the part).
        handle_axis: (3,) unit handle axis, perpendicular to the approach.
    """
    p_part = np.asarray(p_part, dtype=np.float64)
    p_contact = np.asarray(p_contact, dtype=np.float64)
    approach = np.asarray(approach, dtype=np.float64)
    handle_axis = np.asarray(handle_axis, dtype=np.float64)
    standoff = front_standoff(p_part, p_contact, approach)
    if standoff is None:
        return HandleShape(None, None, None)
    relative = p_part - p_contact
    depth, along, across = relative @ approach, relative @ handle_axis, relative @ np.cross(approach, handle_axis)
    handle = (depth <= standoff - PROUD_M) & (depth >= -DEPTH_WINDOW_M) & (np.abs(along) <= HANDLE_WINDOW_M[0])
    handle &= np.abs(across) <= HANDLE_WINDOW_M[1]
    if int(handle.sum()) < MIN_HANDLE_POINTS:
        return HandleShape(standoff, None, None)
    centre = p_part[handle].mean(axis=0)
    centre -= approach * float((centre - p_contact) @ approach)
    low, high = np.percentile(across[handle], [5.0, 95.0])
    p_bar, thickness = None, None
    shift = float(np.median(across[handle]))
    if high - low <= BAR_MAX_WIDTH_M:
        p_bar = p_contact + np.cross(approach, handle_axis) * (shift if abs(shift) > BAR_SHIFT_MIN_M else 0.0)
        thickness = float(np.ptp(across[handle]))
    return HandleShape(standoff, float(np.ptp(along[handle])), centre, p_bar, thickness)


BAR_FIT_RADIUS_M = 0.06
"""A contact with no front near it (``front_standoff`` None: a lever or a bar standing far off its part) is held on
a bar whose section is the part's points within this distance of it, m (the affordance stage's
``bar_fit_radius_m``); a section wider than twice this is not seen whole, and its fit is not believed."""
BAR_FIT_INLIER_M = 0.005
"""Points within this distance of the fitted circle are its inliers, m (the mesh's 5 mm grid)."""
BAR_FIT_MIN_SHARE = 0.5
"""At least this share of the section's points must lie on the circle for it to be a round bar."""
BAR_FIT_MARGIN_M = 0.012
"""The bar is at least its fitted circle's diameter less this, m: a fused surface lies up to 11.7 mm (in
thickness) outside a true bar (``HandleShape.thickness_max``); on the three Meta-World twins, whose contacts have
no front near them, the fits came 2.4 mm under to 3.8 mm over the true 109, 51 and 40 mm bars."""


def bar_thickness_min(p_part: npt.ArrayLike, p_contact: npt.ArrayLike, handle_axis: npt.ArrayLike) -> float | None:
    """The least thickness of a round bar held at a contact with no front near it, m; None if not told.

    The part's points within ``BAR_FIT_RADIUS_M`` of the contact, flattened onto the plane across the handle
    axis, are the bar's section; a circle is fitted to them (refitted on its inliers) and the bar is at least its
    diameter less ``BAR_FIT_MARGIN_M``. Not told with too few points, a circle wider than the section that was
    seen, one off the contact by more than its radius, or fewer than ``BAR_FIT_MIN_SHARE`` of the points on it.

    Args:
        p_part: (N, 3) points of the part at the state of the contact point.
        p_contact: (3,) contact point (the bar's middle).
        handle_axis: (3,) unit handle axis.
    """
    p_part = np.asarray(p_part, dtype=np.float64)
    axis = np.asarray(handle_axis, dtype=np.float64)
    relative = p_part - np.asarray(p_contact, dtype=np.float64)
    relative = relative[np.linalg.norm(relative, axis=1) < BAR_FIT_RADIUS_M]
    if len(relative) < MIN_HANDLE_POINTS:
        return None
    section = relative - np.outer(relative @ axis, axis)
    weights = np.ones(len(section))
    for _ in range(3):
        centre, _, radius = fit_circles(section, weights)
        on_circle = np.abs(np.linalg.norm(section - centre, axis=1) - radius) < BAR_FIT_INLIER_M
        if int(on_circle.sum()) < MIN_HANDLE_POINTS:
            return None
        weights = on_circle.astype(np.float64)
    radius = float(radius)
    if radius > BAR_FIT_RADIUS_M or np.linalg.norm(centre) > radius or on_circle.mean() < BAR_FIT_MIN_SHARE:
        return None
    return max(2.0 * radius - BAR_FIT_MARGIN_M, 0.0)


__all__ = ["BAR_FIT_MARGIN_M", "BAR_FIT_RADIUS_M", "BAR_MAX_WIDTH_M", "BAR_SHIFT_MIN_M", "BIN_M", "FRONT_SHARE", "KNOB_MAX_LENGTH_M", "MIN_HANDLE_POINTS", "PROUD_M", "HandleShape", "bar_thickness_min", "front_standoff", "measure_handle"]
