"""The simulator-neutral model that twin.urdf, twin.xml and twin.usda are written from: links with
their frames, meshes and mass properties, and the joints between them."""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from funrec.geometry.transforms import invert_transform, make_transform
from funrec.typed import FloatArray

VISUAL_DIR = "meshes/visual"
"""Folder (relative to the twin folder) of the visual meshes, one OBJ per link, link frame."""
COLLISION_DIR = "meshes/collision"
"""Folder (relative to the twin folder) of the convex collision pieces, binary STL, link frame."""
OBJ_ROWS_PER_WRITE = 50_000
"""Vertex or face lines formatted per write by :func:`write_obj` (a few MB of text)."""
PRINCIPAL_AXIS_HELPER_TOL = 0.9
"""|cos| above which a world axis is too parallel to the joint axis to seed the link x axis."""


@dataclass(frozen=True)
class MassProperties:
    """Rigid-body mass properties of a link, in its link frame."""

    mass_kg: float
    """Mass (kg), > 0."""
    com_link: FloatArray
    """(3,) centre of mass, link frame, metres."""
    inertia_link: FloatArray
    """(3, 3) inertia tensor about the centre of mass, link-frame axes, kg m^2; symmetric
    positive definite."""
    volume_m3: float
    """Volume (m^3) the mass was computed from."""
    source: str
    """"mesh" (the visual mesh is watertight), "collision" (sum over the convex pieces) or
    "nominal" (a static base without pieces, see :func:`static_mass_properties`)."""

    def __post_init__(self) -> None:
        if np.shape(self.com_link) != (3,) or np.shape(self.inertia_link) != (3, 3):
            raise ValueError(
                f"com_link (3,) and inertia_link (3, 3) expected, got {np.shape(self.com_link)}, {np.shape(self.inertia_link)}"
            )

    def principal_axes(self) -> tuple[FloatArray, FloatArray]:
        """Principal moments (3,) ascending (kg m^2) and the rotation ``R_link_principal`` (3, 3),
        a proper rotation whose columns are the principal axes."""
        moments, R_link_principal = np.linalg.eigh(self.inertia_link)
        if np.linalg.det(R_link_principal) < 0.0:
            R_link_principal[:, 2] *= -1.0
        return moments, R_link_principal


@dataclass(frozen=True)
class SimLink:
    """A rigid link: the fixed static scene or one articulated part."""

    name: str
    """Link name: "static" for the base, the part name (e.g. "part_0") for a part."""
    T_export_link: FloatArray
    """(4, 4) link frame at the canonical state, in the export frame."""
    visual: trimesh.Trimesh | None
    """Visual mesh in the link frame (None when the twin has no static mesh)."""
    collision: tuple[trimesh.Trimesh, ...]
    """Convex collision pieces in the link frame."""
    mass: MassProperties
    """Mass properties. The static base is welded to the world, so its mass never acts; it has one
    anyway because URDF tools (pybullet, Isaac Lab's importer) treat a link without one as massless
    and warn or fail (see :func:`static_mass_properties`)."""

    def __post_init__(self) -> None:
        if np.shape(self.T_export_link) != (4, 4):
            raise ValueError(f"T_export_link must be (4, 4), got {np.shape(self.T_export_link)}")


@dataclass(frozen=True)
class SimJoint:
    """A one-degree-of-freedom joint; its axis is +z of its frame, which is the child link frame."""

    name: str
    """Joint name, equal to the part name (e.g. "part_0")."""
    joint_type: str
    """"revolute" or "prismatic"."""
    parent: str
    """Parent link name ("static")."""
    child: str
    """Child link name (the part)."""
    T_parent_joint: FloatArray
    """(4, 4) joint frame (= child link frame at state 0) in the parent link frame."""
    lower: float
    """Lower limit (rad or m), <= 0."""
    upper: float
    """Upper limit (rad or m), >= 0 and > lower."""
    effort: float
    """Effort limit (N m or N)."""
    velocity: float
    """Velocity limit (rad/s or m/s)."""
    damping: float
    """Viscous damping (N m s/rad or N s/m)."""
    friction: float
    """Coulomb (dry) friction of the joint (N m or N): the largest load the joint resists at
    rest. URDF ``<dynamics friction>``, MJCF ``frictionloss``, USD ``funrec:jointFriction``."""
    armature: float
    """Rotor inertia added to the joint (kg m^2 or kg); MJCF only."""


