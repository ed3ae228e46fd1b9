"""Collision geometry of a twin: a mesh cut into convex pieces (CoACD, grid-cell hulls or one
hull), each thick enough for a simulator's contact solver. The only module that imports coacd."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
import trimesh
from scipy.spatial import ConvexHull

from funrec.errors import ExportError
from funrec.typed import FloatArray

T = TypeVar("T")

log = logging.getLogger(__name__)

DECOMPOSITION_METHODS = ("coacd", "grid", "hull")
"""How a mesh is cut into convex pieces: "coacd" (approximate convex decomposition, seconds per
object), "grid" (convex hull of the horizontal and of the other triangles in each cell of a regular grid;
fast and tight on room-scale scans that are open surfaces) or "hull" (one convex hull of the whole mesh)."""

COACD_MCTS_NODES = 10
"""CoACD tree-search children per node; the CoACD default (20) doubles the run time on two CPU
cores for no visible gain on TSDF meshes of furniture."""
COACD_MCTS_DEPTH = 2
"""CoACD tree-search depth (default 3); see COACD_MCTS_NODES."""
COACD_SAMPLE_RESOLUTION = 1000
"""CoACD surface samples for the concavity metric (default 2000); see COACD_MCTS_NODES."""
COACD_SEED = 0
"""Fixed CoACD seed, so an export is reproducible."""


@dataclass(frozen=True)
class CollisionConfig:
    """How the static scene and the parts are turned into convex collision pieces."""

    static_method: str = "grid"
    """Decomposition of the static mesh: "grid", "coacd" or "hull". "grid" takes about 3 s on a
    500k-triangle room; CoACD needs the mesh simplified first and still takes 10-30 s."""
    part_method: str = "coacd"
    """Decomposition of each part mesh: "coacd", "grid" or "hull"."""
    grid_cell_m: float = 0.25
    """Edge of a grid cell (m) for the "grid" method; a convex piece never spans more than about
    one cell, so a hull can fill at most a cell-sized wedge of a concave corner."""
    coacd_threshold: float = 0.05
    """CoACD concavity threshold (fraction of the mesh size); lower cuts finer and runs longer."""
    coacd_max_pieces: int = 16
    """Most convex pieces CoACD may return for one mesh."""
    coacd_mcts_iterations: int = 15
    """CoACD tree-search iterations (CoACD default 150). 25 instead of 50 cut
    the CPU time 0-37 % on five bench part meshes for at most 0.8 % more hull volume; 15 instead of 25 cut it
    20 % (77.6 -> 62.1 CPU-s) on the 13 part meshes of the plain family, the hulls' 95th-percentile distance
    from the mesh within -2.4 / +2.5 mm of 25's (6.7-35.0 mm) and their volume within -8 / +16 %; 10 cut it
    27 % for up to +4.4 mm (CPU measured on a shared machine: noisy by tens of percent per mesh)."""
    coacd_preprocess_resolution: int = 30
    """Voxels along the longest side when CoACD first makes an open scan manifold (CoACD default
    50); 30 halves the run time of a TSDF door and thickens it by a few millimetres more."""
    coacd_max_input_faces: int = 30_000
    """A mesh with more triangles is simplified by vertex clustering before CoACD, so a
    room-scale scan does not take minutes."""
    simplify_cell_m: float = 0.02
    """Smallest vertex-clustering cell (m) tried when simplifying; doubled until the mesh has at
    most coacd_max_input_faces triangles."""
    min_thickness_m: float = 0.01
    """Each piece is at least this thick (m) in every direction: a TSDF scan is an open surface
    whose hulls are flat, and a flat hull has no volume and gives unstable contacts."""

    def __post_init__(self) -> None:
        for name in ("static_method", "part_method"):
            if getattr(self, name) not in DECOMPOSITION_METHODS:
                raise ValueError(f"{name} must be one of {DECOMPOSITION_METHODS}, got {getattr(self, name)!r}")
        for name in ("grid_cell_m", "coacd_threshold", "simplify_cell_m", "min_thickness_m"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")


def decompose(mesh: trimesh.Trimesh, method: str, config: CollisionConfig, name: str) -> tuple[trimesh.Trimesh, ...]:
    """Cut a mesh into convex pieces.

    Args:
        mesh: triangle mesh in any frame (metres); need not be watertight.
        method: one of DECOMPOSITION_METHODS.
        config: decomposition settings.
        name: what the mesh is (e.g. "meshes/part_0.ply"), for error messages.

    Returns:
        Convex, watertight pieces in the frame of ``mesh``, each at least
        ``config.min_thickness_m`` thick.

    Raises:
        ExportError: the mesh has no triangle, or no piece could be made.
    """
    if len(mesh.faces) == 0:
        raise ExportError(f"{name}: mesh has no triangle to make collision geometry from")
    if method == "coacd":
        point_sets = _coacd_point_sets(mesh, config, name)
    elif method == "grid":
        point_sets = _grid_point_sets(mesh, config.grid_cell_m)
    elif method == "hull":
        point_sets = [np.asarray(mesh.vertices, dtype=np.float64)]
    else:
        raise ExportError(f"{name}: unknown decomposition method {method!r}, expected one of {DECOMPOSITION_METHODS}")
    pieces = tuple(
        piece for points in point_sets if (piece := convex_piece(points, config.min_thickness_m)) is not None
    )
    if not pieces:
        raise ExportError(f"{name}: {method} decomposition produced no convex piece")
    return pieces


def convex_piece(points: FloatArray, min_thickness_m: float) -> trimesh.Trimesh | None:
    """Convex hull of points, padded to a minimum thickness along its thin principal directions.

    Args:
        points: (N, 3) points, metres.
        min_thickness_m: smallest extent (m) of the hull along any principal direction.

    Returns:
        Watertight convex mesh, or None for an empty point set.
    """
    points = np.unique(np.asarray(points, dtype=np.float64), axis=0)
    if len(points) == 0:
        return None
    centre = points.mean(axis=0)
    # Principal directions of the point spread; a flat patch has one near-zero extent.
    _, directions = np.linalg.eigh((points - centre).T @ (points - centre))
    for direction in directions.T:
        extent = np.ptp((points - centre) @ direction)
        if extent < min_thickness_m:
            pad = 0.5 * (min_thickness_m - extent)
            points = np.concatenate([points - pad * direction, points + pad * direction])
    hull = _hull_mesh(points)
    return hull if hull.volume > 0.0 else None


def _hull_mesh(points: FloatArray) -> trimesh.Trimesh:
    """Convex hull of (N, 3) full-dimensional points as a watertight mesh with outward normals.

    scipy's Qhull directly, with trimesh's Qhull options: ``trimesh.convex.convex_hull`` runs
    the same Qhull and then repairs winding and normals face by face, which made it most of the
    static-scene export (a few hundred grid pieces).
    """
    hull = ConvexHull(points, qhull_options="QbB Pp Qt")
    faces = hull.simplices.astype(np.int64)
    corners = points[faces]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    inward = np.einsum("ij,ij->i", normals, hull.equations[:, :3]) < 0.0
    faces[inward] = faces[inward][:, ::-1]
    used, faces = np.unique(faces, return_inverse=True)
    return trimesh.Trimesh(points[used], faces.reshape(-1, 3), process=False)


def cluster_vertices(mesh: trimesh.Trimesh, cell_m: float) -> trimesh.Trimesh:
    """Simplify a mesh by merging the vertices in each grid cell (vertex clustering).

    Args:
        mesh: triangle mesh, metres.
        cell_m: cell edge (m); vertices in one cell become their mean.

    Returns:
        The simplified mesh with degenerate and repeated triangles removed.
    """
    keys = np.floor(np.asarray(mesh.vertices) / cell_m).astype(np.int64)
    _, cluster, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    cluster = cluster.ravel()
    vertices = np.zeros((len(counts), 3))
    np.add.at(vertices, cluster, mesh.vertices)
    vertices /= counts[:, None]
    faces = cluster[mesh.faces]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    _, first = np.unique(np.sort(faces, axis=1), axis=0, return_index=True)
    return trimesh.Trimesh(vertices, faces[np.sort(first)], process=True)


def _simplified(mesh: trimesh.Trimesh, config: CollisionConfig) -> trimesh.Trimesh:
    cell_m = config.simplify_cell_m
    while len(mesh.faces) > config.coacd_max_input_faces:
        simplified = cluster_vertices(mesh, cell_m)
        log.info(
            "simplified %d -> %d triangles (cell %.3f m) for CoACD", len(mesh.faces), len(simplified.faces), cell_m
        )
        if len(simplified.faces) <= config.coacd_max_input_faces:
            return simplified
        cell_m *= 2.0
    return mesh


def interruptible(function: Callable[..., T], *args: Any, **kwargs: Any) -> T:
    """``function(*args, **kwargs)`` in a worker thread, so that Ctrl-C acts within 0.1 s even while a long
    native call (coacd releases the GIL) runs; on an interrupt the worker is left to finish in the background
    (a daemon thread: it ends with the process)."""
    outcome: dict[str, Any] = {}

    def run() -> None:
        try:
            outcome["value"] = function(*args, **kwargs)
        except BaseException as exc:  # handed to the caller's thread
            outcome["error"] = exc

    worker = threading.Thread(target=run, name="funrec-native", daemon=True)
    worker.start()
    while worker.is_alive():
        worker.join(0.1)
    if "error" in outcome:
        raise outcome["error"]
    return outcome["value"]


def _coacd_point_sets(mesh: trimesh.Trimesh, config: CollisionConfig, name: str) -> list[FloatArray]:
    try:
        import coacd
    except ImportError:
        raise ExportError(
            f"{name}: the 'coacd' decomposition needs the coacd package (pip install coacd), "
            "or choose the 'grid' or 'hull' method"
        ) from None
    coacd.set_log_level("error")
    source = _simplified(mesh, config)
    pieces = interruptible(
        coacd.run_coacd,
        coacd.Mesh(np.asarray(source.vertices, dtype=np.float64), np.asarray(source.faces, dtype=np.int32)),
        threshold=config.coacd_threshold,
        max_convex_hull=config.coacd_max_pieces,
        mcts_nodes=COACD_MCTS_NODES,
        mcts_iterations=config.coacd_mcts_iterations,
        mcts_max_depth=COACD_MCTS_DEPTH,
        preprocess_resolution=config.coacd_preprocess_resolution,
        resolution=COACD_SAMPLE_RESOLUTION,
        seed=COACD_SEED,
    )
    return [np.asarray(vertices, dtype=np.float64) for vertices, _ in pieces]


def _orientation_bins(vertices: FloatArray, faces: FloatArray) -> FloatArray:
    """(F,) 1 for horizontal triangles (normal within 45 deg of z: floors, worktops), 0 for the others. The hull
    of one cell's floor and cabinet front together is a wedge standing out in front of the cabinet (up to a
    cell deep) where a robot's base and fingers must go; split so, each hull stays in its surface. (Binning
    vertical faces by facing as well, to split inner corners, tripled the pieces of a TSDF room: its
    triangle normals are noisy.)"""
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    normals = np.cross(b - a, c - a)
    return (np.abs(normals[:, 2]) >= np.sqrt(0.5) * np.linalg.norm(normals, axis=1)).astype(np.int64)


def _grid_point_sets(mesh: trimesh.Trimesh, cell_m: float) -> list[FloatArray]:
    """Vertices of the triangles whose centres fall in each occupied grid cell, horizontal and other
    triangles apart (``_orientation_bins``; the mesh is gravity-aligned, z up)."""
    faces = np.asarray(mesh.faces, dtype=np.int64)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    # Centres summed corner by corner: mesh.triangles_center would cache (F, 3, 3) corners on
    # the mesh (30 MB for a 400k-triangle room) for the rest of the export.
    centres = (vertices[faces[:, 0]] + vertices[faces[:, 1]] + vertices[faces[:, 2]]) / 3.0
    keys = np.column_stack([np.floor(centres / cell_m).astype(np.int64), _orientation_bins(vertices, faces)])
    keys -= keys.min(axis=0)
    # One integer per cell in lexicographic (x, y, z, bin) order: np.unique on it is several times
    # faster than np.unique(keys, axis=0), which sorts structured rows.
    _, cell = np.unique(np.ravel_multi_index(keys.T, tuple(keys.max(axis=0) + 1)), return_inverse=True)
    # Each (cell, vertex) pair once, sorted by cell then vertex: the vertices of every cell.
    pairs = np.unique(np.repeat(cell.ravel(), 3) * len(vertices) + faces.ravel())
    pair_cell, pair_vertex = np.divmod(pairs, len(vertices))
    splits = np.flatnonzero(np.diff(pair_cell)) + 1
    return [vertices[group] for group in np.split(pair_vertex, splits)]


__all__ = ["DECOMPOSITION_METHODS", "CollisionConfig", "cluster_vertices", "convex_piece", "decompose"]
