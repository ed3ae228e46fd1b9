"""Plain data describing a procedural scene: bodies, geoms, materials, lights and the parts
that move; ``mjcf.py`` turns it into MuJoCo XML.

Frames: the scene frame is the MuJoCo world frame (metres, z up). The room floor is z = 0,
the furniture rows stand against the back wall at +y and their fronts face -y.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from funrec.typed import UInt8Array

Vec3 = tuple[float, float, float]
"""A 3-vector as a tuple of floats (hashable, so frozen dataclasses stay comparable)."""

SEE_THROUGH_GROUP = 3
"""Geom group of clear glass: drawn in the colour image, but left out of the depth and label
pass, so depth and ground-truth masks show the surface behind the pane (as a structured-light
or time-of-flight sensor reads through clear glass), never a label without its depth."""
GEOM_SHAPES = ("box", "cylinder", "capsule", "sphere", "mesh")
"""Geom shapes the MJCF writer understands; textured boxes become meshes with UV coordinates;
"mesh" is a triangle mesh file of :attr:`Scene.mesh_files` (third-party assets)."""
PART_KINDS = (
    "door",
    "double_door",
    "wall_door",
    "wall_double_door",
    "drawer",
    "fridge_door",
    "microwave_door",
    "oven_door",
    "dishwasher_door",
    "sliding_door",
    "mw_drawer",
    "mw_door",
    "mw_window",
    "mw_window_horiz",
)
"""Kinds of articulated fronts the furniture builders make (``mw_*``: Meta-World assets, see ``assets.py``)."""
PRISMATIC_KINDS = ("drawer", "sliding_door", "mw_drawer", "mw_window", "mw_window_horiz")
"""Part kinds on a slide joint."""
JOINT_TYPE_OF_KIND = {kind: "prismatic" if kind in PRISMATIC_KINDS else "revolute" for kind in PART_KINDS}
"""Joint type ("revolute" or "prismatic") of each front kind."""


def vec3(values: npt.ArrayLike) -> Vec3:
    """Convert anything of three numbers to a :data:`Vec3`."""
    x, y, z = (float(v) for v in np.asarray(values, dtype=np.float64).reshape(3))
    return (x, y, z)


@dataclass(frozen=True)
class Texture:
    """A procedural RGB texture image, written as ``textures/<name>.png`` beside scene.xml."""

    name: str
    """Texture (and file stem) name, unique in the scene."""
    image: UInt8Array
    """(S, S, 3) uint8 RGB texels; tiles seamlessly."""


@dataclass(frozen=True)
class Material:
    """Surface appearance of geoms."""

    name: str
    """Material name, unique in the scene."""
    rgba: tuple[float, float, float, float]
    """Colour (multiplies the texture when there is one), each in [0, 1]."""
    texture: str | None = None
    """Name of a :class:`Texture`, or None for a plain colour."""
    tile_m: float = 1.0
    """Side of one texture repeat on a surface, metres (textured boxes only)."""
    specular: float = 0.15
    """MuJoCo specular reflectance in [0, 1]."""
    shininess: float = 0.2
    """MuJoCo shininess in [0, 1]."""


@dataclass(frozen=True)
class Geom:
    """One visual and collision primitive, placed in its body's frame."""

    shape: str
    """One of :data:`GEOM_SHAPES`."""
    size: tuple[float, ...]
    """MuJoCo size: box (3,) half extents; cylinder and capsule (radius, half length); sphere (radius,). Metres."""
    pos: Vec3
    """Centre in the body frame, metres."""
    material: str
    """Name of a :class:`Material`."""
    zaxis: Vec3 = (0.0, 0.0, 1.0)
    """Axis of a cylinder or capsule in the body frame (boxes are always axis-aligned)."""
    group: int = 0
    """MuJoCo geom group; :data:`SEE_THROUGH_GROUP` marks glass that the depth sensor sees through."""
    mesh: str = ""
    """Mesh geoms: path of the mesh file in :attr:`Scene.mesh_files`; ``size`` is then the
    (3,) scale applied to the file's vertices."""
    euler: Vec3 = (0.0, 0.0, 0.0)
    """Orientation in the body frame as MuJoCo xyz Euler angles, radians (third-party assets;
    overrides ``zaxis`` when non-zero)."""

    def __post_init__(self) -> None:
        if self.shape not in GEOM_SHAPES:
            raise ValueError(f"geom shape must be one of {GEOM_SHAPES}, got {self.shape!r}")
        if (self.shape == "mesh") != bool(self.mesh):
            raise ValueError(f"a mesh geom needs a mesh file and only a mesh geom has one, got {self.shape!r}, {self.mesh!r}")
        expected = {"box": 3, "cylinder": 2, "capsule": 2, "sphere": 1, "mesh": 3}[self.shape]
        if len(self.size) != expected or min(self.size) <= 0.0:
            raise ValueError(f"{self.shape} needs {expected} positive sizes, got {self.size}")


