"""twin.urdf read back by yourdfpy and pinocchio, and the shared pieces of the simulation exports
(model frames, mass properties, convex decomposition, errors).

The cabinet twin built from exact boxes, and what any simulator must reproduce, are in
tests/helpers/twins.py.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from funrec.errors import ExportError
from funrec.export.collision import CollisionConfig, convex_piece, decompose
from funrec.export.sim_model import mass_properties, part_link_frame
from funrec.export.simulation import SimulationExports, export_simulation
from funrec.formats.twin import read_articulation, write_articulation
from funrec.geometry.joints import joint_transform
from funrec.geometry.transforms import make_transform, transform_points
from tests.helpers.twins import (
    DOOR_SIZE_M,
    FAST_EXPORT,
    T_WORLD_CABINET,
    assert_part_pose,
    box,
    export,
    sample_states,
    write_cabinet_twin,
)


@pytest.fixture(scope="module")
def urdf_export(tmp_path_factory: pytest.TempPathFactory) -> SimulationExports:
    return export(tmp_path_factory.mktemp("urdf"), dataclasses.replace(FAST_EXPORT, formats=("urdf",)))


def _twin_dir(exports: SimulationExports) -> Path:
    assert exports.urdf is not None
    return exports.urdf.parent


def test_urdf_round_trip_yourdfpy(urdf_export: SimulationExports) -> None:
    import yourdfpy

    twin_dir = _twin_dir(urdf_export)
    urdf = yourdfpy.URDF.load(str(urdf_export.urdf), load_meshes=False)
    articulation = read_articulation(twin_dir)
    assert sorted(urdf.actuated_joint_names) == ["part_0", "part_1"]
    for part in articulation.parts:
        visual_file = urdf.link_map[part.name].visuals[0].geometry.mesh.filename
        assert not Path(visual_file).is_absolute()
        p_link = np.asarray(trimesh.load(twin_dir / visual_file).vertices)
        urdf.update_cfg({part.name: 0.0})
        T_static_part_canonical = urdf.get_transform(part.name, "static")
        for state in sample_states(part):
            urdf.update_cfg({part.name: state})
            T_static_part = urdf.get_transform(part.name, "static")
            assert_part_pose(twin_dir, part, state, T_static_part, T_static_part_canonical, p_link)
        urdf.update_cfg({part.name: 0.0})


def test_urdf_round_trip_pinocchio(urdf_export: SimulationExports) -> None:
    import pinocchio as pin

    twin_dir = _twin_dir(urdf_export)
    model = pin.buildModelFromUrdf(str(urdf_export.urdf))
    visuals = pin.buildGeomFromUrdf(model, str(urdf_export.urdf), pin.GeometryType.VISUAL, package_dirs=[str(twin_dir)])
    collisions = pin.buildGeomFromUrdf(
        model, str(urdf_export.urdf), pin.GeometryType.COLLISION, package_dirs=[str(twin_dir)]
    )
    assert collisions.ngeoms == sum(len(link.collision) for link in (urdf_export.model.base, *urdf_export.model.parts))
    data = model.createData()
    assert model.nq == 2
    for part in read_articulation(twin_dir).parts:
        joint_id = model.getJointId(part.name)
        frame_id = model.getFrameId(part.name, pin.FrameType.BODY)
        np.testing.assert_allclose(
            [model.lowerPositionLimit[model.idx_qs[joint_id]], model.upperPositionLimit[model.idx_qs[joint_id]]],
            [min(part.state_range[0], 0.0), max(part.state_range[1], 0.0)],
            atol=1e-12,
        )
        (geometry,) = [g for g in visuals.geometryObjects if g.parentJoint == joint_id]
        p_mesh = np.asarray(trimesh.load(geometry.meshPath).vertices)
        poses = {}
        for state in [0.0, *sample_states(part)]:
            q = pin.neutral(model)
            q[model.idx_qs[joint_id]] = state
            pin.forwardKinematics(model, data, q)
            pin.updateFramePlacements(model, data)
            poses[state] = data.oMf[frame_id].homogeneous.copy()
            T_part_geometry = geometry.placement.homogeneous
            assert_part_pose(twin_dir, part, state, poses[state], poses[0.0], transform_points(T_part_geometry, p_mesh))


def test_urdf_joints_limits_and_dynamics(urdf_export: SimulationExports) -> None:
    import yourdfpy

    urdf = yourdfpy.URDF.load(str(urdf_export.urdf), load_meshes=False)
    door, drawer = urdf.joint_map["part_0"], urdf.joint_map["part_1"]
    assert (door.type, drawer.type) == ("revolute", "prismatic")
    np.testing.assert_allclose(door.axis, [0.0, 0.0, 1.0])
    assert (door.limit.lower, door.limit.upper) == (-0.05, 1.5)
    assert (drawer.limit.lower, drawer.limit.upper) == (0.0, 0.3)
    assert (
        door.limit.effort == FAST_EXPORT.revolute_effort_nm
        and drawer.limit.velocity == FAST_EXPORT.prismatic_velocity_m_s
    )
    assert float(door.dynamics.damping) == FAST_EXPORT.revolute_damping  # yourdfpy keeps it a string
    assert urdf.link_map["static"].inertial is not None and urdf.link_map["world"].inertial is None
    assert urdf.joint_map["world_to_static"].type == "fixed"
    assert float(door.dynamics.friction) >= FAST_EXPORT.revolute_friction_nm
    assert len(urdf.link_map["static"].collisions) == len(urdf_export.model.base.collision) > 0


def test_mass_and_inertia_follow_the_density(urdf_export: SimulationExports, tmp_path: Path) -> None:
    door, drawer = urdf_export.model.parts
    assert door.mass is not None and drawer.mass is not None
    # The door is one watertight box: its mass properties are the solid box's, up to the float32
    # vertices of the PLY file (relative error ~1e-7).
    w, d, h = DOOR_SIZE_M
    mass = FAST_EXPORT.density_kg_m3 * w * d * h
    assert door.mass.source == "mesh"
    np.testing.assert_allclose(door.mass.mass_kg, mass, rtol=1e-5)
    moments, _ = door.mass.principal_axes()
    box_moments = sorted(mass / 12.0 * np.array([d * d + h * h, w * w + h * h, w * w + d * d]))
    np.testing.assert_allclose(moments, box_moments, rtol=1e-5)
    for link in (door, drawer):
        assert link.mass is not None
        moments, _ = link.mass.principal_axes()
        assert link.mass.mass_kg > 0.0 and np.all(moments > 0.0)
        assert moments[0] + moments[1] >= moments[2] * (1.0 - 1e-9)  # triangle inequality
        np.testing.assert_allclose(link.mass.mass_kg, FAST_EXPORT.density_kg_m3 * link.mass.volume_m3)
    # The centre of mass of the box door is its centre, expressed in the link frame.
    centre_world = transform_points(T_WORLD_CABINET, [[0.0, -0.21, 0.6]])[0]
    np.testing.assert_allclose(transform_points(door.T_export_link, [door.mass.com_link])[0], centre_world, atol=1e-6)
    # A density override scales that part only.
    heavy = export(tmp_path, dataclasses.replace(FAST_EXPORT, formats=(), part_densities=(("part_0", 1200.0),)))
    np.testing.assert_allclose(heavy.model.parts[0].mass.mass_kg, 2.0 * door.mass.mass_kg, rtol=1e-9)
    np.testing.assert_allclose(heavy.model.parts[1].mass.mass_kg, drawer.mass.mass_kg, rtol=1e-9)


def test_open_scan_takes_its_mass_from_the_convex_pieces() -> None:
    # A TSDF scan of a door is its front surface only: no volume of its own.
    front = trimesh.Trimesh([[0, 0, 0], [0.5, 0, 0], [0, 0, 0.7], [0.5, 0, 0.7]], [[0, 1, 2], [1, 3, 2]])
    pieces = decompose(front, "hull", CollisionConfig(min_thickness_m=0.02), "front")
    mass = mass_properties(front, pieces, density_kg_m3=600.0)
    assert mass.source == "collision"
    np.testing.assert_allclose(mass.mass_kg, 600.0 * 0.5 * 0.7 * 0.02, rtol=1e-9)
    np.testing.assert_allclose(mass.com_link, [0.25, 0.0, 0.35], atol=1e-12)
    assert np.all(np.linalg.eigvalsh(mass.inertia_link) > 0.0)


_vectors = arrays(np.float64, 3, elements=st.floats(-5.0, 5.0, allow_nan=False))


@settings(deadline=None, max_examples=200)
@given(
    axis=_vectors.filter(lambda a: np.linalg.norm(a) > 1e-3),
    pivot=_vectors,
    centroid=_vectors,
    state=st.floats(-3.0, 3.0),
    revolute=st.booleans(),
)
def test_joint_about_link_z_is_the_formats_joint_transform(
    axis: np.ndarray, pivot: np.ndarray, centroid: np.ndarray, state: float, revolute: bool
) -> None:
    """What every exporter relies on: moving the link frame along or about its own z by s is
    FORMATS' joint transform of s applied to the canonical part."""
    joint_type = "revolute" if revolute else "prismatic"
    T_world_part = part_link_frame(joint_type, axis / np.linalg.norm(axis), pivot if revolute else None, centroid)
    np.testing.assert_allclose(T_world_part[:3, :3].T @ T_world_part[:3, :3], np.eye(3), atol=1e-12)
    assert np.linalg.det(T_world_part[:3, :3]) > 0.0
    if revolute:
        T_part_moved = make_transform(Rotation.from_rotvec([0.0, 0.0, state]).as_matrix(), np.zeros(3))
    else:
        T_part_moved = make_transform(np.eye(3), [0.0, 0.0, state])
    T_world_world = joint_transform(joint_type, axis, pivot if revolute else None, state)
    np.testing.assert_allclose(T_world_part @ T_part_moved, T_world_world @ T_world_part, atol=1e-9)


