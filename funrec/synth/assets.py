"""Articulated objects the team did not design: Meta-World's drawer, safe door and sliding
windows (MIT License), read at build time from an installed ``metaworld`` package, scaled to
human size and drawn in plain paint.

Nothing of Meta-World is stored in this repository. The meshes are copied into each generated
sequence (``gt/meshes/``) with the licence credited in gt.json. The package pins versions that
conflict with FunREC's, so it is usually installed into a separate environment; point
``FUNREC_METAWORLD_ASSETS`` at its ``metaworld/assets`` folder, e.g.
``python -m venv /work/venv_assets && /work/venv_assets/bin/pip install --no-deps metaworld``.

Meta-World frames: fronts face -y, z up, the object's origin at its centre, as in FunREC's
unit frame up to the origin (``units.py`` puts it at the bottom of the front plane).
"""

from __future__ import annotations

import importlib.util
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from funrec.errors import FunrecError
from funrec.synth.room import CLEAR_GLASS, MaterialBank
from funrec.synth.scene import SEE_THROUGH_GROUP, Body, Front, Geom, Joint, box, vec3
from funrec.synth.units import Palette, Unit

METAWORLD_ENV = "FUNREC_METAWORLD_ASSETS"
"""Environment variable naming Meta-World's ``assets`` folder."""
METAWORLD_CREDIT = (
    "Meta-World (Yu et al. 2019, Farama Foundation), MIT License, Copyright (c) 2019 Meta-World Team; "
    "geometry copied unchanged from the metaworld package, scaled and re-painted"
)
"""Licence credit written into the ground truth of every sequence that uses these assets."""


@dataclass(frozen=True)
class AssetModel:
    """Where one Meta-World object is and how it becomes a FunREC front."""

    file: str
    """Body include file under ``objects/assets``."""
    dependencies: str
    """Include file under ``objects/assets`` declaring its meshes."""
    scale: float
    """Uniform scale to human size."""
    stand_m: float
    """Height of the plain stand the object is set on, metres (after scaling)."""
    handle: tuple[float, float, float]
    """Handle centre in the moving body's frame, Meta-World metres (unscaled)."""
    grip_axis: tuple[float, float, float]
    """Direction of the handle bar in the moving body's frame."""
    max_opening: float
    """Joint limit used, radians or Meta-World metres (unscaled), at most Meta-World's."""


ASSET_MODELS: dict[str, AssetModel] = {
    "mw_drawer": AssetModel("drawer.xml", "drawer_dependencies.xml", 3.0, 0.3, (0.0, -0.15, 0.0), (1.0, 0.0, 0.0), 0.15),
    "mw_door": AssetModel(
        "doorlockB.xml", "doorlock_dependencies.xml", 2.4, 0.25, (0.381, -0.12, 0.0), (1.0, 0.0, 0.0), 1.6
    ),
    "mw_window": AssetModel("window.xml", "window_dependencies.xml", 2.5, 0.75, (0.0, -0.095, 0.014), (1.0, 0.0, 0.0), 0.2),
    "mw_window_horiz": AssetModel(
        "window_horiz.xml", "window_dependencies.xml", 2.6, 1.0, (-0.014, -0.095, 0.0), (0.0, 0.0, 1.0), 0.2
    ),
}
"""The Meta-World objects by part kind."""


def metaworld_root() -> Path:
    """Meta-World's ``assets`` folder: ``$FUNREC_METAWORLD_ASSETS`` or the installed package's.

    Raises:
        FunrecError: neither is available (says how to install it).
    """
    configured = os.environ.get(METAWORLD_ENV)
    if configured:
        root = Path(configured)
    else:
        spec = importlib.util.find_spec("metaworld")
        if spec is None or not spec.submodule_search_locations:
            raise FunrecError(
                f"the assets family needs Meta-World's models: pip install --no-deps metaworld (into a separate "
                f"venv if it conflicts) and set {METAWORLD_ENV} to its metaworld/assets folder"
            )
        root = Path(next(iter(spec.submodule_search_locations))) / "assets"
    if not (root / "objects" / "assets").is_dir():
        raise FunrecError(f"{METAWORLD_ENV}={root}: not Meta-World's assets folder (no objects/assets/)")
    return root


