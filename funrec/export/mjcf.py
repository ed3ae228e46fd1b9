"""twin.xml: the twin as a MuJoCo MJCF model (angles in radians, z up in the export frame)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from funrec.export.sim_model import MeshFiles, SimJoint, SimLink, SimModel

MESH_DIR = "meshes"
"""compiler meshdir, relative to twin.xml; mesh files are named relative to it."""
MJCF_JOINT_TYPES = {"revolute": "hinge", "prismatic": "slide"}
"""FunREC joint type -> MJCF joint type."""
VISUAL_GROUP = 2
"""Geom group of visual meshes (MuJoCo's viewer shows groups 0-2 by default)."""
COLLISION_GROUP = 3
"""Geom group of collision pieces (hidden by default in the viewer)."""
FRICTION_SOLIMP = "0.9999 0.9999 0.001 0.5 2"
"""solimpfriction of every joint. MuJoCo's dry friction is a soft constraint: under a constant
load it lets the joint creep at about load/mass * (1-d)/d / b (d the impedance, b about
2/timeconst), 1.4 mm in 2 s for a drawer on a 5 degree slope at MuJoCo's default d = 0.9. At
d = 0.9999 the creep is a thousand times slower and the joint holds as a real hinge does; the
friction force stays bounded by frictionloss, so a robot still moves the part with that force."""
VISUAL_RGBA = "0.75 0.72 0.68 1"
"""Colour of visual meshes; MuJoCo ignores the scan's vertex colours."""


def mjcf_string(model: SimModel, mesh_files: MeshFiles) -> str:
    """The MJCF XML text of a model.

    The body "static" (no joint, so welded to the world) holds the static scene; each part is a
    child body named as the part, placed at its link frame (see
    :class:`~funrec.export.sim_model.SimModel`), with a hinge or slide joint of the same name
    along its local +z (damping, and Coulomb friction as ``frictionloss``), so ``qpos = s`` is the joint transform of articulation.json at state s
    and ``qpos = 0`` the canonical state. Visual geoms (group 2) do not collide; collision geoms
    (group 3) are the convex pieces. Contacts between a part and the static body are excluded:
    the part is built inside its frame (a door in its cabinet) and its joint range keeps it there.

    Args:
        model: the simulator-neutral model.
        mesh_files: mesh paths relative to the folder twin.xml is written to; all must lie
            under MESH_DIR.

    Returns:
        The XML document.
    """
    root = ET.Element("mujoco", model=model.name)
    ET.SubElement(root, "compiler", angle="radian", meshdir=MESH_DIR, autolimits="true")
    defaults = ET.SubElement(root, "default")
    visual = ET.SubElement(defaults, "default", {"class": "visual"})
    ET.SubElement(
        visual,
        "geom",
        type="mesh",
        contype="0",
        conaffinity="0",
        group=str(VISUAL_GROUP),
        density="0",
        rgba=VISUAL_RGBA,
    )
    collision = ET.SubElement(defaults, "default", {"class": "collision"})
    ET.SubElement(collision, "geom", type="mesh", group=str(COLLISION_GROUP))
    asset = ET.SubElement(root, "asset")
    worldbody = ET.SubElement(root, "worldbody")
    static = ET.SubElement(worldbody, "body", name=model.base.name)
    _add_inertial(static, model.base)
    _add_geoms(static, asset, model.base, mesh_files)
    for link, joint in zip(model.parts, model.joints):
        _add_part(static, asset, link, joint, mesh_files)
    if model.parts:
        contact = ET.SubElement(root, "contact")
        for link in model.parts:
            ET.SubElement(contact, "exclude", body1=model.base.name, body2=link.name)
    ET.indent(root)
    return ET.tostring(root, encoding="unicode") + "\n"


def write_mjcf(model: SimModel, mesh_files: MeshFiles, path: str | Path) -> Path:
    """Write twin.xml next to the mesh folder.

    Args:
        model: the simulator-neutral model.
        mesh_files: mesh paths relative to the folder of ``path``.
        path: output file.

    Returns:
        ``path``.
    """
    path = Path(path)
    path.write_text(mjcf_string(model, mesh_files))
    return path


def _numbers(values: np.ndarray) -> str:
    """Space-separated shortest round-trip decimals."""
    return " ".join(repr(float(v)) for v in np.ravel(values))


def _mesh_file(relative: str) -> str:
    prefix = f"{MESH_DIR}/"
    assert relative.startswith(prefix), relative
    return relative[len(prefix) :]


def _add_geoms(body: ET.Element, asset: ET.Element, link: SimLink, mesh_files: MeshFiles) -> None:
    if link.name in mesh_files.visual:
        name = f"{link.name}_visual"
        # A scan is an open surface: "shell" inertia avoids MuJoCo's volume check on it (the
        # visual geom has density 0 and no say in the body's mass anyway).
        ET.SubElement(asset, "mesh", name=name, file=_mesh_file(mesh_files.visual[link.name]), inertia="shell")
        ET.SubElement(body, "geom", {"class": "visual", "name": name, "mesh": name})
    for i, relative in enumerate(mesh_files.collision.get(link.name, ())):
        name = f"{link.name}_collision_{i:03d}"
        ET.SubElement(asset, "mesh", name=name, file=_mesh_file(relative))
        ET.SubElement(body, "geom", {"class": "collision", "name": name, "mesh": name})


def _add_inertial(body: ET.Element, link: SimLink) -> None:
    I = link.mass.inertia_link  # noqa: E741 - the usual symbol of an inertia tensor
    ET.SubElement(
        body,
        "inertial",
        pos=_numbers(link.mass.com_link),
        mass=repr(float(link.mass.mass_kg)),
        fullinertia=_numbers([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]),
    )


def _add_part(parent: ET.Element, asset: ET.Element, link: SimLink, joint: SimJoint, mesh_files: MeshFiles) -> None:
    T_parent_part = joint.T_parent_joint
    quat_xyzw = Rotation.from_matrix(T_parent_part[:3, :3]).as_quat()
    quat_wxyz = np.roll(quat_xyzw, 1)
    body = ET.SubElement(parent, "body", name=link.name, pos=_numbers(T_parent_part[:3, 3]), quat=_numbers(quat_wxyz))
    _add_inertial(body, link)
    ET.SubElement(
        body,
        "joint",
        name=joint.name,
        type=MJCF_JOINT_TYPES[joint.joint_type],
        pos="0 0 0",
        axis="0 0 1",
        limited="true",
        range=_numbers([joint.lower, joint.upper]),
        damping=repr(float(joint.damping)),
        frictionloss=repr(float(joint.friction)),
        solimpfriction=FRICTION_SOLIMP,
        armature=repr(float(joint.armature)),
        actuatorfrcrange=_numbers([-joint.effort, joint.effort]),
    )
    _add_geoms(body, asset, link, mesh_files)


__all__ = ["mjcf_string", "write_mjcf"]
