"""A cabinet twin built from exact boxes (a left-hinged door on top, a drawer below, placed far from
the origin and tilted), and what any simulator export of it must reproduce: part link poses that
agree with articulation.json.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from funrec.export.collision import CollisionConfig
from funrec.export.simulation import ExportConfig, SimulationExports, export_simulation
from funrec.formats.twin import ArticulatedPart, TwinArticulation, make_part, write_articulation
from funrec.geometry.joints import joint_transform
from funrec.geometry.transforms import make_transform, transform_points

POSITION_ATOL_M = 1e-3
"""Required agreement of simulator part poses with articulation.json (1 mm)."""
ANGLE_ATOL_RAD = np.radians(0.1)
"""Required agreement of simulator part orientations (0.1 degree)."""
DOOR_SIZE_M = (0.58, 0.02, 0.38)
"""Door panel (width, thickness, height) in the cabinet frame."""
T_WORLD_CABINET = make_transform(Rotation.from_rotvec([0.3, -0.5, 0.9]).as_matrix(), [2.5, -1.7, 0.8])
"""Where the cabinet stands: a tilted, far-away placement, so no joint axis is axis-aligned and
the door's pivot is metres from the origin."""
FAST_EXPORT = ExportConfig(collision=CollisionConfig(part_method="hull", static_method="grid"))
"""Export settings for tests: one hull per part keeps CoACD (seconds per mesh) out of the fast run."""


def box(size: tuple[float, float, float], centre: tuple[float, float, float]) -> trimesh.Trimesh:
    """An axis-aligned box mesh of extents ``size`` centred at ``centre``."""
    return trimesh.creation.box(extents=size, transform=make_transform(np.eye(3), centre))


def write_cabinet_twin(twin_dir: Path, with_parts: bool = True) -> TwinArticulation:
    """A cabinet (0.6 x 0.4 x 0.8 m, front facing -y of the cabinet frame) with a left-hinged
    door on top and a drawer below, placed by T_WORLD_CABINET; writes articulation.json and
    world-frame meshes as FORMATS.md section 2 says."""
    carcass = trimesh.util.concatenate(
        [
            box((0.6, 0.02, 0.8), (0.0, 0.19, 0.4)),  # back
            box((0.02, 0.4, 0.8), (-0.29, 0.0, 0.4)),  # left
            box((0.02, 0.4, 0.8), (0.29, 0.0, 0.4)),  # right
            box((0.6, 0.4, 0.02), (0.0, 0.0, 0.01)),  # bottom
            box((0.6, 0.4, 0.02), (0.0, 0.0, 0.4)),  # shelf
            box((0.6, 0.4, 0.02), (0.0, 0.0, 0.79)),  # top
        ]
    )
    door = box(DOOR_SIZE_M, (0.0, -0.21, 0.6))
    drawer = trimesh.util.concatenate(
        [
            box((0.56, 0.02, 0.35), (0.0, -0.21, 0.2)),  # front
            box((0.54, 0.36, 0.01), (0.0, -0.02, 0.05)),  # floor
            box((0.01, 0.36, 0.2), (-0.265, -0.02, 0.14)),
            box((0.01, 0.36, 0.2), (0.265, -0.02, 0.14)),
            box((0.54, 0.01, 0.2), (0.0, 0.155, 0.14)),
        ]
    )
    (twin_dir / "meshes").mkdir(parents=True, exist_ok=True)
    for name, mesh in (("static", carcass), ("part_0", door), ("part_1", drawer)):
        mesh.apply_transform(T_WORLD_CABINET)
        mesh.export(twin_dir / "meshes" / f"{name}.ply")
    R_world_cabinet = T_WORLD_CABINET[:3, :3]
    hinge_cabinet = np.array([-0.29, -0.22, 0.6])
    parts = (
        make_part(
            "part_0",
            "revolute",
            R_world_cabinet @ [0.0, 0.0, -1.0],
            transform_points(T_WORLD_CABINET, [hinge_cabinet])[0],
            [0, 1, 2, 3],
            [0.0, 0.4, 0.9, 1.4],
            state_range=(-0.05, 1.5),
            mesh="meshes/part_0.ply",
        ),
        make_part(
            "part_1",
            "prismatic",
            R_world_cabinet @ [0.0, -1.0, 0.0],
            None,
            [4, 5, 6],
            [0.0, 0.1, 0.25],
            state_range=(0.0, 0.3),
            mesh="meshes/part_1.ply",
        ),
    )
    articulation = TwinArticulation(frame_count=8, parts=parts if with_parts else ())
    write_articulation(twin_dir / "articulation.json", articulation)
    return articulation


