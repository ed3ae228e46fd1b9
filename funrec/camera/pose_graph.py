"""Pose-graph optimisation over rigid nodes (Open3D's Levenberg-Marquardt with line-process
pruning of uncertain edges), shared by camera tracking (keyframes) and global alignment (fragment
submaps). The one module that wraps ``open3d.pipelines.registration.global_optimization``."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from funrec.typed import FloatArray

PoseGraphEdge = tuple[int, int, FloatArray, FloatArray, bool]
"""(s, t, T_t_s (4, 4), information (6, 6), uncertain): a relative pose measurement from node s
to node t; uncertain edges (loop closures) may be pruned by the optimiser."""


def optimise_pose_graph(
    T_world_node: Sequence[FloatArray] | FloatArray,
    edges: Sequence[PoseGraphEdge],
    max_correspondence_distance_m: float,
    edge_prune_threshold: float = 0.25,
) -> tuple[FloatArray, set[tuple[int, int]]]:
    """Optimise node poses ``T_world_node`` (N, 4, 4) given relative-pose edges; node 0 is fixed.

    Returns the optimised (N, 4, 4) poses and the (s, t) of the uncertain edges that survived
    pruning. ``max_correspondence_distance_m`` sets Open3D's line-process scale (metres) and
    ``edge_prune_threshold`` the line-process weight below which an uncertain edge is dropped.
    """
    import open3d as o3d  # imported here: Open3D costs ~1 s to import and tracking may not need it

    registration = o3d.pipelines.registration
    graph = registration.PoseGraph()
    for T in np.asarray(T_world_node, dtype=float):
        graph.nodes.append(registration.PoseGraphNode(T))
    for s, t, T_t_s, information, uncertain in edges:
        graph.edges.append(registration.PoseGraphEdge(s, t, T_t_s, information, uncertain=uncertain))
    option = registration.GlobalOptimizationOption(
        max_correspondence_distance=max_correspondence_distance_m,
        edge_prune_threshold=edge_prune_threshold,
        reference_node=0,
    )
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        registration.global_optimization(
            graph, registration.GlobalOptimizationLevenbergMarquardt(),
            registration.GlobalOptimizationConvergenceCriteria(), option,
        )
    kept = {(e.source_node_id, e.target_node_id) for e in graph.edges if e.uncertain}
    return np.array([np.asarray(n.pose) for n in graph.nodes]), kept
