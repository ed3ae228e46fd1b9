"""Simulation exports of a twin folder: twin.urdf, twin.xml (MuJoCo) and twin.usda (USD physics),
all written from one :class:`~funrec.export.sim_model.SimModel` built here from articulation.json
and the meshes (FORMATS.md section 2)."""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from funrec.errors import ExportError, FormatError
from funrec.export.axis_snap import snap_axis
from funrec.export.collision import CollisionConfig, decompose
from funrec.export.glb import write_glb
from funrec.export.mjcf import write_mjcf
from funrec.export.sim_model import (
    MeshFiles,
    SimJoint,
    SimLink,
    SimModel,
    gravity_load,
    mass_properties,
    part_link_frame,
    static_mass_properties,
    to_link_frame,
    write_mesh_files,
)
from funrec.export.urdf import write_urdf
from funrec.formats.twin import ArticulatedPart, TwinArticulation, read_articulation
from funrec.geometry.transforms import check_transform
from funrec.typed import FloatArray

log = logging.getLogger(__name__)

EXPORT_FORMATS = ("urdf", "mjcf", "usd", "glb")
"""Files export_simulation can write: twin.urdf, twin.xml, twin.usda and twin.glb (the meshes as
binary glTF for viewers, no physics)."""
URDF_NAME, MJCF_NAME, USD_NAME, GLB_NAME = "twin.urdf", "twin.xml", "twin.usda", "twin.glb"
"""File names inside the twin folder (FORMATS.md section 2)."""
USD_BINARY_NAME = "twin.usdc"
"""The USD export's name when ExportConfig.usd_binary asks for binary USD (crate)."""
GRAVITY_EXPORT_M_S2 = (0.0, 0.0, -9.81)
"""Gravity in the export frame: the twin's world frame is gravity-aligned with z up (funrec.surfaces.gravity),
as are the frames the simulators put the files in."""


@dataclass(frozen=True)
class InMemoryTwin:
    """A twin folder's contents as the pipeline holds them: the export needs not read back what was just written."""

    articulation: TwinArticulation
    """articulation.json."""
    meshes: dict[str, trimesh.Trimesh]
    """Meshes by their path relative to the twin folder (``meshes/static.ply``), with the vertices
    the PLY files hold (float32, as trimesh writes them): a later ``funrec export TWIN`` of the folder
    then builds the same model."""


