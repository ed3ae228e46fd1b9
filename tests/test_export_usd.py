"""twin.usda read back with pxr: UsdPhysics articulation, joint frames, limits, masses, and every
part posed from its joint frames where articulation.json puts it."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from funrec.export.simulation import SimulationExports
from funrec.formats.twin import read_articulation
from funrec.geometry.transforms import make_transform, transform_points
from tests.helpers.twins import FAST_EXPORT, assert_part_pose, export, sample_states

pxr = pytest.importorskip("pxr")
from pxr import Usd, UsdGeom, UsdPhysics  # noqa: E402

T_EXPORT_WORLD = make_transform(Rotation.from_rotvec([0.5, 0.1, -0.7]).as_matrix(), [-1.0, 0.5, 0.2])
"""A non-trivial export frame (what gravity alignment will later provide)."""
AXIS_VECTORS = {"X": np.array([1.0, 0.0, 0.0]), "Y": np.array([0.0, 1.0, 0.0]), "Z": np.array([0.0, 0.0, 1.0])}
"""UsdPhysics joint axis tokens as vectors of the joint frame."""
FLOAT32_ATOL = 1e-5
"""USD joint frames and mesh points are float32: metre-scale values agree to about 1e-6 m."""


@pytest.fixture(scope="module")
def usd_export(tmp_path_factory: pytest.TempPathFactory) -> SimulationExports:
    return export(tmp_path_factory.mktemp("usd"), dataclasses.replace(FAST_EXPORT, formats=("usd",)))


def _matrix(gf_matrix: object) -> np.ndarray:
    """A Gf.Matrix4d (row-vector convention) as a (4, 4) T_a_b acting on column vectors."""
    return np.array(gf_matrix, dtype=np.float64).T


def _pos_rot(position: object, rotation: object) -> np.ndarray:
    """(4, 4) transform from a UsdPhysics localPos (Gf.Vec3f) and localRot (Gf.Quatf)."""
    imaginary = rotation.GetImaginary()  # type: ignore[attr-defined]
    quat_xyzw = [imaginary[0], imaginary[1], imaginary[2], rotation.GetReal()]  # type: ignore[attr-defined]
    return make_transform(Rotation.from_quat(quat_xyzw).as_matrix(), np.array(position, dtype=np.float64))


class UsdJoint:
    """A UsdPhysics revolute or prismatic joint read back, with the forward kinematics of its child."""

    def __init__(self, stage: Usd.Stage, prim: Usd.Prim) -> None:
        self.revolute = prim.IsA(UsdPhysics.RevoluteJoint)
        joint = UsdPhysics.RevoluteJoint(prim) if self.revolute else UsdPhysics.PrismaticJoint(prim)
        self.axis = AXIS_VECTORS[joint.GetAxisAttr().Get()]
        self.lower, self.upper = joint.GetLowerLimitAttr().Get(), joint.GetUpperLimitAttr().Get()
        (body0,) = joint.GetBody0Rel().GetTargets()
        (body1,) = joint.GetBody1Rel().GetTargets()
        self.body0, self.body1 = stage.GetPrimAtPath(body0), stage.GetPrimAtPath(body1)
        self.T_body0_joint = _pos_rot(joint.GetLocalPos0Attr().Get(), joint.GetLocalRot0Attr().Get())
        self.T_body1_joint = _pos_rot(joint.GetLocalPos1Attr().Get(), joint.GetLocalRot1Attr().Get())

    def T_export_body1(self, state: float) -> np.ndarray:
        """(4, 4) pose of body1 at joint state ``state`` (rad or m), from body0's pose and the joint frames."""
        T_export_body0 = _matrix(UsdGeom.XformCache().GetLocalToWorldTransform(self.body0))
        if self.revolute:
            T_joint0_joint1 = make_transform(Rotation.from_rotvec(self.axis * state).as_matrix(), np.zeros(3))
        else:
            T_joint0_joint1 = make_transform(np.eye(3), self.axis * state)
        return T_export_body0 @ self.T_body0_joint @ T_joint0_joint1 @ np.linalg.inv(self.T_body1_joint)