def test_revolute_link_frame_lies_on_the_axis(urdf_export: SimulationExports) -> None:
    twin_dir = _twin_dir(urdf_export)
    door = read_articulation(twin_dir).parts[0]
    assert door.pivot_world is not None and np.linalg.norm(door.pivot_world) > 1.0
    T_export_door = urdf_export.model.parts[0].T_export_link
    np.testing.assert_allclose(T_export_door[:3, 2], door.axis_world, atol=1e-12)
    offset = T_export_door[:3, 3] - door.pivot_world
    np.testing.assert_allclose(np.cross(offset, door.axis_world), 0.0, atol=1e-12)


def test_static_only_twin_exports_a_fixed_model(tmp_path: Path) -> None:
    import pinocchio as pin
    import yourdfpy

    exports = export(tmp_path, dataclasses.replace(FAST_EXPORT, formats=("urdf",)), with_parts=False)
    assert exports.urdf is not None
    urdf = yourdfpy.URDF.load(str(exports.urdf), load_meshes=False)
    assert list(urdf.link_map) == ["world", "static"] and list(urdf.joint_map) == ["world_to_static"]
    assert pin.buildModelFromUrdf(str(exports.urdf)).nq == 0


def test_missing_mesh_names_the_file(tmp_path: Path) -> None:
    twin_dir = tmp_path / "twin"
    write_cabinet_twin(twin_dir)
    (twin_dir / "meshes" / "part_1.ply").unlink()
    with pytest.raises(ExportError, match=r"meshes/part_1\.ply: mesh file is missing"):
        export_simulation(twin_dir, FAST_EXPORT)