@dataclass(frozen=True)
class ExportConfig:
    """Physical defaults and geometry settings of the simulation exports."""

    density_kg_m3: float = 600.0
    """Density of every part (kg/m^3); 600 is particle board / MDF, what most cabinet doors and
    drawer fronts are made of."""
    part_densities: tuple[tuple[str, float], ...] = ()
    """Per-part density overrides, (part name, kg/m^3) pairs, e.g. (("part_1", 2500.0),) for a
    glass door."""
    revolute_effort_nm: float = 50.0
    """Effort limit of revolute joints (N m); URDF needs one, a passive hinge has no motor."""
    prismatic_effort_n: float = 100.0
    """Effort limit of prismatic joints (N)."""
    revolute_velocity_rad_s: float = 3.0
    """Velocity limit of revolute joints (rad/s), about a door flung open by hand."""
    prismatic_velocity_m_s: float = 1.0
    """Velocity limit of prismatic joints (m/s)."""
    revolute_damping: float = 0.2
    """Viscous damping of revolute joints (N m s/rad); a 1 kg door slows within about a second."""
    prismatic_damping: float = 2.0
    """Viscous damping of prismatic joints (N s/m)."""
    revolute_friction_nm: float = 0.3
    """Least Coulomb friction of revolute joints (N m): what a cabinet hinge takes to start turning."""
    prismatic_friction_n: float = 3.0
    """Least Coulomb friction of prismatic joints (N): what a drawer runner takes to start sliding."""
    friction_gravity_margin: float = 1.5
    """Each joint's friction is at least this multiple of the largest gravity load on it over its
    range (torque about the axis, or force along it), so a passive part stays where it is put. An
    axis estimated a few degrees off vertical (a door) or off horizontal (a drawer) makes gravity
    pull the part; a real hinge or runner holds such a part by friction, and a stiff spring would
    fight a robot that moves it. 0 keeps only the least friction above."""
    armature: float = 0.01
    """Armature of every joint (kg m^2 or kg), MJCF only; keeps light parts numerically stable."""
    T_export_world: tuple[tuple[float, ...], ...] | None = None
    """(4, 4) row-major transform from the twin's world frame to the frame of the exported files
    (e.g. a gravity-aligned frame with z up); None is the identity."""
    formats: tuple[str, ...] = EXPORT_FORMATS
    """Which files to write, a subset of ("urdf", "mjcf", "usd", "glb")."""
    snap_axis_deg: float = 0.0
    """Snap a joint axis within this many degrees of vertical (gravity) or of the floor plane to it
    in the exported files (articulation.json keeps the estimate), so a door hinge estimated a few
    degrees off vertical does not swing under gravity. 0 (the default) snaps nothing: on the two
    smoke twins measured a 6 degree snap (applied to articulation.json for scoring) cut the axis
    error from 5.35 to 0.20 degrees (smoke_rev_00, ADD 82.6 -> 94.1 %) and from 0.88 to 0.28
    degrees (smoke_pri_00, ADD 96.9 -> 98.8 %), but the bench and the robot checks were not run
    with it, and a slanted real hinge would be snapped wrongly."""
    usd_binary: bool = False
    """Write the USD export as binary twin.usdc (about a third of the size, faster to load) instead
    of text twin.usda. Text stays the default: it is the file FORMATS.md names, and a user can
    read and diff it."""
    model_name: str = "twin"
    """Model name inside the files (URDF robot, MJCF model, USD root prim)."""
    collision: CollisionConfig = field(default_factory=CollisionConfig)
    """Convex decomposition of the static scene and of the parts."""

    def __post_init__(self) -> None:
        # A config file gives lists; store tuples so the config stays hashable and immutable.
        object.__setattr__(self, "formats", tuple(self.formats))
        object.__setattr__(self, "part_densities", tuple((str(n), float(d)) for n, d in self.part_densities))
        if self.T_export_world is not None:
            T = check_transform(self.T_export_world, "T_export_world")
            object.__setattr__(self, "T_export_world", tuple(tuple(float(v) for v in row) for row in T))
        unknown = set(self.formats) - set(EXPORT_FORMATS)
        if unknown:
            raise ValueError(f"formats {sorted(unknown)} unknown; expected a subset of {EXPORT_FORMATS}")
        if not 0.0 <= self.snap_axis_deg < 45.0:
            raise ValueError(f"snap_axis_deg must be in [0, 45), got {self.snap_axis_deg}")
        if min(self.revolute_friction_nm, self.prismatic_friction_n, self.friction_gravity_margin) < 0.0:
            raise ValueError("joint friction and friction_gravity_margin must be >= 0")
        if not self.density_kg_m3 > 0.0 or any(not d > 0.0 for _, d in self.part_densities):
            raise ValueError("densities must be positive")

    def export_from_world(self) -> FloatArray:
        """(4, 4) ``T_export_world``."""
        if self.T_export_world is None:
            return np.eye(4)
        return check_transform(self.T_export_world, "T_export_world")


@dataclass(frozen=True)
class SimulationExports:
    """What export_simulation wrote."""

    urdf: Path | None
    """twin.urdf, or None if not requested."""
    mjcf: Path | None
    """twin.xml, or None if not requested."""
    usd: Path | None
    """twin.usda (or twin.usdc), or None if not requested."""
    glb: Path | None
    """twin.glb, or None if not requested."""
    mesh_files: MeshFiles
    """Visual and collision mesh files used by twin.urdf and twin.xml."""
    model: SimModel
    """The model all files were written from (link frames, masses, limits)."""
    decomposition_seconds: float
    """Wall time of the convex decompositions (s)."""
    total_seconds: float
    """Wall time of the whole export (s)."""