@dataclass(frozen=True)
class SimModel:
    """A fixed-base articulated model: the static link, one link per part, one joint per part.

    Frames: ``export`` is the root frame of every file (``T_export_world`` maps the twin's world
    frame into it); ``static`` is the fixed base link, equal to ``export``; ``part_k`` is the link
    of part k at its canonical state (joint state 0): its z axis is the joint axis and its origin
    lies on the axis nearest the mesh centroid (revolute) or at the mesh centroid (prismatic). The
    joint frame of part k coincides with its link frame, so every simulator reads the joint axis
    as +z and the link pose at state s is ``T_export_part(s) = T_export_part(0) @ Rz(s)``
    (revolute) or ``@ Tz(s)`` (prismatic), which equals FORMATS' joint transform
    ``T_export_world @ T(s) @ T_world_export @ T_export_part(0)``.
    """

    name: str
    """Model name (robot name in URDF, model name in MJCF, root prim in USD)."""
    base: SimLink
    """The fixed static link; its frame is the export frame."""
    parts: tuple[SimLink, ...]
    """Part links, in articulation.json order."""
    joints: tuple[SimJoint, ...]
    """joints[k] moves parts[k]."""


@dataclass(frozen=True)
class MeshFiles:
    """Mesh files written next to twin.urdf / twin.xml, paths relative to the twin folder."""

    visual: dict[str, str]
    """Link name -> visual OBJ path."""
    collision: dict[str, tuple[str, ...]]
    """Link name -> collision STL paths, one per convex piece."""


def part_link_frame(
    joint_type: str, axis_world: FloatArray, pivot_world: FloatArray | None, centroid_world: FloatArray
) -> FloatArray:
    """Link (and joint) frame of a part at its canonical state, in the world frame.

    Args:
        joint_type: "revolute" or "prismatic".
        axis_world: (3,) unit joint axis, world frame.
        pivot_world: (3,) point on the revolute axis, world frame; None if prismatic.
        centroid_world: (3,) centroid of the part mesh, world frame.

    Returns:
        (4, 4) ``T_world_part``: z along the axis; origin on the axis nearest the centroid
        (revolute) or at the centroid (prismatic).
    """
    z = np.asarray(axis_world, dtype=np.float64)
    z = z / np.linalg.norm(z)
    helper = np.eye(3)[int(np.argmin(np.abs(z)))]
    assert abs(helper @ z) < PRINCIPAL_AXIS_HELPER_TOL
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    R_world_part = np.stack([x, np.cross(z, x), z], axis=1)
    origin = np.asarray(centroid_world, dtype=np.float64)
    if joint_type == "revolute":
        assert pivot_world is not None
        pivot = np.asarray(pivot_world, dtype=np.float64)
        origin = pivot + z * float(z @ (origin - pivot))
    return make_transform(R_world_part, origin)


def mass_properties(
    visual: trimesh.Trimesh, collision: tuple[trimesh.Trimesh, ...], density_kg_m3: float
) -> MassProperties:
    """Mass, centre of mass and inertia of a link of uniform density.

    A watertight visual mesh gives the exact solid; a TSDF scan usually is an open surface, so
    otherwise the convex collision pieces (watertight by construction) are summed, counting any
    overlap between pieces twice.

    Args:
        visual: visual mesh, link frame.
        collision: convex pieces, link frame.
        density_kg_m3: density (kg/m^3).

    Returns:
        Mass properties in the link frame.
    """
    solids = [visual] if visual.is_watertight and visual.volume > 0.0 else list(collision)
    source = "mesh" if solids[0] is visual else "collision"
    volumes = np.array([s.volume for s in solids])
    coms = np.array([s.center_mass for s in solids])
    volume = float(volumes.sum())
    com = (volumes[:, None] * coms).sum(axis=0) / volume
    inertia = np.zeros((3, 3))
    for solid, v, c in zip(solids, volumes, coms):
        d = c - com
        # trimesh gives the unit-density inertia about the solid's own centre of mass;
        # the parallel-axis theorem moves it to the link's centre of mass.
        inertia += density_kg_m3 * (np.asarray(solid.moment_inertia) + v * (d @ d * np.eye(3) - np.outer(d, d)))
    return MassProperties(
        mass_kg=density_kg_m3 * volume,
        com_link=com,
        inertia_link=0.5 * (inertia + inertia.T),
        volume_m3=volume,
        source=source,
    )


STATIC_NOMINAL_MASS_KG = 1.0
"""Mass given to a static base without collision pieces (it is welded to the world)."""


def static_mass_properties(collision: tuple[trimesh.Trimesh, ...], density_kg_m3: float) -> MassProperties:
    """Mass properties of the static base: its convex pieces at ``density_kg_m3``, or a nominal
    1 kg point-like body at the origin when it has none. Only tools that insist on an inertial
    read it; the base never moves."""
    if collision:
        return mass_properties(trimesh.Trimesh(), collision, density_kg_m3)
    return MassProperties(
        mass_kg=STATIC_NOMINAL_MASS_KG,
        com_link=np.zeros(3),
        inertia_link=np.eye(3) * 1e-3,
        volume_m3=0.0,
        source="nominal",
    )