def test_point_cloud_mesh_is_rejected(tmp_path: Path) -> None:
    twin_dir = tmp_path / "twin"
    write_cabinet_twin(twin_dir)
    trimesh.PointCloud(np.random.default_rng(0).random((50, 3))).export(twin_dir / "meshes" / "static.ply")
    with pytest.raises(ExportError, match=r"meshes/static\.ply: holds no triangles"):
        export_simulation(twin_dir, FAST_EXPORT)


def test_bad_requests_are_export_errors(tmp_path: Path) -> None:
    twin_dir = tmp_path / "twin"
    articulation = write_cabinet_twin(twin_dir)
    with pytest.raises(
        ExportError, match=r"part_densities names \['door'\], the twin has parts \['part_0', 'part_1'\]"
    ):
        export_simulation(twin_dir, dataclasses.replace(FAST_EXPORT, part_densities=(("door", 900.0),)))
    still = dataclasses.replace(articulation.parts[1], state_range=(0.0, 0.0))
    write_articulation(
        twin_dir / "articulation.json", dataclasses.replace(articulation, parts=(articulation.parts[0], still))
    )
    with pytest.raises(ExportError, match=r"articulation\.json: part part_1 has an empty range"):
        export_simulation(twin_dir, FAST_EXPORT)
    (twin_dir / "articulation.json").unlink()
    with pytest.raises(ExportError, match=r"articulation\.json: file is missing"):
        export_simulation(twin_dir, FAST_EXPORT)


