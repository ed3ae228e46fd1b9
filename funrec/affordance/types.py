"""Affordance types: the settings of :func:`funrec.affordance.contacts.find_affordances` and its result
(held parts with contact point, grasp frame and demonstrated motion); see :mod:`funrec.affordance.contacts`
for the conventions and :mod:`funrec.formats.affordances` for affordances.json.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy.typing as npt
import trimesh

from funrec.surfaces.hands import HandConfig

REFERENCE_WIDTH_PX = 640
"""Image width at which pixel sizes of :class:`AffordanceConfig` are given."""

PartSurface = trimesh.Trimesh | trimesh.PointCloud | npt.ArrayLike
"""A part's surface at its canonical state, world frame: a mesh, a point cloud or (N, 3) points."""


@dataclass(frozen=True)
class AffordanceConfig:
    """Settings of :func:`find_affordances`; lengths in metres, durations in seconds."""

    hands: HandConfig = field(default_factory=HandConfig)
    """Hand detection, used when no hand masks are passed in."""
    surface_spacing_m: float = 0.005
    """Mesh faces are sampled with one point per this spacing squared (as the ground truth's
    5 mm points); point clouds are used as they are."""
    hand_erosion_px: int = 2
    """Hand masks are eroded by this many pixels (at 640 px image width, scaled with the width)
    before lifting: edge depth mixes hand and scene."""
    hand_stride_px: int = 2
    """Every k-th hand pixel in each direction is lifted (at 640 px image width, scaled with the
    width; a hand covers thousands of pixels)."""
    distal_quantile: float = 0.98
    """The hand's far end: points whose distance from the camera is within ``distal_band_m`` of
    this quantile of all hand points' distances. The egocentric arm reaches away from the eyes,
    so its far end is the gripping hand, whichever side of it the camera sees."""
    distal_band_m: float = 0.04
    """Depth of the hand's far end, metres (about a hand's thickness)."""
    contact_distance_m: float = 0.08
    """Far-end points within this of the part surface put the hand at the part. The camera sees
    the back of the hand, 4-6 cm off the surface it grips (measured on the synthetic bench)."""
    min_contact_points: int = 5
    """Fewest far-end points near the part for a frame to count as touching it."""
    hold_radius_m: float = 0.04
    """A touching frame is a hold when the far end's centroid, in the part's canonical frame, is
    within this of the grip position (where it stays longest): a held hand moves with the part."""
    max_gap_s: float = 0.2
    """Holds separated by shorter gaps (missed detections) are merged."""
    min_hold_s: float = 0.3
    """Shorter holds are dropped (brushing past a part)."""
    min_motion_rad: float = 0.05
    """A hold of a revolute part is an interaction only if the part turns this much during it."""
    min_motion_m: float = 0.02
    """A hold of a prismatic part is an interaction only if the part slides this much during it."""
    vote_top_fraction: float = 0.5
    """Surface points with at least this fraction of the top contact vote form the contact core,
    whose vote-weighted centre is the first contact estimate."""
    region_fraction: float = 0.25
    """Surface points with at least this fraction of the top vote form the contact region."""
    region_max_points: int = 2000
    """Most points written for the contact region (highest weights kept)."""
    search_radius_m: float = 0.2
    """Radius around the first estimate in which the front surface is fitted and the handle is
    searched: holds a door handle (14 cm) whole when the first estimate is off by 5 cm."""
    handle_search_radius_m: float = 0.3
    """Radius around the first estimate in which handle geometry is searched (the front plane is
    fitted within ``search_radius_m``): holds a 30 cm drawer bar whole when the first estimate is
    off by 10 cm along it; a handle reaching out of it counts as long (``max_handle_length_m``)."""
    front_cell_m: float = 0.005
    """Cell size of the front-layer test (as seen from the hand), metres."""
    front_depth_m: float = 0.015
    """Points deeper than this behind the front-most point of their cell are hidden (the inner
    side of a door, drawer walls, bins) and take no part in the surface fit."""
    plane_tolerance_m: float = 0.005
    """RANSAC inlier distance of the front plane: a few mm of fused-mesh noise."""
    plane_hypotheses: int = 200
    """RANSAC hypotheses for the front plane."""
    front_min_width_m: float = 0.06
    """A layer of points parallel to the RANSAC plane and in front of it (up to
    ``handle_max_height_m``) is the part's front, rather than handle geometry, when it is this
    wide across (5-95 % range along its narrow in-plane direction; bars and lips are 1-3 cm)
    ..."""
    front_min_area_m2: float = 0.01
    """... and covers this area (cells of ``front_cell_m``; a 30 x 2 cm bar covers 0.006 m^2)."""
    max_handle_length_m: float = 0.35
    """A handle piece up to this long (along its principal direction) gives the contact at its
    centre: the first estimate's error runs mostly along the handle (2-4 cm on the synthetic
    bench), while its centre is where a hand or gripper holds it best. On a longer handle (an
    oven bar, a fridge's long bar), or one that reaches out of ``handle_search_radius_m``, the contact
    is the point of the handle's axis level with the hand's far end, where the hand was."""
    handle_min_height_m: float = 0.008
    """Points standing this far out of the front plane are handle geometry (bars stand 3 cm out,
    knobs 3 cm, recessed grips' lips 1-2 cm; 8 mm is above the fit noise)."""
    handle_max_height_m: float = 0.08
    """... and no farther (anything farther is not a handle)."""
    max_hand_distance_m: float = 0.12
    """A contact snapped to handle geometry farther than this from the hand's far end (the centroid
    of its points during the holds) is not where the hand was: the hand wraps the handle, its far
    end (the back of the hand) lies 3.4-8.4 cm from the right contact on the 32 bench parts whose
    contact is right; 22-23 cm on mw_drawer_00 and mw_window_00, where the front plane was the top
    of a bar seen from above and a wall behind it stood out of it. Such a hold is fitted as a bar
    (``bar_fit_radius_m``)."""
    max_front_hinge_cos: float = 0.5
    """... nor is one whose front plane's normal makes a cosine above this with a revolute part's
    hinge axis (a door's front contains its hinge): 0.00-0.02 on the 20 bench doors, 0.99 on
    mw_door_00 (the top of its bar, seen from above, taken for the front)."""
    bar_fit_radius_m: float = 0.06
    """Radius around the first estimate whose points give the held bar's axis (a circle fitted
    across their principal direction) when the front does not fit the hold: holds mw_door_00's
    bar (5 cm radius) across; 4 cm took its end cap for the axis (measured)."""
    handle_link_m: float = 0.012
    """Handle points closer than this are linked into one piece (2-3 surface spacings)."""
    min_handle_points: int = 5
    """Fewest handle points for the contact to be snapped to the handle."""
    handle_anisotropy: float = 2.0
    """The handle's principal direction gives the grasp x axis when its extent ratio (square root
    of the eigenvalue ratio) exceeds this; otherwise a fallback: the joint axis for revolute
    parts (bars on doors run along the hinge), the wider direction of the front for prismatic."""
    observe_frames: int = 8
    """Frames outside the holds whose depth adds to the part surface around the contact before the
    handle is searched: the hand hides the handle while it is held, so a part fused from the
    frames in which it moves often lacks it (a third of the points near the handle, measured)."""
    observe_window_s: float = 4.0
    """... chosen evenly among the frames within this time of a hold in which the part rests at
    its canonical state (the contact moved less than ``observe_still_m``; the handle is seen
    before the grasp) or has moved it at least ``observe_min_displacement_m`` (after the release).
    The points are kept where they lie, seen along the front's normal, inside the part surface's
    outline with holes up to ``observe_fill_m`` filled, which leaves out the static scene."""
    observe_min_views: int = 2
    """An observed voxel (``surface_spacing_m``) counts when this many of the frames saw it."""
    observe_still_m: float = 0.005
    """See ``observe_window_s``."""
    observe_min_displacement_m: float = 0.25
    """See ``observe_window_s``."""
    observe_fill_m: float = 0.12
    """See ``observe_window_s``: a hole the hand left in the fused part (its size, measured)."""
    footprint_cell_m: float = 0.01
    """Cell size of the part outline test, metres."""
    path_samples: int = 21
    """States sampled over the joint range for the contact path."""
    seed: int = 0
    """Seed of the surface sampling and the plane RANSAC (results are deterministic)."""

    def __post_init__(self) -> None:
        positive = (self.surface_spacing_m, self.distal_band_m, self.contact_distance_m, self.hold_radius_m,
                    self.search_radius_m, self.front_cell_m, self.plane_tolerance_m, self.handle_link_m,
                    self.max_hand_distance_m, self.bar_fit_radius_m)
        if min(positive) <= 0 or not 0.0 < self.distal_quantile <= 1.0 or self.hand_stride_px < 1:
            raise ValueError(f"AffordanceConfig needs positive lengths, 0 < distal_quantile <= 1 and hand_stride_px >= 1, got {self}")
        if not 0.0 < self.vote_top_fraction <= 1.0 or not 0.0 < self.region_fraction <= 1.0 or self.path_samples < 2:
            raise ValueError(f"AffordanceConfig needs fractions in (0, 1] and path_samples >= 2, got {self}")

    @property
    def handle_radius_m(self) -> float:
        """Radius around the first estimate that holds both the front fit and the handle search."""
        return max(self.search_radius_m, self.handle_search_radius_m)


__all__ = ["REFERENCE_WIDTH_PX", "AffordanceConfig", "PartSurface"]