def export_simulation(twin_dir: str | Path, config: ExportConfig = ExportConfig(),  # noqa: B008 (frozen)
                      twin: InMemoryTwin | None = None) -> SimulationExports:
    """Write twin.urdf, twin.xml and twin.usda into a twin folder.

    Args:
        twin_dir: twin folder holding articulation.json and the meshes it names.
        config: export settings.
        twin: the twin's articulation and meshes as they were just written to ``twin_dir`` (the
            pipeline's); None reads them from the folder.

    Returns:
        The files written and the model they describe.

    Raises:
        ExportError: articulation.json or a mesh is missing or unusable, or a joint range is
            empty.
    """
    start = time.perf_counter()
    twin_dir = Path(twin_dir)
    model, decomposition_seconds = build_model(twin_dir, config, twin)
    mesh_files = write_mesh_files(model, twin_dir)
    paths: dict[str, Path | None] = {name: None for name in EXPORT_FORMATS}
    if "urdf" in config.formats:
        paths["urdf"] = write_urdf(model, mesh_files, twin_dir / URDF_NAME)
    if "mjcf" in config.formats:
        paths["mjcf"] = write_mjcf(model, mesh_files, twin_dir / MJCF_NAME)
    if "usd" in config.formats:
        from funrec.export.usd import write_usd  # pxr is heavy and only needed here

        usd_name = USD_BINARY_NAME if config.usd_binary else USD_NAME
        paths["usd"] = write_usd(model, twin_dir / usd_name)
    if "glb" in config.formats:
        paths["glb"] = write_glb(model, twin_dir / GLB_NAME)
    total = time.perf_counter() - start
    log.info("simulation exports of %s in %.1f s (decomposition %.1f s)", twin_dir, total, decomposition_seconds)
    return SimulationExports(
        urdf=paths["urdf"],
        mjcf=paths["mjcf"],
        usd=paths["usd"],
        glb=paths["glb"],
        mesh_files=mesh_files,
        model=model,
        decomposition_seconds=decomposition_seconds,
        total_seconds=total,
    )


def build_model(twin_dir: str | Path, config: ExportConfig = ExportConfig(),  # noqa: B008 (frozen)
                twin: InMemoryTwin | None = None) -> tuple[SimModel, float]:
    """Read a twin folder (or take its in-memory copy) into a simulator-neutral model.

    Args:
        twin_dir: twin folder holding articulation.json and its meshes; named in errors.
        config: export settings.
        twin: the folder's articulation and meshes already in memory; None reads them.

    Returns:
        The model and the wall time (s) spent in convex decomposition.

    Raises:
        ExportError: see :func:`export_simulation`.
    """
    twin_dir = Path(twin_dir)
    if twin is None:
        try:
            articulation = read_articulation(twin_dir)
        except FormatError as exc:
            raise ExportError(str(exc)) from None
    else:
        articulation = twin.articulation

    def load(relative: str) -> trimesh.Trimesh:
        if twin is not None and relative in twin.meshes:
            return twin.meshes[relative].copy()
        return _load_mesh(twin_dir, relative)
    names = [part.name for part in articulation.parts]
    unknown = [name for name, _ in config.part_densities if name not in names]
    if unknown:
        raise ExportError(
            f"{twin_dir / 'articulation.json'}: part_densities names {unknown}, the twin has parts {names}"
        )
    densities = dict(config.part_densities)
    T_export_world = config.export_from_world()
    tic = time.perf_counter()
    # The parts' decompositions run in a background thread while the static scene's runs here:
    # CoACD releases the GIL, so on two cores the part and static decompositions overlap. The
    # static one also goes to that thread if it is CoACD too (one CoACD run at a time).
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="funrec-decompose") as pool:
        part_inputs = []
        for part in articulation.parts:
            if part.mesh is None:
                raise ExportError(
                    f"{twin_dir / 'articulation.json'}: part {part.name} names no mesh; a simulator link needs one"
                )
            mesh_world = load(part.mesh)
            axis_world, pivot_world = _snapped_axis(part, mesh_world.centroid, T_export_world, config.snap_axis_deg)
            T_world_part = part_link_frame(part.joint_type, axis_world, pivot_world, mesh_world.centroid)
            visual_part = to_link_frame(mesh_world, T_world_part)
            decomposition = pool.submit(decompose, visual_part, config.collision.part_method, config.collision, part.mesh)
            part_inputs.append((part, T_world_part, visual_part, decomposition))
        base = _static_link(articulation.static_mesh, load, T_export_world, config, pool)
        parts, joints = [], []
        for part, T_world_part, visual_part, decomposition in part_inputs:
            pieces = decomposition.result()
            mass = mass_properties(visual_part, pieces, densities.get(part.name, config.density_kg_m3))
            log.info("%s: %d convex pieces, %.3f kg from the %s", part.name, len(pieces), mass.mass_kg, mass.source)
            T_export_part = T_export_world @ T_world_part
            link = SimLink(part.name, T_export_part, visual_part, pieces, mass)
            parts.append(link)
            joints.append(_joint(twin_dir, part, link, config))
    seconds = time.perf_counter() - tic
    model = SimModel(name=config.model_name, base=base, parts=tuple(parts), joints=tuple(joints))
    return model, seconds