def test_convex_pieces_are_thick_and_watertight() -> None:
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]])
    piece = convex_piece(np.asarray(flat.vertices, dtype=np.float64), min_thickness_m=0.01)
    assert piece is not None and piece.is_watertight
    np.testing.assert_allclose(sorted(piece.extents), [0.01, 1.0, 1.0], atol=1e-9)
    config = CollisionConfig(grid_cell_m=0.25)
    pieces = decompose(trimesh.creation.box(extents=(1.0, 0.5, 0.02)), "grid", config, "box")
    assert len(pieces) > 4 and all(p.is_watertight and p.volume > 0.0 for p in pieces)
    with pytest.raises(ExportError, match="empty.ply: mesh has no triangle"):
        decompose(trimesh.Trimesh(), "hull", config, "empty.ply")


def test_grid_pieces_do_not_wedge_floor_and_front_together() -> None:
    """A cabinet front standing on the floor: one hull of the cell holding both filled the space in front of
    the cabinet (up to a cell deep and high), where a robot's base and fingers reach for a low drawer."""
    # Open surfaces, as a TSDF scan's: the floor z = 0 in front of the front (y < 0), the front y = 0 above it.
    floor = trimesh.Trimesh([[-0.5, -1, 0], [0.5, -1, 0], [0.5, 0, 0], [-0.5, 0, 0]], [[0, 1, 2], [0, 2, 3]])
    front = trimesh.Trimesh([[-0.5, 0, 0], [0.5, 0, 0], [0.5, 0, 0.6], [-0.5, 0, 0.6]], [[0, 2, 1], [0, 3, 2]])
    room = trimesh.util.concatenate([floor, front])
    room = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(room.vertices, room.faces, 0.03))  # a scan's fine triangles
    shift = np.array([0.013, 0.12, 0.07])  # the corner inside grid cells, not on their boundaries
    room.apply_translation(shift)
    pieces = decompose(room, "grid", CollisionConfig(grid_cell_m=0.25), "room")
    # Points 3 cm in front of the front and 3 cm above the floor: inside no piece (each piece is padded to
    # min_thickness_m = 1 cm, so its surface stays within 5 mm of the surfaces).
    gap = np.column_stack([np.linspace(-0.45, 0.45, 10), np.full(10, -0.03), np.full(10, 0.03)]) + shift
    assert not any(piece.contains(gap).any() for piece in pieces)


@pytest.mark.slow
def test_coacd_splits_a_concave_drawer() -> None:
    pytest.importorskip("coacd")
    drawer = trimesh.util.concatenate(
        [
            box((0.5, 0.02, 0.2), (0.0, -0.2, 0.1)),
            box((0.5, 0.4, 0.01), (0.0, 0.0, 0.005)),
            box((0.5, 0.02, 0.2), (0.0, 0.2, 0.1)),
        ]
    )
    pieces = decompose(drawer, "coacd", CollisionConfig(), "drawer")
    assert len(pieces) >= 3
    assert sum(p.volume for p in pieces) < 0.5 * drawer.convex_hull.volume


def test_export_of_an_in_memory_twin_equals_the_export_of_its_folder(tmp_path: Path) -> None:
    """The pipeline hands the export the twin it holds (InMemoryTwin) instead of reading back the
    folder it just wrote; both must give the same files, and the meshes it hands over must be what
    the PLY files hold, so that `funrec export TWIN` later rebuilds the same model."""
    import shutil

    from funrec.export.simulation import InMemoryTwin
    from funrec.formats.meshes import as_written
    from funrec.formats.twin import read_articulation

    config = dataclasses.replace(FAST_EXPORT, formats=("urdf", "mjcf"))
    folder = export(tmp_path / "a", config)
    twin_dir = folder.urdf.parent
    shutil.copytree(twin_dir, tmp_path / "b")
    articulation = read_articulation(twin_dir)
    names = [articulation.static_mesh] + [p.mesh for p in articulation.parts]
    meshes = {name: trimesh.load(twin_dir / name, process=False) for name in names}
    export_simulation(tmp_path / "b", config, InMemoryTwin(articulation, meshes))
    for name in ("twin.urdf", "twin.xml"):
        assert (tmp_path / "b" / name).read_text() == (twin_dir / name).read_text(), name
    rng = np.random.default_rng(0)
    mesh = trimesh.Trimesh(rng.normal(size=(30, 3)), rng.integers(0, 30, size=(20, 3)), process=False)
    mesh.export(tmp_path / "m.ply")
    read = trimesh.load(tmp_path / "m.ply", process=False)
    np.testing.assert_array_equal(as_written(mesh).vertices, read.vertices)  # exact: the same float32 values
    np.testing.assert_array_equal(as_written(mesh).faces, read.faces)
