"""Gravity alignment: the twin's world frame with z up, from the floor plane of the static scene
(or, without a visible floor, from a worktop or the ceiling, else from the head-mounted camera's roll-free
x axes)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from funrec.geometry.transforms import make_transform
from funrec.typed import FloatArray

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GravityConfig:
    """Settings of :func:`estimate_gravity`."""

    voxel_m: float = 0.03
    """Static points are thinned to one per voxel of this edge before plane fitting, metres:
    a room-scale mesh has ~10^6 vertices and the floor is metres wide."""
    plane_distance_m: float = 0.02
    """RANSAC inlier distance to a plane, metres: about 3 sigma of Kinect-like depth noise at
    2 m after TSDF averaging, thin enough to separate a floor from a 2 cm skirting board."""
    max_floor_tilt_deg: float = 60.0
    """A plane may be the floor when its normal is within this angle of the camera prior's up.
    The prior is good to a few degrees when the person turns (the x axes then span the horizontal
    plane), but when they face one way it is the mean -y axis, pitched by how far down they look:
    measured 38-46 deg on bench kitchens, so the floor test below leans on camera height too."""
    camera_height_m: tuple[float, float] = (1.0, 2.4)
    """The floor lies this far below the median camera centre, metres: a head-mounted or hand-held
    camera of a standing or briefly crouching person (median heights 1.24-1.70 m on the bench). It
    separates the floor from a counter top (0.3-0.8 m below the head on the bench; with 0.6 here a
    0.9 m counter was taken for the floor) and from walls, which the camera is not 'above'."""
    worktop_height_m: float = 0.90
    """Without a visible floor, a large horizontal plane 0.3 m to ``camera_height_m[0]`` below the cameras is
    taken for a kitchen worktop at this height above the floor, metres (EN 1116 and US cabinets: 0.85-0.95 m);
    the floor is put that far below it, with a warning."""
    assumed_camera_height_m: float = 1.55
    """Without a visible floor or worktop, the floor is put this far below camera 0 (a standing adult's eye
    height), metres, with a warning: the robot stands on it, so the camera's own height (0) would float it."""
    max_ceiling_tilt_deg: float = 30.0
    """Without a floor or worktop, a large plane above the cameras whose normal is within this angle of the
    camera prior's up is taken for the ceiling and gives up. Tighter than ``max_floor_tilt_deg``: a ceiling
    has no height test to tell it from a wall, and a person looking down at an angle tilts the prior towards
    the wall in front (whose normal, flipped to the prior's side, would put the cameras 'below' it)."""
    min_plane_fraction: float = 0.04
    """A horizontal plane needs at least this fraction of the thinned points to count."""
    max_planes: int = 6
    """Planes peeled off by successive RANSAC runs in search of the floor."""
    refine_distance_m: float = 0.01
    """Each plane is fitted again, by RANSAC among its own inliers at this inlier distance, metres: at
    ``plane_distance_m`` a floor's inliers can take in a second level a few centimetres up (a plinth, a
    bottom panel), and the least-squares plane through both tilts (2.7 degrees and the floor 4 cm off under
    camera 0 on a twin of plain_rev_fridge_00, with a level 4.7 cm up); at 1 cm, a static voxel (fused floors
    lie within 5 mm of their plane: the fridge twin's, measured in the true scene), the larger level alone remains."""
    ransac_iterations: int = 400
    """RANSAC iterations per plane."""
    seed: int = 0
    """Seed of the RANSAC sampling (reproducible output)."""