def _check_round_trip(exports: SimulationExports, T_export_world: np.ndarray | None = None) -> None:
    assert exports.usd is not None
    twin_dir = exports.usd.parent
    stage = Usd.Stage.Open(str(exports.usd))
    root = stage.GetDefaultPrim()
    xform_cache = UsdGeom.XformCache()
    for part in read_articulation(twin_dir).parts:
        joint = UsdJoint(stage, root.GetChild("joints").GetChild(part.name))
        assert joint.body1.GetName() == part.name and joint.body0.GetName() == "static"
        T_export_body1 = _matrix(xform_cache.GetLocalToWorldTransform(joint.body1))
        # PhysX needs the authored body pose to satisfy the joint at state 0.
        np.testing.assert_allclose(joint.T_export_body1(0.0), T_export_body1, atol=FLOAT32_ATOL)
        visual = joint.body1.GetChild("visual")
        T_body_visual = np.linalg.inv(T_export_body1) @ _matrix(xform_cache.GetLocalToWorldTransform(visual))
        p_body = transform_points(T_body_visual, np.array(UsdGeom.Mesh(visual).GetPointsAttr().Get(), dtype=np.float64))
        for state in sample_states(part):
            assert_part_pose(
                twin_dir, part, state, joint.T_export_body1(state), joint.T_export_body1(0.0), p_body, T_export_world
            )


def test_usd_round_trip(usd_export: SimulationExports) -> None:
    _check_round_trip(usd_export)


def test_usd_round_trip_in_another_export_frame(tmp_path: Path) -> None:
    T_export_world = tuple(tuple(row) for row in T_EXPORT_WORLD)
    exports = export(tmp_path, dataclasses.replace(FAST_EXPORT, formats=("usd",), T_export_world=T_export_world))
    _check_round_trip(exports, T_EXPORT_WORLD)


def test_usd_stage_is_an_isaac_style_articulation(usd_export: SimulationExports) -> None:
    assert usd_export.usd is not None
    stage = Usd.Stage.Open(str(usd_export.usd))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    root = stage.GetDefaultPrim()
    assert root.HasAPI(UsdPhysics.ArticulationRootAPI)
    root_joint = UsdPhysics.FixedJoint(root.GetChild("joints").GetChild("root_joint"))
    assert not root_joint.GetBody0Rel().GetTargets()
    assert root_joint.GetBody1Rel().GetTargets() == [root.GetChild("static").GetPath()]
    for link in (usd_export.model.base, *usd_export.model.parts):
        body = root.GetChild(link.name)
        assert body.HasAPI(UsdPhysics.RigidBodyAPI)
        pieces = body.GetChild("collision").GetChildren()
        assert len(pieces) == len(link.collision) > 0
        for piece in pieces:
            assert piece.HasAPI(UsdPhysics.CollisionAPI)
            assert UsdPhysics.MeshCollisionAPI(piece).GetApproximationAttr().Get() == UsdPhysics.Tokens.convexHull
        assert not body.GetChild("visual").HasAPI(UsdPhysics.CollisionAPI)


def test_usd_limits_are_degrees_and_masses_match(usd_export: SimulationExports) -> None:
    assert usd_export.usd is not None
    stage = Usd.Stage.Open(str(usd_export.usd))
    root = stage.GetDefaultPrim()
    for part, link in zip(read_articulation(usd_export.usd.parent).parts, usd_export.model.parts):
        joint = UsdJoint(stage, root.GetChild("joints").GetChild(part.name))
        lower, upper = min(part.state_range[0], 0.0), max(part.state_range[1], 0.0)
        if part.joint_type == "revolute":
            assert joint.revolute
            lower, upper = math.degrees(lower), math.degrees(upper)
        np.testing.assert_allclose([joint.lower, joint.upper], [lower, upper], rtol=1e-6)
        mass_api = UsdPhysics.MassAPI(root.GetChild(part.name))
        assert link.mass is not None
        np.testing.assert_allclose(mass_api.GetMassAttr().Get(), link.mass.mass_kg, rtol=1e-6)
        np.testing.assert_allclose(mass_api.GetCenterOfMassAttr().Get(), link.mass.com_link, atol=FLOAT32_ATOL)
        principal = mass_api.GetPrincipalAxesAttr().Get()
        R_link_principal = _pos_rot((0.0, 0.0, 0.0), principal)[:3, :3]
        moments = np.array(mass_api.GetDiagonalInertiaAttr().Get(), dtype=np.float64)
        inertia = R_link_principal @ np.diag(moments) @ R_link_principal.T
        np.testing.assert_allclose(inertia, link.mass.inertia_link, atol=1e-6 * np.abs(moments).max())


def test_static_only_usd(tmp_path: Path) -> None:
    exports = export(tmp_path, dataclasses.replace(FAST_EXPORT, formats=("usd",)), with_parts=False)
    assert exports.usd is not None
    stage = Usd.Stage.Open(str(exports.usd))
    joints = [prim for prim in stage.Traverse() if prim.IsA(UsdPhysics.Joint)]
    assert [prim.GetName() for prim in joints] == ["root_joint"]
    assert stage.GetDefaultPrim().GetChild("static").GetChild("visual").IsA(UsdGeom.Mesh)