def gravity_load(link: SimLink, joint: SimJoint, gravity_export: FloatArray, samples: int = 33) -> float:
    """Largest gravity load on a joint over its range: |torque about the axis| (N m) of a revolute
    joint, |force along the axis| (N) of a prismatic one.

    Args:
        link: the part link moved by ``joint`` (its mass properties, link frame).
        joint: the joint; its frame is the link frame at state 0, axis +z.
        gravity_export: (3,) gravitational acceleration in the export frame (m/s^2).
        samples: states sampled evenly over [lower, upper].

    Returns:
        The largest load over the sampled states (N m or N).
    """
    g = np.asarray(gravity_export, dtype=np.float64)
    force_export = link.mass.mass_kg * g
    R_export_joint = joint.T_parent_joint[:3, :3]
    axis_export = R_export_joint[:, 2]
    if joint.joint_type == "prismatic":
        return abs(float(force_export @ axis_export))
    # About the axis through the joint origin: torque = ((R(s) c) x F) . a with c the centre of
    # mass in the joint frame; only the rotation about z changes with s.
    force_joint = R_export_joint.T @ force_export
    c = link.mass.com_link
    s = np.linspace(joint.lower, joint.upper, samples)
    cx = np.cos(s) * c[0] - np.sin(s) * c[1]
    cy = np.sin(s) * c[0] + np.cos(s) * c[1]
    torque_z = cx * force_joint[1] - cy * force_joint[0]
    return float(np.abs(torque_z).max())


def to_link_frame(mesh: trimesh.Trimesh, T_world_link: FloatArray) -> trimesh.Trimesh:
    """A copy of a world-frame mesh expressed in a link frame (``p_link = T_link_world p_world``)."""
    moved = mesh.copy()
    moved.apply_transform(invert_transform(T_world_link))
    return moved


def write_obj(mesh: trimesh.Trimesh, path: Path) -> None:
    """Write a triangle mesh as Wavefront OBJ: ``v x y z [r g b]`` lines (vertex colours in [0, 1]
    after the position, as trimesh, MeshLab and MuJoCo read them) and ``f i j k`` lines.

    Streamed in blocks of OBJ_ROWS_PER_WRITE lines: ``trimesh.Trimesh.export`` formats the whole
    file as one string first, which took 107 MB extra for a 417k-triangle room scan.

    Args:
        mesh: triangle mesh; its vertex colours are written when it has them.
        path: file to write.
    """
    rows = np.asarray(mesh.vertices, dtype=np.float64)
    if mesh.visual.kind == "vertex":
        rows = np.hstack([rows, np.asarray(mesh.visual.vertex_colors, dtype=np.float64)[:, :3] / 255.0])
    faces = np.asarray(mesh.faces, dtype=np.int64) + 1  # OBJ indices start at 1
    vertex_line = "v" + " %.8f" * rows.shape[1] + "\n"
    with open(path, "w") as f:
        for lines, template in ((rows, vertex_line), (faces, "f %d %d %d\n")):
            for start in range(0, len(lines), OBJ_ROWS_PER_WRITE):
                block = lines[start : start + OBJ_ROWS_PER_WRITE]
                f.write(template * len(block) % tuple(block.ravel().tolist()))


def write_mesh_files(model: SimModel, twin_dir: Path) -> MeshFiles:
    """Write every link's visual OBJ and collision STL pieces into the twin folder.

    Args:
        model: the model to write.
        twin_dir: twin folder; files go to VISUAL_DIR and COLLISION_DIR inside it, which are
            emptied first.

    Returns:
        The relative paths written.
    """
    for folder in (VISUAL_DIR, COLLISION_DIR):
        # Both folders belong to the exports: clear pieces left by an earlier export.
        shutil.rmtree(twin_dir / folder, ignore_errors=True)
        (twin_dir / folder).mkdir(parents=True)
    visual: dict[str, str] = {}
    collision: dict[str, tuple[str, ...]] = {}
    for link in (model.base, *model.parts):
        if link.visual is not None:
            visual[link.name] = f"{VISUAL_DIR}/{link.name}.obj"
            write_obj(link.visual, twin_dir / visual[link.name])
        paths = tuple(f"{COLLISION_DIR}/{link.name}_{i:03d}.stl" for i in range(len(link.collision)))
        for path, piece in zip(paths, link.collision):
            piece.export(twin_dir / path, file_type="stl")
        collision[link.name] = paths
    return MeshFiles(visual=visual, collision=collision)


__all__ = [
    "COLLISION_DIR",
    "VISUAL_DIR",
    "MassProperties",
    "MeshFiles",
    "SimJoint",
    "SimLink",
    "SimModel",
    "gravity_load",
    "mass_properties",
    "part_link_frame",
    "static_mass_properties",
    "to_link_frame",
    "write_mesh_files",
    "write_obj",
]
