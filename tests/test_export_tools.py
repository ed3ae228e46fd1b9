"""Twins in the tools people use: twin.glb in trimesh, the rerun recording read back with
rerun's own reader, binary USD, and Isaac Lab's robot doctor on twin.urdf and twin.usda."""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from funrec.export.simulation import ExportConfig, export_simulation
from tests.helpers.twins import FAST_EXPORT, write_cabinet_twin


@pytest.fixture(scope="module")
def cabinet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    twin_dir = tmp_path_factory.mktemp("tools") / "twin"
    write_cabinet_twin(twin_dir)
    export_simulation(twin_dir, FAST_EXPORT)
    return twin_dir


def test_glb_has_a_named_node_per_link_at_the_link_frame(cabinet: Path) -> None:
    scene = trimesh.load(cabinet / "twin.glb")
    assert isinstance(scene, trimesh.Scene)
    assert {"static", "part_0", "part_1"} <= set(scene.graph.nodes_geometry)
    for name in ("part_0", "part_1"):
        T_world_part, geometry = scene.graph[name]
        posed = scene.geometry[geometry].copy().apply_transform(T_world_part)
        canonical = trimesh.load(cabinet / "meshes" / f"{name}.ply")
        # glTF may split vertices per face: compare the point sets both ways.
        assert cKDTree(posed.vertices).query(canonical.vertices)[0].max() < 1e-5
        assert cKDTree(canonical.vertices).query(posed.vertices)[0].max() < 1e-5


def test_usdc_on_request(cabinet: Path, tmp_path: Path) -> None:
    from pxr import Usd, UsdPhysics

    twin_dir = tmp_path / "twin"
    shutil.copytree(cabinet, twin_dir)
    (twin_dir / "twin.usda").unlink()
    exports = export_simulation(twin_dir, dataclasses.replace(FAST_EXPORT, formats=("usd",), usd_binary=True))
    assert exports.usd == twin_dir / "twin.usdc" and not (twin_dir / "twin.usda").exists()
    assert (twin_dir / "twin.usdc").read_bytes()[:8] == b"PXR-USDC"
    stage = Usd.Stage.Open(str(exports.usd))
    joint = stage.GetPrimAtPath("/twin/joints/part_0")
    assert joint.IsA(UsdPhysics.RevoluteJoint)
    np.testing.assert_allclose(joint.GetAttribute("physxJoint:maxJointVelocity").Get(),
                               np.degrees(ExportConfig().revolute_velocity_rad_s), rtol=1e-6)
    assert joint.GetAttribute("funrec:jointFriction").Get() > 0.0


def test_isaaclab_robot_doctor_accepts_urdf_and_usd(cabinet: Path) -> None:
    pytest.importorskip("isaaclab_robot_doctor")
    for name in ("twin.urdf", "twin.usda"):
        result = subprocess.run([sys.executable, "-c", "import sys; from isaaclab_robot_doctor.cli import main; sys.exit(main())", "check", name], cwd=cabinet,
                                capture_output=True, text=True, timeout=120)
        assert result.returncode == 0, result.stdout + result.stderr
        assert "0 errors, 0 warnings" in result.stdout, result.stdout


def test_rerun_recording_reads_back(tiny_capture: Path, tmp_path: Path) -> None:
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    from funrec.export.rerun_log import write_rerun
    from funrec.formats.capture import load_capture
    from funrec.formats.twin import read_articulation
    from tests.helpers.twins import oracle_twin_with_contact

    twin, part, _ = oracle_twin_with_contact(tiny_capture, tmp_path / "oracle")
    rrd = write_rerun(twin, tmp_path / "twin.rrd", load_capture(tiny_capture))
    frames: dict[str, set[int]] = defaultdict(set)
    static = set()
    for chunk in RrdReader(rrd).stream():
        if chunk.is_static:
            static.add(chunk.entity_path)
        elif "frame" in chunk.timeline_names:
            frames[chunk.entity_path].update(chunk.to_record_batch().column("frame").to_pylist())
    articulation = read_articulation(twin)
    F = articulation.frame_count
    for entity in ("world/camera", f"world/parts/{part}", "world/camera/image/rgb", "world/camera/image/depth",
                   "world/camera/image/parts", "world/camera/image/hand"):
        assert frames[f"/{entity}"] == set(range(F)), entity
    assert frames[f"/joints/{part}"] == set(articulation.parts[0].frames.tolist())
    for entity in ("world/static", f"world/parts/{part}/mesh", f"world/parts/{part}/contact", f"world/parts/{part}/grasp",
                   "world/camera_path", "world/camera/image"):
        assert f"/{entity}" in static, entity