def box(lo: npt.ArrayLike, hi: npt.ArrayLike, material: str) -> Geom:
    """An axis-aligned box from its corners ``lo`` and ``hi`` (body frame, metres)."""
    lo_arr = np.asarray(lo, dtype=np.float64)
    hi_arr = np.asarray(hi, dtype=np.float64)
    return Geom("box", vec3(np.abs(hi_arr - lo_arr) / 2.0), vec3((lo_arr + hi_arr) / 2.0), material)


def rod(start: npt.ArrayLike, end: npt.ArrayLike, radius: float, material: str, shape: str = "cylinder") -> Geom:
    """A cylinder (or capsule) between two points of the body frame."""
    start_arr = np.asarray(start, dtype=np.float64)
    end_arr = np.asarray(end, dtype=np.float64)
    length = float(np.linalg.norm(end_arr - start_arr))
    return Geom(
        shape, (radius, length / 2.0), vec3((start_arr + end_arr) / 2.0), material, vec3((end_arr - start_arr) / length)
    )


def shift(geoms: tuple[Geom, ...], offset: npt.ArrayLike) -> tuple[Geom, ...]:
    """The same geoms translated by ``offset`` (re-expresses them in a frame whose origin is -offset)."""
    delta = np.asarray(offset, dtype=np.float64)
    return tuple(replace(g, pos=vec3(np.asarray(g.pos) + delta)) for g in geoms)


@dataclass(frozen=True)
class Joint:
    """A joint at the origin of its body."""

    name: str
    """Joint name; ground-truth parts are named part_0, part_1, ..."""
    kind: str
    """"hinge" (revolute) or "slide" (prismatic)."""
    axis: Vec3
    """Unit axis in the body frame; positive motion opens the part."""
    range: tuple[float, float]
    """Joint limits (closed = 0), radians or metres."""


@dataclass(frozen=True)
class Body:
    """A rigid body: a static furniture unit, or a moving front when it has a joint."""

    name: str
    """Body name, unique in the scene."""
    pos: Vec3
    """Origin in the parent frame, metres (rotated relative to the parent only by ``yaw``)."""
    geoms: tuple[Geom, ...] = ()
    """Geoms in this body's frame."""
    bodies: tuple[Body, ...] = ()
    """Child bodies."""
    joint: Joint | None = None
    """Joint connecting the body to its parent; None welds it."""
    sites: tuple[tuple[str, Vec3], ...] = ()
    """Named points (name, position in the body frame), e.g. handle centres; not rendered."""
    yaw: float = 0.0
    """Rotation about the parent's z axis, radians (only a free-standing or angled furniture row
    uses it; everything below it is axis-aligned in the row frame)."""
    touches_parent: bool = True
    """False: no contacts between this body and its parent. A third-party moving part sits inside its
    carcass's mesh, and MuJoCo collides a mesh as its convex hull: the hull of Meta-World's drawer case
    holds the drawer (0.41 m deep), which then cannot move."""


