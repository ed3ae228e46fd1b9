"""twin.usda: the twin as a USD stage with a UsdPhysics articulation laid out as Isaac Sim's URDF
importer lays out a fixed-base robot. The only module that imports pxr."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import trimesh
from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt
from scipy.spatial.transform import Rotation

from funrec.errors import ExportError
from funrec.export.sim_model import SimJoint, SimLink, SimModel
from funrec.typed import FloatArray

GRAVITY_M_S2 = 9.81
"""Magnitude of the physics scene's gravity, along -z of the export frame."""
JOINT_AXIS = "Z"
"""Joint axis token: every joint frame has the joint axis as its local z."""
FRICTION_ATTR = "funrec:jointFriction"
"""Joint attribute holding the Coulomb friction of the joint (N m or N, as SimJoint.friction).
UsdPhysics has no joint friction; PhysX's ``physxJoint:jointFriction`` is a unitless coefficient
of the joint's constraint force, not a torque, so the value is kept in FunREC's own namespace."""
MAX_VELOCITY_ATTR = "physxJoint:maxJointVelocity"
"""PhysX joint velocity limit, degrees/s (revolute) or m/s (prismatic), as Isaac Sim's URDF
importer writes it."""


def write_usd(model: SimModel, path: str | Path) -> Path:
    """Write twin.usda.

    ``/<name>`` (default prim, ArticulationRootAPI) holds one rigid body per link: ``static``
    (fixed to the world by ``joints/root_joint``) and one per part, each an Xform at its link
    frame (see :class:`~funrec.export.sim_model.SimModel`) with a ``visual`` mesh and convex
    ``collision`` pieces (CollisionAPI, approximation "convexHull", purpose "guide"), all in the
    link frame. ``joints/<part>`` is a RevoluteJoint or PrismaticJoint with axis "Z": its frame is
    the part's link frame (localPos0/localRot0 in the static body, identity in the part), its
    limits are in degrees (revolute) or metres (prismatic), a zero-stiffness DriveAPI carries
    the joint damping, ``physxJoint:maxJointVelocity`` the velocity limit and
    ``funrec:jointFriction`` the Coulomb friction (see FRICTION_ATTR). Stage: metersPerUnit 1, kilogramsPerUnit 1, upAxis Z, and a
    ``/physicsScene`` with gravity along -z.

    Args:
        model: the simulator-neutral model.
        path: output file (.usda for text, .usd/.usdc for binary).

    Returns:
        ``path``.

    Raises:
        ExportError: USD cannot write the file.
    """
    path = Path(path)
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0)
    root_path = Sdf.Path.absoluteRootPath.AppendChild(Tf.MakeValidIdentifier(model.name))
    root = UsdGeom.Xform.Define(stage, root_path).GetPrim()
    stage.SetDefaultPrim(root)
    UsdPhysics.ArticulationRootAPI.Apply(root)
    scene = UsdPhysics.Scene.Define(stage, "/physicsScene")
    scene.CreateGravityDirectionAttr(Gf.Vec3f(0.0, 0.0, -1.0))
    scene.CreateGravityMagnitudeAttr(GRAVITY_M_S2)

    body_paths = {}
    for link in (model.base, *model.parts):
        body_paths[link.name] = _define_body(stage, root_path.AppendChild(Tf.MakeValidIdentifier(link.name)), link)
    joints_path = root_path.AppendChild("joints")
    UsdGeom.Scope.Define(stage, joints_path)
    fixed = UsdPhysics.FixedJoint.Define(stage, joints_path.AppendChild("root_joint"))
    fixed.CreateBody1Rel().SetTargets([body_paths[model.base.name]])
    for joint in model.joints:
        _define_joint(stage, joints_path.AppendChild(Tf.MakeValidIdentifier(joint.name)), joint, body_paths)
    if not stage.GetRootLayer().Export(str(path)):
        raise ExportError(f"{path}: USD could not write the stage")
    return path


