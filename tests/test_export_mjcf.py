"""twin.xml loaded, posed and stepped in MuJoCo: every part where articulation.json puts it."""

from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from funrec.export.simulation import SimulationExports
from funrec.formats.twin import read_articulation
from funrec.geometry.transforms import make_transform, transform_points
from tests.helpers.twins import FAST_EXPORT, assert_part_pose, export, sample_states

T_EXPORT_WORLD = make_transform(Rotation.from_rotvec([-0.2, 0.4, 1.1]).as_matrix(), [0.3, -2.0, 1.5])
"""A non-trivial export frame (what gravity alignment will later provide)."""
RANGE_SLACK = 0.02
"""How far (rad or m) a soft MuJoCo joint limit may be overshot while the part falls on it."""


@pytest.fixture(scope="module")
def mjcf_export(tmp_path_factory: pytest.TempPathFactory) -> SimulationExports:
    return export(tmp_path_factory.mktemp("mjcf"), dataclasses.replace(FAST_EXPORT, formats=("mjcf",)))


def _body_pose(data: mujoco.MjData, body_id: int) -> np.ndarray:
    return make_transform(data.xmat[body_id].reshape(3, 3), data.xpos[body_id])


def _visual_vertices_in_body(model: mujoco.MjModel, body_name: str) -> np.ndarray:
    """(N, 3) vertices of the body's visual mesh in the body frame, as MuJoCo compiled them
    (MuJoCo re-centres a mesh on its own frame and moves the geom to compensate)."""
    geom_id = model.geom(f"{body_name}_visual").id
    mesh_id = model.geom_dataid[geom_id]
    start, count = model.mesh_vertadr[mesh_id], model.mesh_vertnum[mesh_id]
    p_mesh = model.mesh_vert[start : start + count].astype(np.float64)
    quat_wxyz = model.geom_quat[geom_id]
    R_body_geom = Rotation.from_quat(np.roll(quat_wxyz, -1)).as_matrix()
    return transform_points(make_transform(R_body_geom, model.geom_pos[geom_id]), p_mesh)


def _check_round_trip(exports: SimulationExports, T_export_world: np.ndarray | None = None) -> None:
    assert exports.mjcf is not None
    twin_dir = exports.mjcf.parent
    model = mujoco.MjModel.from_xml_path(str(exports.mjcf))
    data = mujoco.MjData(model)
    for part in read_articulation(twin_dir).parts:
        joint = model.joint(part.name)
        body_id = model.body(part.name).id
        assert model.jnt_bodyid[joint.id] == body_id
        p_body = _visual_vertices_in_body(model, part.name)
        poses = {}
        for state in [0.0, *sample_states(part)]:
            data.qpos[:] = 0.0
            data.qpos[model.jnt_qposadr[joint.id]] = state
            mujoco.mj_kinematics(model, data)
            poses[state] = _body_pose(data, body_id)
            assert_part_pose(twin_dir, part, state, poses[state], poses[0.0], p_body, T_export_world)


def test_mjcf_round_trip(mjcf_export: SimulationExports) -> None:
    _check_round_trip(mjcf_export)


def test_mjcf_round_trip_in_another_export_frame(tmp_path: Path) -> None:
    T_export_world = tuple(tuple(row) for row in T_EXPORT_WORLD)
    exports = export(tmp_path, dataclasses.replace(FAST_EXPORT, formats=("mjcf",), T_export_world=T_export_world))
    _check_round_trip(exports, T_EXPORT_WORLD)


def test_mjcf_joints_are_named_limited_and_in_radians(mjcf_export: SimulationExports) -> None:
    assert mjcf_export.mjcf is not None
    root = ET.parse(mjcf_export.mjcf).getroot()
    assert root.find("compiler").get("angle") == "radian"  # type: ignore[union-attr]
    model = mujoco.MjModel.from_xml_path(str(mjcf_export.mjcf))
    for part in read_articulation(mjcf_export.mjcf.parent).parts:
        joint = model.joint(part.name)
        expected_type = mujoco.mjtJoint.mjJNT_HINGE if part.joint_type == "revolute" else mujoco.mjtJoint.mjJNT_SLIDE
        assert joint.type[0] == expected_type and joint.limited[0]
        np.testing.assert_allclose(joint.range, [min(part.state_range[0], 0.0), max(part.state_range[1], 0.0)])
        assert joint.damping[0] > 0.0 and joint.armature[0] > 0.0
        link = next(link for link in mjcf_export.model.parts if link.name == part.name)
        assert link.mass is not None
        np.testing.assert_allclose(model.body(part.name).mass[0], link.mass.mass_kg, rtol=1e-9)
        np.testing.assert_allclose(np.sort(model.body(part.name).inertia), link.mass.principal_axes()[0], rtol=1e-6)


def test_mjcf_steps_and_respects_the_limits(mjcf_export: SimulationExports) -> None:
    assert mjcf_export.mjcf is not None
    model = mujoco.MjModel.from_xml_path(str(mjcf_export.mjcf))
    data = mujoco.MjData(model)
    for _ in range(500):
        mujoco.mj_step(model, data)
    assert np.all(np.isfinite(data.qpos))
    low, high = model.jnt_range[:, 0], model.jnt_range[:, 1]
    assert np.all(data.qpos >= low - RANGE_SLACK) and np.all(data.qpos <= high + RANGE_SLACK)
    # A contact between a part and its cabinet would be the part's own frame: excluded.
    static_id = model.body("static").id
    for contact in data.contact[: data.ncon]:
        bodies = {model.geom_bodyid[contact.geom1], model.geom_bodyid[contact.geom2]}
        assert static_id not in bodies or len(bodies) == 1


def test_static_only_mjcf_loads(tmp_path: Path) -> None:
    exports = export(tmp_path, dataclasses.replace(FAST_EXPORT, formats=("mjcf",)), with_parts=False)
    assert exports.mjcf is not None
    model = mujoco.MjModel.from_xml_path(str(exports.mjcf))
    assert model.njnt == 0 and model.nbody == 2
    assert model.ngeom == 1 + len(exports.model.base.collision)
    mujoco.mj_step(model, mujoco.MjData(model))


@pytest.mark.slow
def test_reconstructed_room_exports_and_loads_everywhere(tmp_path: Path) -> None:
    """End to end on a room-scale scan: the smoke suite's door sequence is reconstructed (open TSDF
    surfaces, ~500k static triangles) and exported with default settings (CoACD for parts); the
    files load in MuJoCo, pinocchio and USD."""
    import pinocchio as pin
    from pxr import Usd, UsdPhysics

    from funrec.export.simulation import export_simulation
    from funrec.pipeline import reconstruct
    from funrec.synth import generate_sequence, smoke_suite

    capture = generate_sequence(smoke_suite()[0], tmp_path)
    summary = reconstruct(capture, tmp_path / "twin")
    exports = export_simulation(summary.twin_dir)
    assert exports.mjcf is not None and exports.urdf is not None and exports.usd is not None
    model = mujoco.MjModel.from_xml_path(str(exports.mjcf))
    data = mujoco.MjData(model)
    for _ in range(200):
        mujoco.mj_step(model, data)
    assert np.all(np.isfinite(data.qpos)) and model.njnt == len(summary.parts)
    assert pin.buildModelFromUrdf(str(exports.urdf)).nq == len(summary.parts)
    stage = Usd.Stage.Open(str(exports.usd))
    joints = [prim for prim in stage.Traverse() if prim.IsA(UsdPhysics.Joint)]
    assert len(joints) == 1 + len(summary.parts)
    for link in exports.model.parts:
        assert link.mass is not None and link.mass.mass_kg > 0.0