def _snapped_axis(
    part: ArticulatedPart, centroid_world: FloatArray, T_export_world: FloatArray, tolerance_deg: float
) -> tuple[FloatArray, FloatArray | None]:
    """The part's joint axis (3,) and revolute pivot (3,) (None if prismatic) in the world frame,
    the axis snapped in the (z-up) export frame. A snapped hinge turns about the point of the
    estimated axis nearest the part's centroid: turning it about the stored pivot (the axis point
    nearest the world origin, metres away) would shift the axis at the part by centimetres."""
    R_export_world = T_export_world[:3, :3]
    axis_export, snapped = snap_axis(R_export_world @ part.axis_world, tolerance_deg)
    if snapped == "none":
        return part.axis_world, part.pivot_world
    angle = np.degrees(np.arccos(np.clip(axis_export @ (R_export_world @ part.axis_world), -1.0, 1.0)))
    log.info("%s: axis snapped %s (%.2f deg)", part.name, snapped, angle)
    pivot_world = part.pivot_world
    if pivot_world is not None:
        pivot_world = pivot_world + part.axis_world * float(part.axis_world @ (centroid_world - pivot_world))
    return R_export_world.T @ axis_export, pivot_world


def _static_link(
    static_mesh: str | None, load: Callable[[str], trimesh.Trimesh], T_export_world: FloatArray, config: ExportConfig,
    pool: ThreadPoolExecutor,
) -> SimLink:
    """The static link: the static mesh in the export frame and its convex pieces."""
    visual = None
    collision: tuple[trimesh.Trimesh, ...] = ()
    if static_mesh is not None:
        visual = load(static_mesh)
        visual.apply_transform(T_export_world)
        tic = time.perf_counter()
        method = config.collision.static_method
        if method == "coacd":
            collision = pool.submit(decompose, visual, method, config.collision, static_mesh).result()
        else:
            collision = decompose(visual, method, config.collision, static_mesh)
        log.info("static: %d convex pieces (%s) in %.1f s", len(collision), method, time.perf_counter() - tic)
    mass = static_mass_properties(collision, config.density_kg_m3)
    return SimLink(name="static", T_export_link=np.eye(4), visual=visual, collision=collision, mass=mass)


def _joint(twin_dir: Path, part: ArticulatedPart, link: SimLink, config: ExportConfig) -> SimJoint:
    """The joint of a part; the canonical state 0 always lies inside the limits, and its friction
    holds the part against gravity (ExportConfig.friction_gravity_margin)."""
    lower, upper = min(part.state_range[0], 0.0), max(part.state_range[1], 0.0)
    if not upper > lower:
        raise ExportError(
            f"{twin_dir / 'articulation.json'}: part {part.name} has an empty range {list(part.state_range)}; "
            "a simulator joint needs lower < upper"
        )
    revolute = part.joint_type == "revolute"
    joint = SimJoint(
        name=part.name,
        joint_type=part.joint_type,
        parent="static",
        child=part.name,
        T_parent_joint=link.T_export_link,
        lower=lower,
        upper=upper,
        effort=config.revolute_effort_nm if revolute else config.prismatic_effort_n,
        velocity=config.revolute_velocity_rad_s if revolute else config.prismatic_velocity_m_s,
        damping=config.revolute_damping if revolute else config.prismatic_damping,
        friction=config.revolute_friction_nm if revolute else config.prismatic_friction_n,
        armature=config.armature,
    )
    load = gravity_load(link, joint, np.array(GRAVITY_EXPORT_M_S2))
    friction = max(joint.friction, config.friction_gravity_margin * load)
    log.info("%s: gravity load up to %.3f %s, joint friction %.3f", part.name, load, "N m" if revolute else "N", friction)
    return dataclasses.replace(joint, friction=friction)


def _load_mesh(twin_dir: Path, relative: str) -> trimesh.Trimesh:
    """Load a triangle mesh named in articulation.json; ExportError names the file otherwise."""
    path = twin_dir / relative
    if not path.is_file():
        raise ExportError(f"{path}: mesh file is missing (named in {twin_dir / 'articulation.json'})")
    try:
        loaded = trimesh.load(path, process=False)
    except Exception as exc:  # trimesh raises many types on a corrupt file
        raise ExportError(f"{path}: cannot read mesh ({exc})") from None
    if isinstance(loaded, trimesh.Scene):
        loaded = loaded.to_mesh() if loaded.geometry else trimesh.Trimesh()
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise ExportError(f"{path}: holds no triangles (a point cloud?); a simulator needs a triangle mesh")
    return loaded


__all__ = [
    "EXPORT_FORMATS",
    "GLB_NAME",
    "ExportConfig",
    "SimulationExports",
    "build_model",
    "export_simulation",
]