def _define_body(stage: Usd.Stage, body_path: Sdf.Path, link: SimLink) -> Sdf.Path:
    body = UsdGeom.Xform.Define(stage, body_path)
    T_export_link = link.T_export_link
    quat_xyzw = Rotation.from_matrix(T_export_link[:3, :3]).as_quat()
    body.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*map(float, T_export_link[:3, 3])))
    body.AddOrientOp(UsdGeom.XformOp.PrecisionDouble).Set(
        Gf.Quatd(float(quat_xyzw[3]), Gf.Vec3d(*map(float, quat_xyzw[:3])))
    )
    prim = body.GetPrim()
    UsdPhysics.RigidBodyAPI.Apply(prim)
    mass_api = UsdPhysics.MassAPI.Apply(prim)
    moments, R_link_principal = link.mass.principal_axes()
    principal_xyzw = Rotation.from_matrix(R_link_principal).as_quat()
    mass_api.CreateMassAttr(float(link.mass.mass_kg))
    mass_api.CreateCenterOfMassAttr(Gf.Vec3f(*map(float, link.mass.com_link)))
    mass_api.CreateDiagonalInertiaAttr(Gf.Vec3f(*map(float, moments)))
    mass_api.CreatePrincipalAxesAttr(Gf.Quatf(float(principal_xyzw[3]), Gf.Vec3f(*map(float, principal_xyzw[:3]))))
    if link.visual is not None:
        _define_mesh(stage, body_path.AppendChild("visual"), link.visual)
    collision_path = body_path.AppendChild("collision")
    UsdGeom.Scope.Define(stage, collision_path)
    for i, piece in enumerate(link.collision):
        mesh = _define_mesh(stage, collision_path.AppendChild(f"piece_{i:03d}"), piece)
        mesh.CreatePurposeAttr(UsdGeom.Tokens.guide)
        UsdPhysics.CollisionAPI.Apply(mesh.GetPrim())
        UsdPhysics.MeshCollisionAPI.Apply(mesh.GetPrim()).CreateApproximationAttr(UsdPhysics.Tokens.convexHull)
    return body_path


def _define_mesh(stage: Usd.Stage, mesh_path: Sdf.Path, mesh: trimesh.Trimesh) -> UsdGeom.Mesh:
    """A triangle mesh prim; per-vertex colours become displayColor when the mesh has them."""
    usd_mesh = UsdGeom.Mesh.Define(stage, mesh_path)
    points = np.ascontiguousarray(mesh.vertices, dtype=np.float32)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int32)
    usd_mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
    usd_mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, dtype=np.int32)))
    usd_mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.ravel()))
    usd_mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    usd_mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([points.min(axis=0), points.max(axis=0)])))
    if mesh.visual.kind == "vertex":
        colors = np.ascontiguousarray(np.asarray(mesh.visual.vertex_colors)[:, :3], dtype=np.float32) / 255.0
        primvar = UsdGeom.PrimvarsAPI(usd_mesh).CreatePrimvar(
            "displayColor", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.vertex
        )
        primvar.Set(Vt.Vec3fArray.FromNumpy(colors))
    return usd_mesh


def _define_joint(stage: Usd.Stage, joint_path: Sdf.Path, joint: SimJoint, body_paths: dict[str, Sdf.Path]) -> None:
    revolute = joint.joint_type == "revolute"
    if revolute:
        usd_joint = UsdPhysics.RevoluteJoint.Define(stage, joint_path)
        lower, upper = math.degrees(joint.lower), math.degrees(joint.upper)
    else:
        usd_joint = UsdPhysics.PrismaticJoint.Define(stage, joint_path)
        lower, upper = joint.lower, joint.upper
    usd_joint.CreateAxisAttr(JOINT_AXIS)
    usd_joint.CreateLowerLimitAttr(float(lower))
    usd_joint.CreateUpperLimitAttr(float(upper))
    usd_joint.CreateBody0Rel().SetTargets([body_paths[joint.parent]])
    usd_joint.CreateBody1Rel().SetTargets([body_paths[joint.child]])
    position, rotation = _pos_rot(joint.T_parent_joint)
    usd_joint.CreateLocalPos0Attr(position)
    usd_joint.CreateLocalRot0Attr(rotation)
    usd_joint.CreateLocalPos1Attr(Gf.Vec3f(0.0, 0.0, 0.0))
    usd_joint.CreateLocalRot1Attr(Gf.Quatf(1.0, Gf.Vec3f(0.0, 0.0, 0.0)))
    # A drive with zero stiffness is a viscous damper; USD angular drive gains are per degree.
    drive = UsdPhysics.DriveAPI.Apply(usd_joint.GetPrim(), "angular" if revolute else "linear")
    drive.CreateTypeAttr("force")
    drive.CreateStiffnessAttr(0.0)
    drive.CreateDampingAttr(float(joint.damping * (math.pi / 180.0 if revolute else 1.0)))
    drive.CreateMaxForceAttr(float(joint.effort))
    prim = usd_joint.GetPrim()
    velocity = math.degrees(joint.velocity) if revolute else joint.velocity
    prim.CreateAttribute(MAX_VELOCITY_ATTR, Sdf.ValueTypeNames.Float).Set(float(velocity))
    prim.CreateAttribute(FRICTION_ATTR, Sdf.ValueTypeNames.Float).Set(float(joint.friction))


def _pos_rot(T_a_b: FloatArray) -> tuple[Gf.Vec3f, Gf.Quatf]:
    """(localPos, localRot) of frame b in frame a, as UsdPhysics joint attributes."""
    quat_xyzw = Rotation.from_matrix(T_a_b[:3, :3]).as_quat()
    return (
        Gf.Vec3f(*map(float, T_a_b[:3, 3])),
        Gf.Quatf(float(quat_xyzw[3]), Gf.Vec3f(*map(float, quat_xyzw[:3]))),
    )


__all__ = ["FRICTION_ATTR", "MAX_VELOCITY_ATTR", "write_usd"]
