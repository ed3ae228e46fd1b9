"""MuJoCo MJCF text of a :class:`Scene`, optionally with the render rig (ego camera and hand
proxy as mocap bodies).

Textured boxes are written as inline meshes with explicit texture coordinates so every face
gets the same texel density (MuJoCo's own box mapping stretches 2D textures per face), and
their faces are subdivided because MuJoCo lights per vertex.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from funrec.synth.scene import Body, Geom, Material, Scene
from funrec.typed import FloatArray, IntArray

LIGHTING_CELL_M = 0.25
"""Largest face subdivision of a textured box, metres; MuJoCo's per-vertex lighting needs
vertices this dense for spot lights to shade large walls smoothly."""
TEXTURE_DIR = "textures"
"""Folder beside scene.xml holding the texture PNG files."""
CAMERA_NAME = "ego"
"""Name of the ego camera in the render model."""
HAND_BODIES = ("hand", "forearm")
"""Mocap body names of the hand proxy in the render model."""


@dataclass(frozen=True)
class RenderRig:
    """What the render model adds to the scene: the camera and the hand proxy."""

    width: int
    """Image width, pixels."""
    height: int
    """Image height, pixels."""
    fovy_deg: float
    """Vertical field of view of the ego camera, degrees."""
    hand: tuple[Geom, ...]
    """Hand geoms in the grasp frame."""
    forearm: tuple[Geom, ...]
    """Forearm geoms in the forearm frame."""
    skin: Material
    """Material of the hand proxy."""


def _fmt(values: object) -> str:
    array = np.atleast_1d(np.asarray(values, dtype=np.float64))
    return " ".join(f"{v:.9g}" for v in array.ravel())


def box_mesh(half: FloatArray, offset: FloatArray, tile_m: float) -> tuple[FloatArray, FloatArray, IntArray]:
    """Vertices, texture coordinates and triangles of a subdivided box centred at the origin.

    Args:
        half: (3,) half extents, metres.
        offset: (3,) shift added before computing texture coordinates (decorrelates boxes).
        tile_m: metres per texture repeat.

    Returns:
        vertices (V, 3), texcoords (V, 2) and faces (T, 3) with outward winding.
    """
    vertices, texcoords, faces = [], [], []
    # In-plane axes per face normal: horizontal first, so textures stay upright on walls.
    planes = {0: (1, 2), 1: (0, 2), 2: (0, 1)}
    for axis in range(3):
        u_axis, v_axis = planes[axis]
        nu = max(1, math.ceil(2 * half[u_axis] / LIGHTING_CELL_M))
        nv = max(1, math.ceil(2 * half[v_axis] / LIGHTING_CELL_M))
        us, vs = np.meshgrid(
            np.linspace(-half[u_axis], half[u_axis], nu + 1),
            np.linspace(-half[v_axis], half[v_axis], nv + 1),
            indexing="ij",
        )
        for sign in (-1.0, 1.0):
            points = np.zeros((us.size, 3))
            points[:, axis] = sign * half[axis]
            points[:, u_axis] = us.ravel()
            points[:, v_axis] = vs.ravel()
            base = sum(len(v) for v in vertices)
            idx = np.arange(us.size).reshape(nu + 1, nv + 1) + base
            a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
            normal_along = np.cross(np.eye(3)[u_axis], np.eye(3)[v_axis])[axis] * sign
            tris = (
                np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
                if normal_along > 0
                else np.concatenate([np.stack([a, c, b], 1), np.stack([a, d, c], 1)])
            )
            vertices.append(points)
            texcoords.append((points[:, [u_axis, v_axis]] + offset[[u_axis, v_axis]]) / tile_m)
            faces.append(tris)
    return np.concatenate(vertices), np.concatenate(texcoords), np.concatenate(faces).astype(np.int64)


class _Writer:
    """Accumulates assets while walking the body tree."""

    def __init__(self, materials: dict[str, Material]) -> None:
        self.materials = materials
        self.meshes: list[ET.Element] = []
        self.excluded: list[tuple[str, str]] = []

    def geom(self, parent: ET.Element, geom: Geom, name: str, extra: dict[str, str] | None = None) -> None:
        attrs = {"name": name, "pos": _fmt(geom.pos), "material": geom.material}
        material = self.materials[geom.material]
        if geom.shape == "box" and material.texture is not None:
            half = np.asarray(geom.size)
            vertices, texcoords, faces = box_mesh(half, np.asarray(geom.pos) + len(self.meshes) * 0.37, material.tile_m)
            mesh = f"mesh_{len(self.meshes)}"
            self.meshes.append(
                ET.Element(
                    "mesh",
                    {
                        "name": mesh,
                        "vertex": _fmt(vertices),
                        "texcoord": _fmt(texcoords),
                        "face": " ".join(str(i) for i in faces.ravel()),
                    },
                )
            )
            attrs.update({"type": "mesh", "mesh": mesh})
        elif geom.shape == "mesh":
            mesh = f"mesh_{len(self.meshes)}"
            # Mass from the mesh's own volume, not its convex hull's (Meta-World's hollow drawer weighed 80 kg).
            self.meshes.append(
                ET.Element("mesh", {"name": mesh, "file": geom.mesh, "scale": _fmt(geom.size), "inertia": "exact"})
            )
            attrs.update({"type": "mesh", "mesh": mesh})
        else:
            attrs.update({"type": geom.shape, "size": _fmt(geom.size)})
            if geom.shape in ("cylinder", "capsule") and not any(geom.euler):
                attrs["zaxis"] = _fmt(geom.zaxis)
        if any(geom.euler):
            attrs["euler"] = _fmt(geom.euler)
        if geom.group:
            attrs["group"] = str(geom.group)
        attrs.update(extra or {})
        ET.SubElement(parent, "geom", attrs)

    def body(self, parent: ET.Element, body: Body) -> None:
        element = ET.SubElement(parent, "body", {"name": body.name, "pos": _fmt(body.pos)})
        if not body.touches_parent:
            self.excluded.append((parent.get("name", "world"), body.name))
        if body.yaw:
            element.set("euler", _fmt([0.0, 0.0, body.yaw]))
        if body.joint is not None:
            joint = body.joint
            ET.SubElement(
                element,
                "joint",
                {
                    "name": joint.name,
                    "type": joint.kind,
                    "axis": _fmt(joint.axis),
                    "range": _fmt(joint.range),
                    "limited": "true",
                    "damping": "1",
                    "armature": "0.01",
                },
            )
        for k, geom in enumerate(body.geoms):
            self.geom(element, geom, f"{body.name}_g{k}")
        for name, pos in body.sites:
            ET.SubElement(element, "site", {"name": name, "pos": _fmt(pos), "size": "0.01", "group": "4"})
        for child in body.bodies:
            self.body(element, child)


def scene_to_mjcf(scene: Scene, rig: RenderRig | None = None, model_name: str = "funrec_synth") -> str:
    """MJCF text of the scene (z up, radians); textures are read from ``textures/<name>.png``
    relative to the XML file.

    Args:
        scene: the scene.
        rig: adds the ego camera and the hand proxy as mocap bodies when given.
        model_name: the model name attribute.

    Returns:
        The XML document as a string.
    """
    materials = {m.name: m for m in scene.materials}
    if rig is not None:
        materials[rig.skin.name] = rig.skin
    root = ET.Element("mujoco", {"model": model_name})
    ET.SubElement(root, "compiler", {"angle": "radian"})
    visual = ET.SubElement(root, "visual")
    ambient = _fmt([scene.ambient] * 3)
    ET.SubElement(
        visual,
        "headlight",
        {"ambient": ambient, "diffuse": _fmt([scene.ambient * 0.6] * 3), "specular": "0.05 0.05 0.05"},
    )
    if rig is None:
        ET.SubElement(visual, "quality", {"shadowsize": "2048", "offsamples": "4"})
    else:
        # No multisampling and a smaller shadow map make CPU rendering 3x faster; the sensor
        # model's optical blur replaces the anti-aliasing.
        ET.SubElement(visual, "quality", {"shadowsize": "1024", "offsamples": "0"})
        ET.SubElement(visual, "global", {"offwidth": str(rig.width), "offheight": str(rig.height)})
    ET.SubElement(root, "default").append(ET.Element("geom", {"density": "500"}))
    asset = ET.SubElement(root, "asset")
    for texture in scene.textures:
        ET.SubElement(
            asset, "texture", {"name": texture.name, "type": "2d", "file": f"{TEXTURE_DIR}/{texture.name}.png"}
        )
    for material in materials.values():
        attrs = {
            "name": material.name,
            "rgba": _fmt(material.rgba),
            "specular": _fmt(material.specular),
            "shininess": _fmt(material.shininess),
        }
        if material.texture is not None:
            attrs["texture"] = material.texture
        ET.SubElement(asset, "material", attrs)
    world = ET.SubElement(root, "worldbody")
    for light in scene.lights:
        ET.SubElement(
            world,
            "light",
            {
                "name": light.name,
                "type": light.kind,
                "pos": _fmt(light.pos),
                "dir": _fmt(light.dir),
                "diffuse": _fmt(light.diffuse),
                "specular": "0.15 0.15 0.15",
                "castshadow": str(light.cast_shadow).lower(),
                "cutoff": _fmt(light.cutoff_deg),
                "attenuation": _fmt(light.attenuation),
            },
        )
    writer = _Writer(materials)
    for body in scene.bodies:
        writer.body(world, body)
    if rig is not None:
        camera = ET.SubElement(world, "body", {"name": "camera_rig", "mocap": "true", "pos": "0 0 1.5"})
        ET.SubElement(camera, "camera", {"name": CAMERA_NAME, "fovy": repr(float(rig.fovy_deg))})
        no_contact = {"contype": "0", "conaffinity": "0"}
        for name, geoms in zip(HAND_BODIES, (rig.hand, rig.forearm)):
            element = ET.SubElement(world, "body", {"name": name, "mocap": "true", "pos": "0 0 -10"})
            for k, geom in enumerate(geoms):
                writer.geom(element, geom, f"{name}_g{k}", no_contact)
    for mesh in writer.meshes:
        asset.append(mesh)
    if writer.excluded:
        contact = ET.SubElement(root, "contact")
        for body1, body2 in writer.excluded:
            ET.SubElement(contact, "exclude", {"body1": body1, "body2": body2})
    ET.indent(root)
    return ET.tostring(root, encoding="unicode") + "\n"


__all__ = ["CAMERA_NAME", "HAND_BODIES", "LIGHTING_CELL_M", "TEXTURE_DIR", "RenderRig", "box_mesh", "scene_to_mjcf"]
