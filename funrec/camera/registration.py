"""Pairwise registration of fragment submaps: coarse-to-fine coloured ICP from the trajectory's guess
(FPFH + RANSAC only when that fails), scored over correspondences in both directions and gated on
residual, overlap, geometric constraint, bounded correction and forward/reverse agreement.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import open3d as o3d

from funrec.camera.submaps import Submap
from funrec.geometry.transforms import pose_difference
from funrec.typed import FloatArray

logger = logging.getLogger(__name__)

_registration = o3d.pipelines.registration


@dataclass(frozen=True)
class RegistrationConfig:
    """Settings of :func:`register_submaps`."""

    coarse_icp_distances_m: tuple[float, ...] = (0.10, 0.05)
    """Correspondence distances of the coloured ICP rounds on the coarse clouds, metres: the
    first must exceed the drift to be corrected."""
    coarse_icp_iterations: int = 15
    """Iteration cap of each coarse round (they converge in 5-15 on the bench)."""
    fine_distance_voxels: float = 1.0
    """Correspondence distance of the single fine coloured-ICP round on the full clouds, and the
    distance at which fitness, RMSE and information are measured, in voxels of the coarser of
    the two submaps (2 cm at the default voxel)."""
    fine_icp_iterations: int = 10
    """Iteration cap of the fine round."""
    max_rmse_voxels: float = 0.3
    """An edge is accepted only when its point-to-plane RMSE at the fine distance is below this
    many voxels of the coarser submap (6 mm at 2 cm). Correctly aligned submaps of the bench
    scenes give 3.5-6 mm at 2 cm (a uniform spread within a 1 cm band alone would give ~5.8 mm),
    and 6-12 mm for submaps capped to ~5 cm voxels (centroids of larger voxels leave curved and
    far surfaces); both measured."""
    min_fitness: float = 0.25
    """... and when at least this fraction of one submap's points has a neighbour in the other
    within the fine distance (partial overlap of two views of a room is typically 0.3-0.9)."""
    min_constraint: float = 0.0
    """... and when the matched surfaces pin every translation by geometry alone: the smallest
    eigenvalue of the mean n n^T over the matched normals (1/3 for normals spread evenly over
    all directions, 0 when they are all perpendicular to one direction, along which a slide
    leaves the residual unchanged). Off by default: bench kitchens seen from the front measure
    0.002-0.007, and colour still pinned their slides (correct 10 cm / 5 deg corrections at
    0.002), so geometric degeneracy alone does not predict failure; the value is reported."""
    max_correction_m: float = 0.30
    """... and when it moves the submaps by at most this much relative to the trajectory,
    metres: tracking drift is centimetres, a larger jump means a wrong (symmetric) solution."""
    max_correction_rad: float = math.radians(20.0)
    """... and turns them by at most this much relative to the trajectory, radians."""
    min_correction_m: float = 0.01
    """An accepted registration that moves the submaps by less than this relative to the
    trajectory (and turns them by less than ``min_correction_rad``) is not used: it agrees with
    the trajectory within registration noise (measured 1-5 mm from perfect poses), and adding
    it would only add that noise (measured: ATE 2.6 -> 4.4 mm on a well-tracked sequence).
    The same band bounds the disagreement of the forward and reverse registrations."""
    min_correction_rad: float = math.radians(1.0)
    """... radians."""
    prior_fitness_margin: float = 0.05
    """A registration that moves the submaps beyond that band is still not used when the
    trajectory's own relative pose passes the RMSE gate and its fitness is within this margin of
    the registration's: the data do not prefer the registration, which then slid along a weakly
    constrained direction rather than found drift."""
    check_reverse: bool = True
    """Re-run the fine round from the target to the source before using a registration, and
    reject it when the two disagree by more than ``min_correction_m`` / ``min_correction_rad``
    (a slide on partial overlap depends on which cloud is matched against which)."""
    ransac_distance_m: float = 0.075
    """Inlier distance of the FPFH RANSAC on the coarse clouds, metres: 1.5 coarse voxels
    (Open3D's global-registration ratio). RANSAC runs only when ICP from the trajectory fails
    the gate."""
    ransac_iterations: int = 100000
    """RANSAC iteration cap; it stops earlier once 99.9 % confidence is reached."""
    feature_radius_m: float = 0.25
    """FPFH neighbourhood radius on the coarse clouds, metres (5 coarse voxels, Open3D's ratio)."""
    prefer_trajectory: float = 0.05
    """Fitness bonus of the ICP result started from the trajectory over the one started from
    FPFH: repeated cabinet fronts give FPFH solutions shifted by one cabinet with a slightly
    higher fitness (measured +0.04 at a 45 cm shift)."""


@dataclass(frozen=True)
class AlignmentEdge:
    """One pairwise registration between fragment submaps."""

    source: int
    """Source fragment index (the lower one)."""
    target: int
    """Target fragment index."""
    fitness: float
    """Fraction of one submap's points with a neighbour in the other within the fine distance
    (the larger of the two directions)."""
    inlier_rmse_m: float
    """Point-to-plane RMSE of those neighbours, metres."""
    accepted: bool
    """Passed the gate (RMSE, fitness, constraint, bounded correction, reverse agreement)."""
    used: bool
    """Constrained the pose graph and survived its pruning: accepted, and it disagreed with the
    trajectory by more than ``min_correction_m`` / ``min_correction_rad``."""
    reason: str
    """Why it was rejected or not used ("" when used)."""
    correction_m: float
    """How far the registration moves the source relative to the trajectory's guess, metres."""
    correction_rad: float
    """... and how far it turns it, radians."""
    T_target_source: FloatArray
    """(4, 4) registered transform from the source fragment frame to the target fragment frame."""
    start: str
    """Which initial guess ICP converged from: "trajectory" or "fpfh"."""
    constraint: float = 0.0
    """Smallest eigenvalue of the mean n n^T of the matched normals (see ``min_constraint``)."""


@dataclass(frozen=True)
class _Score:
    fitness: float
    rmse_m: float
    constraint: float


def match_distance(source: Submap, target: Submap, config: RegistrationConfig) -> float:
    """Fine correspondence distance of a pair, metres: ``fine_distance_voxels`` of the coarser voxel."""
    return config.fine_distance_voxels * max(source.voxel_m, target.voxel_m)


def fpfh_features(submap: Submap, config: RegistrationConfig) -> o3d.pipelines.registration.Feature:
    """(33, N_coarse) FPFH descriptors of the submap's coarse points (Open3D)."""
    return _registration.compute_fpfh_feature(
        submap.coarse, o3d.geometry.KDTreeSearchParamHybrid(radius=config.feature_radius_m, max_nn=100))


def _colour_icp(source: o3d.geometry.PointCloud, target: o3d.geometry.PointCloud, distance_m: float,
                T_init: FloatArray, iterations: int, robust: bool = False) -> FloatArray | None:
    """One coloured-ICP run (Open3D), with a Tukey kernel of half the correspondence distance when
    ``robust``; None when it finds no correspondences or diverges."""
    estimation = _registration.TransformationEstimationForColoredICP(
        0.968, _registration.TukeyLoss(k=distance_m / 2)) if robust else _registration.TransformationEstimationForColoredICP()
    try:
        result = _registration.registration_colored_icp(
            source, target, distance_m, T_init, estimation,
            _registration.ICPConvergenceCriteria(relative_fitness=1e-6, relative_rmse=1e-6, max_iteration=iterations),
        )
    except RuntimeError as exc:
        if "No correspondences" not in str(exc):
            raise
        return None
    # fitness 0: diverged (measured on noise-free ray-cast planes: one step flew off by 10^7 m,
    # a near-singular colour system).
    return np.asarray(result.transformation) if result.fitness > 0.0 else None


def _icp(source: Submap, target: Submap, T_init: FloatArray, config: RegistrationConfig) -> FloatArray | None:
    """T_target_source from ``T_init`` by coarse-to-fine coloured ICP: rounds on the coarse clouds
    at ``coarse_icp_distances_m``, then one on the full clouds at the fine distance. None when the
    clouds do not meet in the first round; a later round that fails keeps the last result.

    The coarse rounds use a Tukey kernel (Open3D's 0.968 geometric weight otherwise): without it,
    far correspondences of partial overlap dragged the coarse rounds 17-37 cm along rows of
    cabinets from a 10 cm / 5 deg error on 4 of 40 bench pairs; with it on 2, which the gate
    rejects (measured, /tmp/helper-G2/variants.py).

    Colour pins the slide along walls and rows of cabinet fronts that geometry leaves free
    (measured on perfectly posed bench submaps: point-to-plane ICP slid 4-57 cm, coloured ICP
    1-5 mm)."""
    rounds = [(source.coarse, target.coarse, d, config.coarse_icp_iterations, True) for d in config.coarse_icp_distances_m]
    rounds.append((source.cloud, target.cloud, match_distance(source, target, config), config.fine_icp_iterations, False))
    T = np.asarray(T_init)
    for k, (source_cloud, target_cloud, distance, iterations, robust) in enumerate(rounds):
        T_next = _colour_icp(source_cloud, target_cloud, distance, T, iterations, robust)
        if T_next is None:
            return None if k == 0 else T
        T = T_next
    return T


def _score(source: Submap, target: Submap, T_target_source: FloatArray, distance_m: float) -> _Score:
    """Fitness, point-to-plane RMSE and constraint of an alignment over the nearest neighbours
    within ``distance_m`` in both directions. Fitness is the larger overlap fraction, so that a
    small submap inside a large one scores its own overlap. Point-to-plane, because the
    point-to-point RMSE Open3D reports is dominated by the voxel spacing (measured ~7 mm at a
    2 cm voxel on perfectly posed submaps), not by the misalignment."""
    fitness, residuals, normals = 0.0, [], []
    T_source_target = np.linalg.inv(T_target_source)
    for a, b, T_b_a in ((source, target, T_target_source), (target, source, T_source_target)):
        if len(a.points) == 0 or len(b.points) == 0:
            continue
        p_b = a.points @ T_b_a[:3, :3].T + T_b_a[:3, 3]
        distance, index = b.tree.query(p_b, distance_upper_bound=distance_m)
        matched = np.isfinite(distance)
        fitness = max(fitness, float(np.mean(matched)))
        n_b = b.normals[index[matched]]
        residuals.append(np.sum((p_b[matched] - b.points[index[matched]]) * n_b, axis=1))
        # normals in the target frame, so that both directions share one constraint matrix
        normals.append(n_b if b is target else n_b @ T_target_source[:3, :3].T)
    r, n = np.concatenate(residuals or [np.zeros(0)]), np.concatenate(normals or [np.zeros((0, 3))])
    if len(r) == 0:
        return _Score(fitness, math.inf, 0.0)
    return _Score(fitness, float(np.sqrt(np.mean(r**2))), float(np.linalg.eigvalsh(n.T @ n / len(n))[0]))


def _global_guess(source: Submap, target: Submap, features: Callable[[Submap], object],
                  config: RegistrationConfig) -> FloatArray:
    """T_target_source from FPFH matches and RANSAC (Open3D)."""
    result = _registration.registration_ransac_based_on_feature_matching(
        source.coarse, target.coarse, features(source), features(target), True, config.ransac_distance_m,
        _registration.TransformationEstimationPointToPoint(False), 3,
        [_registration.CorrespondenceCheckerBasedOnEdgeLength(0.9),
         _registration.CorrespondenceCheckerBasedOnDistance(config.ransac_distance_m)],
        _registration.RANSACConvergenceCriteria(config.ransac_iterations, 0.999),
    )
    return np.asarray(result.transformation)


def _close(T_a: FloatArray, T_b: FloatArray, config: RegistrationConfig) -> bool:
    """Whether two transforms differ by at most ``min_correction_m`` and ``min_correction_rad``."""
    moved_m, turned_rad = pose_difference(T_a, T_b)
    return moved_m <= config.min_correction_m and turned_rad <= config.min_correction_rad


def _fits(score: _Score, voxel_m: float, config: RegistrationConfig) -> list[str]:
    """Why an alignment's fit is rejected (empty: it fits); ``voxel_m`` of the coarser submap."""
    reasons = []
    if score.fitness < config.min_fitness:
        reasons.append(f"fitness {score.fitness:.2f} < {config.min_fitness}")
    if not score.rmse_m <= config.max_rmse_voxels * voxel_m:
        reasons.append(f"RMSE {score.rmse_m * 1000:.1f} mm > {config.max_rmse_voxels * voxel_m * 1000:.1f} mm")
    if score.constraint < config.min_constraint:
        reasons.append(f"surfaces leave a slide free (constraint {score.constraint:.3f} < {config.min_constraint})")
    return reasons


def _candidate(source: Submap, target: Submap, T: FloatArray, T_prior: FloatArray, start: str, indices: tuple[int, int],
               config: RegistrationConfig) -> AlignmentEdge:
    score = _score(source, target, T, match_distance(source, target, config))
    moved_m, turned_rad = pose_difference(T_prior, T)
    reasons = _fits(score, max(source.voxel_m, target.voxel_m), config)
    if moved_m > config.max_correction_m or turned_rad > config.max_correction_rad:
        reasons.append(f"moves {moved_m * 100:.0f} cm / {math.degrees(turned_rad):.0f} deg from the trajectory")
    logger.debug("%d->%d from %s: fitness %.3f RMSE %.1f mm constraint %.3f, moved %.1f cm %.2f deg %s", *indices, start,
                 score.fitness, score.rmse_m * 1000, score.constraint, 100 * moved_m, math.degrees(turned_rad), reasons)
    return AlignmentEdge(*indices, score.fitness, score.rmse_m, not reasons, False, "; ".join(reasons), moved_m,
                         turned_rad, T, start, score.constraint)


def register_submaps(source: Submap, target: Submap, T_prior: FloatArray, indices: tuple[int, int],
                     config: RegistrationConfig,
                     features: Callable[[Submap], object] | None = None) -> tuple[AlignmentEdge, FloatArray | None]:
    """Register two submaps: ICP from the trajectory's guess ``T_prior`` (4, 4) = T_target_source;
    only when that fails the gate, also from FPFH + RANSAC, keeping the better that passes
    (the trajectory's start is preferred by ``prefer_trajectory``).

    Args:
        source, target: the submaps.
        T_prior: (4, 4) the trajectory's T_target_source.
        indices: (source, target) fragment indices, for the report.
        config: settings.
        features: ``features(submap)`` -> its FPFH features, so a caller can compute each
            submap's once; :func:`fpfh_features` by default.

    Returns:
        The edge and, when it is to be used, its 6x6 information matrix (Open3D's, at the fine
        distance).
    """
    features = features or (lambda submap: fpfh_features(submap, config))
    candidates = []
    T = _icp(source, target, T_prior, config)
    if T is not None:
        candidates.append(_candidate(source, target, T, T_prior, "trajectory", indices, config))
    if not (candidates and candidates[0].accepted):
        T = _icp(source, target, _global_guess(source, target, features, config), config)
        if T is not None and not (candidates and _close(T, candidates[0].T_target_source, config)):
            candidates.append(_candidate(source, target, T, T_prior, "fpfh", indices, config))
    if not candidates:
        return AlignmentEdge(*indices, 0.0, math.inf, False, False, "no overlap from any start", 0.0, 0.0, T_prior,
                             "trajectory"), None
    edge = max(candidates, key=lambda e: (e.accepted, e.fitness + (config.prefer_trajectory if e.start == "trajectory"
                                                                    else 0.0), -e.inlier_rmse_m))
    if not edge.accepted:
        return edge, None
    rejection = _trust(source, target, edge.T_target_source, T_prior, edge.fitness, config)
    if rejection is not None:
        return replace(edge, accepted=edge.accepted and not rejection[0], reason=rejection[1]), None
    return replace(edge, used=True), np.asarray(_registration.get_information_matrix_from_point_clouds(
        source.cloud, target.cloud, match_distance(source, target, config), edge.T_target_source))


def _trust(source: Submap, target: Submap, T_target_source: FloatArray, T_prior: FloatArray, fitness: float,
           config: RegistrationConfig) -> tuple[bool, str] | None:
    """Why an accepted registration is not to be used, as (rejected, reason); None to use it.

    Not used when it agrees with the trajectory within the noise band, or when the trajectory's
    own pose fits as well; rejected when the reverse registration (target to source, from the
    inverse) lands elsewhere."""
    if _close(T_target_source, T_prior, config):
        return False, "agrees with the trajectory"
    distance_m = match_distance(source, target, config)
    prior = _score(source, target, T_prior, distance_m)
    if not _fits(prior, max(source.voxel_m, target.voxel_m), config) and prior.fitness >= fitness - config.prior_fitness_margin:
        return False, f"the trajectory fits as well (fitness {prior.fitness:.2f}, RMSE {prior.rmse_m * 1000:.1f} mm)"
    if config.check_reverse:
        T_source_target = _colour_icp(target.cloud, source.cloud, distance_m, np.linalg.inv(T_target_source),
                                      config.fine_icp_iterations)
        if T_source_target is None:
            return True, "reverse registration found no correspondences"
        if not _close(np.linalg.inv(T_source_target), T_target_source, config):
            moved_m, turned_rad = pose_difference(np.linalg.inv(T_source_target), T_target_source)
            return True, f"reverse registration disagrees by {moved_m * 100:.1f} cm / {math.degrees(turned_rad):.1f} deg"
    return None

__all__ = ["AlignmentEdge", "RegistrationConfig", "fpfh_features", "match_distance", "register_submaps"]