@dataclass(frozen=True)
class GravityAlignment:
    """A gravity-aligned frame ("aligned") for a reconstruction made in the pipeline's world."""

    T_aligned_world: FloatArray
    """(4, 4) maps pipeline-world coordinates to the aligned frame: z up, x along camera 0's
    horizontal x axis, origin on the floor below camera 0 (``assumed_camera_height_m`` below it
    without a floor)."""
    source: str
    """"floor_plane" when a floor was found, "worktop_plane" when only a worktop was (the floor is put
    ``worktop_height_m`` below it), "ceiling_plane" when only a ceiling was (up from it, the floor put
    ``assumed_camera_height_m`` below camera 0), else "camera_axes" (up from the cameras, the floor as for
    the ceiling)."""
    floor_inliers: int
    """Thinned static points on the plane that gave up (floor, worktop or ceiling; 0 from the cameras)."""
    floor: str = "seen"
    """How the floor's height was found, in words: "seen", or what it was assumed from (written to the twin's
    gravity.json, so that a robot planned in it knows what it stands on)."""


WORKTOP_BELOW_CAMERA_M = 0.3
"""A worktop lies at least this far below the median camera centre, metres."""


def _camera_up_prior(T_world_camera: FloatArray) -> FloatArray:
    """Up from the cameras: orthogonal to their x axes (a head-mounted camera barely rolls),
    on the side of their -y axes (OpenCV y points down)."""
    x_axes = T_world_camera[:, :3, 0]
    minus_y = -T_world_camera[:, :3, 1].mean(axis=0)
    scatter = x_axes.T @ x_axes
    eigenvalues, eigenvectors = np.linalg.eigh(scatter)
    up = eigenvectors[:, 0]
    # With little yaw variation the x axes span one direction only and the smallest
    # eigenvector is ambiguous in the plane of up and forward: fall back to the -y mean.
    if eigenvalues[1] < 0.05 * eigenvalues[2]:
        up = minus_y - x_axes.mean(axis=0) * (x_axes.mean(axis=0) @ minus_y)
    up = up / np.linalg.norm(up)
    return up if up @ minus_y >= 0 else -up


