"""The hand-written twin that funrec view's tests show (tests/test_view.py, tests/test_view_browser.py)."""

from __future__ import annotations

import socket
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from funrec.formats.affordances import Affordances, Interaction, PartAffordance, write_affordances
from funrec.formats.camera_poses import write_camera_poses
from funrec.formats.twin import TwinArticulation, make_part, write_articulation
from funrec.geometry.transforms import make_transform

AXIS, PIVOT = np.array([0.0, 0.0, 1.0]), np.array([0.5, 1.0, 0.0])
CONTACT = np.array([0.1, 0.95, 0.9])


def write_view_twin(tmp_path: Path) -> Path:
    """A hand-written twin: a wall, a door (part_0, revolute) and a drawer point cloud (part_1), a camera path, a contact."""
    (tmp_path / "meshes").mkdir(parents=True)
    trimesh.creation.box(extents=(2.0, 0.1, 2.0)).export(str(tmp_path / "meshes/static.ply"))
    door = trimesh.creation.box(extents=(0.4, 0.02, 0.8))
    door.apply_translation([0.3, 0.95, 0.5])
    door.export(str(tmp_path / "meshes/part_0.ply"))
    drawer = trimesh.PointCloud(np.random.default_rng(0).uniform(-0.1, 0.1, (50, 3)))
    drawer.export(str(tmp_path / "meshes/part_1.ply"))
    parts = (
        make_part("part_0", "revolute", AXIS, PIVOT, [5, 6, 7], [0.0, 0.4, 1.2], mesh="meshes/part_0.ply"),
        make_part("part_1", "prismatic", [0.0, -1.0, 0.0], None, [12, 13], [0.0, 0.25], mesh="meshes/part_1.ply"),
    )
    write_articulation(tmp_path / "articulation.json", TwinArticulation(30, parts, static_mesh="meshes/static.ply"))
    T_world_camera = np.stack([make_transform(Rotation.from_euler("y", 2.0 * i, degrees=True).as_matrix(), [0.05 * i, 0.0, -1.0]) for i in range(30)])
    write_camera_poses(tmp_path / "camera_poses.txt", T_world_camera)
    frames = np.arange(4, 8)
    affordance = PartAffordance("part_0", "revolute", CONTACT, make_transform(np.eye(3), CONTACT), True,
                                (Interaction(frames, frames / 15.0, np.zeros(4)),), np.zeros((0, 3)), np.zeros(0), np.zeros(2), np.tile(CONTACT, (2, 1)))
    write_affordances(tmp_path, Affordances((affordance,), (("part_1", "never held"),), "detected", 15.0))
    return tmp_path


def free_port() -> int:
    """A free TCP port on loopback."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