def _floats(text: str | None, default: tuple[float, ...]) -> np.ndarray:
    return np.array([float(v) for v in text.split()]) if text else np.array(default, dtype=np.float64)


class _Converter:
    """Turns one Meta-World body tree into FunREC bodies (visual geoms only, plain materials)."""

    def __init__(self, root: Path, model: AssetModel, kind: str, mats: MaterialBank) -> None:
        self.root, self.model, self.kind, self.mats = root, model, kind, mats
        deps = ET.parse(root / "objects" / "assets" / model.dependencies).getroot()
        self.mesh_paths = {m.get("name"): m.get("file") for m in deps.iter("mesh")}
        self.paint: dict[str, str] = {}
        self.mesh_files: dict[str, bytes] = {}
        self.moving: Body | None = None
        self.joint_name = ""

    def material(self, name: str) -> str:
        if name not in self.paint:
            if "glass" in name:
                self.paint[name] = self.mats.plain(CLEAR_GLASS, 0.9, 0.95)
            else:
                grey = float(self.mats.rng.uniform(0.45, 0.9))
                tint = self.mats.rng.normal(0.0, 0.04, 3)
                self.paint[name] = self.mats.plain((*vec3(np.clip(grey + tint, 0.05, 0.95)), 1.0), 0.3, 0.3)
        return self.paint[name]

    def geom(self, element: ET.Element, inherited: str) -> Geom | None:
        cls = element.get("class", inherited)
        if cls.endswith("_col") or element.get("group") == "4":
            return None
        s = self.model.scale
        pos = vec3(_floats(element.get("pos"), (0.0, 0.0, 0.0)) * s)
        euler = vec3(_floats(element.get("euler"), (0.0, 0.0, 0.0)))
        material = self.material(element.get("material", "default"))
        group = SEE_THROUGH_GROUP if "glass" in element.get("material", "") else 0
        mesh = element.get("mesh")
        if mesh is not None:
            # Meta-World's paths are relative to a scene one folder below assets/ (e.g. sawyer_xyz/).
            source = (self.root / "objects" / self.mesh_paths[mesh]).resolve()
            path = f"meshes/{self.kind}/{source.name}"
            self.mesh_files[path] = source.read_bytes()
            return Geom("mesh", (s, s, s), pos, material, group=group, mesh=path, euler=euler)
        shape = element.get("type", "sphere")
        size = tuple(float(v) * s for v in _floats(element.get("size"), ()))
        return Geom(shape, size, pos, material, group=group, euler=euler)

    def body(self, element: ET.Element, inherited: str, name: str) -> Body:
        cls = element.get("childclass", inherited)
        geoms = [g for g in (self.geom(e, cls) for e in element.findall("geom")) if g is not None]
        joint_element = element.find("joint")
        joint = None
        if joint_element is not None and self.moving is None:
            joint = self._joint(joint_element, f"{name}_joint")
            # The largest mesh first: it stands for the panel in the ground-truth bookkeeping.
            geoms.sort(key=lambda g: -self._extent(g) if g.shape == "mesh" else 0.0)
        children = tuple(self.body(child, cls, f"{name}_{k}") for k, child in enumerate(element.findall("body")))
        body = Body(
            name,
            vec3(_floats(element.get("pos"), (0.0, 0.0, 0.0)) * self.model.scale),
            tuple(geoms),
            children,
            joint,
        )
        if joint is not None:
            handle = vec3(np.asarray(self.model.handle) * self.model.scale)
            # The moving part lies inside its carcass's convex hull, which is what MuJoCo collides.
            sites = ((f"{name}_handle", handle),)
            body = Body(body.name, body.pos, body.geoms, body.bodies, joint, sites, touches_parent=False)
            self.moving, self.joint_name = body, joint.name
        return body

    def _extent(self, geom: Geom) -> float:
        mesh = trimesh.load(trimesh.util.wrap_as_stream(self.mesh_files[geom.mesh]), file_type="stl")
        return float(np.prod(np.ptp(mesh.vertices, axis=0)))

    def _joint(self, element: ET.Element, name: str) -> Joint:
        axis = _floats(element.get("axis"), (0.0, 0.0, 1.0))
        lo, hi = _floats(element.get("range"), (0.0, 1.0))
        if hi <= 0.0 and lo < 0.0:  # opens towards negative values: flip the axis
            axis, hi = -axis, -lo
        kind = "slide" if element.get("type") == "slide" else "hinge"
        limit = min(float(hi), self.model.max_opening) * (self.model.scale if kind == "slide" else 1.0)
        return Joint(name, kind, vec3(axis), (0.0, round(limit, 4)))