def sample_states(part: ArticulatedPart) -> np.ndarray:
    """A few joint states across the observed range, ends included."""
    lower, upper = min(part.state_range[0], 0.0), max(part.state_range[1], 0.0)
    return np.linspace(lower, upper, 5)


def expected_vertices(twin_dir: Path, part: ArticulatedPart, state: float, T_export_world: np.ndarray) -> np.ndarray:
    """(N, 3) canonical mesh vertices moved by the FORMATS joint transform, in the export frame."""
    assert part.mesh is not None
    p_world = np.asarray(trimesh.load(twin_dir / part.mesh).vertices)
    T_world_world = joint_transform(part.joint_type, part.axis_world, part.pivot_world, state)
    return transform_points(T_export_world @ T_world_world, p_world)


def assert_part_pose(
    twin_dir: Path,
    part: ArticulatedPart,
    state: float,
    T_export_link: np.ndarray,
    T_export_link_canonical: np.ndarray,
    p_link: np.ndarray,
    T_export_world: np.ndarray | None = None,
) -> None:
    """Check a simulator's pose of a part link against articulation.json.

    Args:
        twin_dir: the twin folder.
        part: the part, from articulation.json.
        state: joint state the simulator was set to.
        T_export_link: (4, 4) link pose the simulator computed at ``state``, export frame.
        T_export_link_canonical: (4, 4) link pose the simulator computed at state 0.
        p_link: (N, 3) the part's mesh vertices as the simulator holds them, link frame.
        T_export_world: (4, 4) export transform used; None is the identity.
    """
    T_export_world = np.eye(4) if T_export_world is None else T_export_world
    expected = expected_vertices(twin_dir, part, state, T_export_world)
    got = transform_points(T_export_link, p_link)
    # Vertex order may change through a mesh file: compare the point sets both ways.
    distance = max(cKDTree(got).query(expected)[0].max(), cKDTree(expected).query(got)[0].max())
    assert distance < POSITION_ATOL_M, f"{part.name} at {state}: vertices off by {distance * 1e3:.3f} mm"
    T_world_world = joint_transform(part.joint_type, part.axis_world, part.pivot_world, state)
    T_expected = T_export_world @ T_world_world @ np.linalg.inv(T_export_world)
    T_motion = T_export_link @ np.linalg.inv(T_export_link_canonical)
    angle = Rotation.from_matrix(T_motion[:3, :3] @ T_expected[:3, :3].T).magnitude()
    assert angle < ANGLE_ATOL_RAD, f"{part.name} at {state}: rotation off by {np.degrees(angle):.4f} deg"
    offset = np.linalg.norm(T_motion[:3, 3] - T_expected[:3, 3])
    assert offset < POSITION_ATOL_M, f"{part.name} at {state}: translation off by {offset * 1e3:.3f} mm"


def export(tmp_path: Path, config: ExportConfig = FAST_EXPORT, with_parts: bool = True) -> SimulationExports:
    """Write the cabinet twin and export it."""
    twin_dir = tmp_path / "twin"
    write_cabinet_twin(twin_dir, with_parts=with_parts)
    return export_simulation(twin_dir, config)


def oracle_twin_with_contact(tiny_capture: Path, twin: Path) -> tuple[Path, str, np.ndarray]:
    """The oracle twin of the tiny capture with an affordance exactly at the true handle."""
    from funrec.bench.baselines import write_oracle_twin
    from funrec.formats.affordances import Affordances, Interaction, PartAffordance, write_affordances
    from funrec.formats.ground_truth import read_ground_truth
    from funrec.geometry.transforms import invert_transform, make_transform, transform_points

    write_oracle_twin(tiny_capture, twin)
    gt = read_ground_truth(tiny_capture / "gt")
    (truth,) = gt.parts
    contact = transform_points(invert_transform(gt.T_world_camera[0]), truth.handle_world[None])[0]  # oracle world: camera 0
    frames = np.arange(truth.intervals[0][0], truth.intervals[0][1] + 1)
    affordance = PartAffordance(truth.part.name, truth.part.joint_type, contact, make_transform(np.eye(3), contact), True,
                                (Interaction(frames, frames / 15.0, np.zeros(len(frames))),), np.zeros((0, 3)), np.zeros(0),
                                np.zeros(2), np.tile(contact, (2, 1)))
    write_affordances(twin, Affordances((affordance,), (), "detected", 15.0))
    return twin, truth.part.name, contact
