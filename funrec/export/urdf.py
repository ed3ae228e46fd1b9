"""twin.urdf: the twin as a fixed-base URDF robot, built and written through yourdfpy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yourdfpy

from funrec.errors import ExportError
from funrec.export.sim_model import MeshFiles, SimJoint, SimLink, SimModel
from funrec.geometry.transforms import make_transform

URDF_JOINT_TYPES = {"revolute": "revolute", "prismatic": "prismatic"}
"""FunREC joint type -> URDF joint type."""
WORLD_LINK = "world"
"""The massless root link; loaders that fix a massless root (pybullet, Isaac Lab, Gazebo) keep the
twin where it is without a ``useFixedBase`` flag."""
WORLD_JOINT = "world_to_static"
"""The fixed joint from WORLD_LINK to the static link."""


def build_urdf(model: SimModel, mesh_files: MeshFiles) -> yourdfpy.URDF:
    """The model as a yourdfpy URDF object (no meshes loaded).

    Args:
        model: the simulator-neutral model.
        mesh_files: mesh paths relative to the folder the URDF is written to.

    Returns:
        A yourdfpy.URDF whose links and joints mirror ``model``.
    """
    links = [yourdfpy.Link(name=WORLD_LINK), *(_link(link, mesh_files) for link in (model.base, *model.parts))]
    world = yourdfpy.Joint(name=WORLD_JOINT, type="fixed", parent=WORLD_LINK, child=model.base.name, origin=np.eye(4))
    joints = [world, *(_joint(joint) for joint in model.joints)]
    robot = yourdfpy.Robot(name=model.name, links=links, joints=joints)
    return yourdfpy.URDF(
        robot=robot,
        build_scene_graph=False,
        load_meshes=False,
        filename_handler=yourdfpy.filename_handler_null,
    )


def write_urdf(model: SimModel, mesh_files: MeshFiles, path: str | Path) -> Path:
    """Write twin.urdf.

    Links: "world" (massless, the root), "static" (the base, fixed to "world" by the joint
    "world_to_static"; its frame is the export frame) and one per part whose frame is the part's
    joint frame at the canonical state (see :class:`~funrec.export.sim_model.SimModel`). Every
    link but "world" has an <inertial>. Each joint is named as its part, with axis (0, 0, 1), its
    origin at the part's link frame, damping and Coulomb friction in <dynamics>, so ``q = s``
    puts the part where the joint transform of articulation.json puts it. Meshes are referenced
    by paths relative to the URDF.

    Args:
        model: the simulator-neutral model.
        mesh_files: mesh paths relative to the folder of ``path``.
        path: output file.

    Returns:
        ``path``.

    Raises:
        ExportError: yourdfpy rejects the model.
    """
    path = Path(path)
    urdf = build_urdf(model, mesh_files)
    if not urdf.validate():
        raise ExportError(f"{path}: yourdfpy rejects the model: {urdf.errors}")
    urdf.write_xml_file(str(path))
    return path


def _mesh_geometry(filename: str) -> yourdfpy.Geometry:
    return yourdfpy.Geometry(mesh=yourdfpy.Mesh(filename=filename))


def _link(link: SimLink, mesh_files: MeshFiles) -> yourdfpy.Link:
    visuals = []
    if link.name in mesh_files.visual:
        visuals.append(
            yourdfpy.Visual(
                name=f"{link.name}_visual", origin=np.eye(4), geometry=_mesh_geometry(mesh_files.visual[link.name])
            )
        )
    collisions = [
        yourdfpy.Collision(name=f"{link.name}_collision_{i:03d}", origin=np.eye(4), geometry=_mesh_geometry(filename))
        for i, filename in enumerate(mesh_files.collision.get(link.name, ()))
    ]
    inertial = yourdfpy.Inertial(
        origin=make_transform(np.eye(3), link.mass.com_link),
        mass=float(link.mass.mass_kg),
        inertia=np.asarray(link.mass.inertia_link, dtype=np.float64),
    )
    return yourdfpy.Link(name=link.name, inertial=inertial, visuals=visuals, collisions=collisions)


def _joint(joint: SimJoint) -> yourdfpy.Joint:
    return yourdfpy.Joint(
        name=joint.name,
        type=URDF_JOINT_TYPES[joint.joint_type],
        parent=joint.parent,
        child=joint.child,
        origin=np.asarray(joint.T_parent_joint, dtype=np.float64),
        axis=np.array([0.0, 0.0, 1.0]),
        dynamics=yourdfpy.Dynamics(damping=float(joint.damping), friction=float(joint.friction)),
        limit=yourdfpy.Limit(
            effort=float(joint.effort),
            velocity=float(joint.velocity),
            lower=float(joint.lower),
            upper=float(joint.upper),
        ),
    )


__all__ = ["WORLD_JOINT", "WORLD_LINK", "build_urdf", "write_urdf"]