@dataclass(frozen=True)
class Front:
    """An articulable front (door, drawer, ...) made by a furniture builder.

    It becomes a ground-truth part when an interaction targets it; otherwise its joint is
    removed and it stays closed and static.
    """

    kind: str
    """One of :data:`PART_KINDS`."""
    body: str
    """Name of the :class:`Body` that carries the front."""
    joint: str
    """Provisional joint name given by the builder."""
    handle_site: str
    """Name of the site at the handle centre (on the front's body)."""
    grip_axis: Vec3
    """Direction the fingers wrap around (along the handle bar), body frame."""
    details: dict[str, str | float] = field(default_factory=dict, compare=False)
    """Descriptive facts written to gt.json (furniture, hinge side, handle shape, size)."""
    panel: tuple[Vec3, Vec3] | None = field(default=None, compare=False)
    """(centre, half extents) of the front's panel in its body frame when its first geom is
    not a box (a mesh of a third-party asset); None: the first geom is the panel."""


@dataclass(frozen=True)
class Light:
    """A light in the scene frame."""

    name: str
    """Light name."""
    kind: str
    """"spot" or "directional"."""
    pos: Vec3
    """Position, metres."""
    dir: Vec3
    """Direction the light points to."""
    diffuse: Vec3
    """Diffuse RGB intensity."""
    cast_shadow: bool = False
    """Whether the light casts shadows (costly; one light does)."""
    cutoff_deg: float = 80.0
    """Spot cone half angle, degrees."""
    attenuation: Vec3 = (1.0, 0.0, 0.0)
    """Constant, linear and quadratic attenuation."""


@dataclass(frozen=True)
class Scene:
    """Everything needed to write scene.xml, plus the bookkeeping of the articulable fronts."""

    bodies: tuple[Body, ...]
    """Top-level bodies (children of the MuJoCo world body)."""
    materials: tuple[Material, ...]
    """All materials used by geoms."""
    textures: tuple[Texture, ...]
    """All textures used by materials."""
    lights: tuple[Light, ...]
    """Scene lights."""
    fronts: tuple[Front, ...]
    """Every articulable front; ground-truth parts are chosen among them."""
    walk_area: tuple[float, float, float, float]
    """Free floor rectangle (x_min, x_max, y_min, y_max) the camera may walk in, metres."""
    ambient: float = 0.25
    """Head-light ambient intensity (fill light), in [0, 1]."""
    description: dict[str, str | float] = field(default_factory=dict, compare=False)
    """Descriptive facts written to gt.json (room size, family)."""
    mesh_files: tuple[tuple[str, bytes], ...] = field(default=(), compare=False)
    """(path relative to scene.xml, file contents) of the meshes that mesh geoms use."""


def map_bodies(bodies: tuple[Body, ...], joint_names: dict[str, str]) -> tuple[Body, ...]:
    """Rename the joints listed in ``joint_names`` (old -> new) and weld every other jointed body.

    Args:
        bodies: body trees.
        joint_names: provisional joint name -> final name, for the fronts that move.

    Returns:
        New body trees; only the listed joints remain.
    """
    out = []
    for body in bodies:
        joint = body.joint
        if joint is not None:
            joint = replace(joint, name=joint_names[joint.name]) if joint.name in joint_names else None
        out.append(replace(body, joint=joint, bodies=map_bodies(body.bodies, joint_names)))
    return tuple(out)


__all__ = [
    "GEOM_SHAPES",
    "SEE_THROUGH_GROUP",
    "JOINT_TYPE_OF_KIND",
    "PART_KINDS",
    "PRISMATIC_KINDS",
    "Body",
    "Front",
    "Geom",
    "Joint",
    "Light",
    "Material",
    "Scene",
    "Texture",
    "Vec3",
    "box",
    "map_bodies",
    "rod",
    "shift",
    "vec3",
]