def _static_geoms(body: Body, offset: np.ndarray) -> list[tuple[Geom, np.ndarray]]:
    """Geoms of the body tree outside jointed bodies, with the summed position of their body
    (Meta-World's bodies carry no rotation)."""
    here = offset + np.asarray(body.pos)
    out = [(geom, here) for geom in body.geoms]
    for child in body.bodies:
        if child.joint is None:
            out += _static_geoms(child, here)
    return out


def asset_unit(kind: str, mats: MaterialBank, palette: Palette) -> tuple[Unit, dict[str, bytes]]:
    """A Meta-World object at human scale on a plain stand, as a unit (``units.py`` frame).

    Args:
        kind: a key of :data:`ASSET_MODELS`.
        mats: material bank (plain paint is drawn from its rng).
        palette: the scene's palette (the stand uses its carcass material).

    Returns:
        The unit (its one front is the object's moving part) and the mesh files it needs
        (path relative to scene.xml -> bytes).
    """
    model = ASSET_MODELS[kind]
    root = metaworld_root()
    converter = _Converter(root, model, kind, mats)
    xml = ET.parse(root / "objects" / "assets" / model.file).getroot()
    top = converter.body(xml.find("body"), "", kind)
    if converter.moving is None:
        raise FunrecError(f"{root / 'objects' / 'assets' / model.file}: no jointed body")
    points = [
        np.asarray(
            trimesh.load(trimesh.util.wrap_as_stream(converter.mesh_files[geom.mesh]), file_type="stl").vertices
        )
        * model.scale
        + np.asarray(geom.pos)
        + offset
        for geom, offset in _static_geoms(top, np.zeros(3))
        if geom.shape == "mesh"
    ]
    if not points:
        raise FunrecError(f"{model.file}: no static mesh to size the object by")
    lo, hi = np.vstack(points).min(axis=0), np.vstack(points).max(axis=0)
    width, depth, height = (float(v) for v in hi - lo)
    # Unit frame: the front plane (lowest y) at y = 0, the bottom on the stand.
    top = Body(top.name, vec3((-(lo[0] + hi[0]) / 2, -lo[1], model.stand_m - lo[2])), top.geoms, top.bodies)
    stand = box((-width / 2, 0.0, 0.0), (width / 2, depth, model.stand_m), palette.carcass)
    moving = converter.moving
    panel = moving.geoms[0]
    if panel.shape != "mesh":
        raise FunrecError(f"{model.file}: the moving body has no mesh to stand for its panel")
    vertices = trimesh.load(trimesh.util.wrap_as_stream(converter.mesh_files[panel.mesh]), file_type="stl").vertices
    p_lo = np.asarray(vertices).min(axis=0) * model.scale + np.asarray(panel.pos)
    p_hi = np.asarray(vertices).max(axis=0) * model.scale + np.asarray(panel.pos)
    front = Front(
        kind,
        moving.name,
        converter.joint_name,
        f"{moving.name}_handle",
        vec3(model.grip_axis),
        {"furniture": "metaworld", "source": f"metaworld/assets/objects/assets/{model.file}", "scale": model.scale},
        panel=(vec3((p_lo + p_hi) / 2), vec3((p_hi - p_lo) / 2)),
    )
    unit = Unit(Body(f"{kind}_unit", (0.0, 0.0, 0.0), (stand,), (top,)), (front,), width, depth, model.stand_m + height)
    return unit, converter.mesh_files


__all__ = ["ASSET_MODELS", "METAWORLD_CREDIT", "METAWORLD_ENV", "AssetModel", "asset_unit", "metaworld_root"]
