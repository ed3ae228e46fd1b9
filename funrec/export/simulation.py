"""Simulation exports of a twin folder: twin.urdf, twin.xml (MuJoCo) and twin.usda (USD physics),
all written from one :class:`~funrec.export.sim_model.SimModel` built here from articulation.json
and the meshes (FORMATS.md section 2)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from funrec.errors import ExportError, FormatError
from funrec.export.collision import CollisionConfig, decompose
from funrec.export.mjcf import write_mjcf
from funrec.export.sim_model import (
    MeshFiles,
    SimJoint,
    SimLink,
    SimModel,
    mass_properties,
    part_link_frame,
    to_link_frame,
    write_mesh_files,
)
from funrec.export.urdf import write_urdf
from funrec.formats.twin import ArticulatedPart, TwinArticulation, read_articulation
from funrec.geometry.transforms import check_transform
from funrec.typed import FloatArray

log = logging.getLogger(__name__)

EXPORT_FORMATS = ("urdf", "mjcf", "usd")
"""Simulator files export_simulation can write: twin.urdf, twin.xml and twin.usda."""
URDF_NAME, MJCF_NAME, USD_NAME = "twin.urdf", "twin.xml", "twin.usda"
"""File names inside the twin folder (FORMATS.md section 2)."""


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
    armature: float = 0.01
    """Armature of every joint (kg m^2 or kg), MJCF only; keeps light parts numerically stable."""
    T_export_world: tuple[tuple[float, ...], ...] | None = None
    """(4, 4) row-major transform from the twin's world frame to the frame of the exported files
    (e.g. a gravity-aligned frame with z up); None is the identity."""
    formats: tuple[str, ...] = EXPORT_FORMATS
    """Which files to write, a subset of ("urdf", "mjcf", "usd")."""
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
    """twin.usda, or None if not requested."""
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

        paths["usd"] = write_usd(model, twin_dir / USD_NAME)
    total = time.perf_counter() - start
    log.info("simulation exports of %s in %.1f s (decomposition %.1f s)", twin_dir, total, decomposition_seconds)
    return SimulationExports(
        urdf=paths["urdf"],
        mjcf=paths["mjcf"],
        usd=paths["usd"],
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
            T_world_part = part_link_frame(part.joint_type, part.axis_world, part.pivot_world, mesh_world.centroid)
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
            parts.append(SimLink(part.name, T_export_part, visual_part, pieces, mass))
            joints.append(_joint(twin_dir, part, T_export_part, config))
    seconds = time.perf_counter() - tic
    model = SimModel(name=config.model_name, base=base, parts=tuple(parts), joints=tuple(joints))
    return model, seconds


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
    return SimLink(name="static", T_export_link=np.eye(4), visual=visual, collision=collision, mass=None)


def _joint(twin_dir: Path, part: ArticulatedPart, T_static_part: FloatArray, config: ExportConfig) -> SimJoint:
    """The joint of a part; the canonical state 0 always lies inside the limits."""
    lower, upper = min(part.state_range[0], 0.0), max(part.state_range[1], 0.0)
    if not upper > lower:
        raise ExportError(
            f"{twin_dir / 'articulation.json'}: part {part.name} has an empty range {list(part.state_range)}; "
            "a simulator joint needs lower < upper"
        )
    revolute = part.joint_type == "revolute"
    return SimJoint(
        name=part.name,
        joint_type=part.joint_type,
        parent="static",
        child=part.name,
        T_parent_joint=T_static_part,
        lower=lower,
        upper=upper,
        effort=config.revolute_effort_nm if revolute else config.prismatic_effort_n,
        velocity=config.revolute_velocity_rad_s if revolute else config.prismatic_velocity_m_s,
        damping=config.revolute_damping if revolute else config.prismatic_damping,
        armature=config.armature,
    )


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
    "ExportConfig",
    "SimulationExports",
    "build_model",
    "export_simulation",
]