def _floor_plane(points_world: FloatArray, up_prior: FloatArray, config: GravityConfig,
                 p_world_camera: FloatArray | None = None) -> tuple[tuple[FloatArray, float, int] | None, ...]:
    """The lowest large plane roughly facing up with the cameras at head height above it, the lowest one at
    worktop height below them, and the largest one above them (a ceiling): each (unit normal pointing up,
    offset d with n.p + d = 0, inliers) or None."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_world))
    cloud = cloud.voxel_down_sample(config.voxel_m)
    total = len(cloud.points)
    if total < 100:
        return None, None, None
    o3d.utility.random.seed(config.seed)
    cos_tilt = np.cos(np.radians(config.max_floor_tilt_deg))
    cos_ceiling_tilt = np.cos(np.radians(config.max_ceiling_tilt_deg))
    best: tuple[FloatArray, float, int] | None = None
    worktop: tuple[FloatArray, float, int] | None = None
    ceiling: tuple[FloatArray, float, int] | None = None
    for _ in range(config.max_planes):
        if len(cloud.points) < 3 * int(config.min_plane_fraction * total) or len(cloud.points) < 50:
            break
        plane, inliers = cloud.segment_plane(config.plane_distance_m, 3, config.ransac_iterations)
        if len(inliers) >= 3:
            plane, _ = cloud.select_by_index(inliers).segment_plane(config.refine_distance_m, 3, config.ransac_iterations)
        normal, d = np.asarray(plane[:3], dtype=np.float64), float(plane[3])
        scale = np.linalg.norm(normal)
        normal, d = normal / scale, d / scale
        if normal @ up_prior < 0:
            normal, d = -normal, -d
        height = None if p_world_camera is None else float(np.median(p_world_camera @ normal + d))
        at_head_height = height is None or config.camera_height_m[0] <= height <= config.camera_height_m[1]
        large = normal @ up_prior >= cos_tilt and len(inliers) >= config.min_plane_fraction * total
        # Height of the plane along up is -d; the floor is the lowest horizontal plane.
        if large and at_head_height and (best is None or -d < -best[1]):
            best = (normal, d, len(inliers))
        at_worktop_height = height is not None and WORKTOP_BELOW_CAMERA_M <= height < config.camera_height_m[0]
        if large and at_worktop_height and (worktop is None or -d < -worktop[1]):
            worktop = (normal, d, len(inliers))
        above = height is not None and height <= -WORKTOP_BELOW_CAMERA_M
        if large and above and normal @ up_prior >= cos_ceiling_tilt and (ceiling is None or len(inliers) > ceiling[2]):
            ceiling = (normal, d, len(inliers))
        cloud = cloud.select_by_index(inliers, invert=True)
    return best, worktop, ceiling


def estimate_gravity(
    points_world: npt.ArrayLike,
    T_world_camera: npt.ArrayLike,
    config: GravityConfig = GravityConfig(),  # noqa: B008 (frozen, immutable default)
) -> GravityAlignment:
    """Find the gravity-aligned frame of a reconstruction.

    Args:
        points_world: (N, 3) static scene points (e.g. static mesh vertices), pipeline world.
        T_world_camera: (F, 4, 4) camera-to-world poses, pipeline world.
        config: settings.

    Returns:
        The alignment; apply ``T_aligned_world`` to every pose, point, axis and pivot.
    """
    points_world = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    T_world_camera = np.asarray(T_world_camera, dtype=np.float64)
    up = _camera_up_prior(T_world_camera)
    finite = points_world[np.isfinite(points_world).all(axis=1)]
    floor, worktop, ceiling = _floor_plane(finite, up, config, T_world_camera[:, :3, 3]) if len(points_world) else (None,) * 3
    p_camera0 = T_world_camera[0, :3, 3]
    eye_height = f"not seen: assumed {config.assumed_camera_height_m:.2f} m below camera 0 (a standing adult's eye height)"
    if floor is not None:
        up, d, inliers = floor
        origin = p_camera0 - up * (up @ p_camera0 + d)
        source, floor_note = "floor_plane", "seen"
    elif worktop is not None:
        up, d, inliers = worktop
        origin = p_camera0 - up * (up @ p_camera0 + d + config.worktop_height_m)
        source, floor_note = "worktop_plane", f"not seen: assumed {config.worktop_height_m:.2f} m below a worktop-high plane"
        log.warning("no floor plane found: the floor is assumed %.2f m below the worktop-high plane seen "
                    "(a robot planned in this twin stands on that guess)", config.worktop_height_m)
    elif ceiling is not None:
        # A level ceiling gives up as well as a floor does (on the 4988aea and 7120ead twins of
        # geo_island_rev_wall_00, filmed under wall cabinets with neither floor nor worktop in view, the camera
        # axes tilted it 9.4 degrees); the ceiling's height above the floor varies too much (2.4-3 m) to give
        # the floor's.
        up, _, inliers = ceiling
        origin, source, floor_note = p_camera0 - config.assumed_camera_height_m * up, "ceiling_plane", eye_height
        log.warning("no floor plane found: gravity from the ceiling, and the floor assumed %.2f m below camera 0 "
                    "(a robot planned in this twin stands on that guess)", config.assumed_camera_height_m)
    else:
        origin, inliers, source = p_camera0 - config.assumed_camera_height_m * up, 0, "camera_axes"
        floor_note = eye_height
        log.warning("no floor plane found: gravity from the camera axes, and the floor assumed %.2f m below "
                    "camera 0 (a robot planned in this twin stands on that guess)", config.assumed_camera_height_m)
    x_axis = T_world_camera[0, :3, 0] - up * (up @ T_world_camera[0, :3, 0])
    if np.linalg.norm(x_axis) < 1e-6:  # camera 0 looks straight down its own x axis: pick any
        x_axis = np.cross(up, [0.0, 1.0, 0.0]) if abs(up[1]) < 0.9 else np.cross(up, [1.0, 0.0, 0.0])
    x_axis = x_axis / np.linalg.norm(x_axis)
    R_aligned_world = np.stack([x_axis, np.cross(up, x_axis), up])
    return GravityAlignment(make_transform(R_aligned_world, -R_aligned_world @ origin), source, inliers, floor_note)


__all__ = ["GravityAlignment", "GravityConfig", "estimate_gravity"]
