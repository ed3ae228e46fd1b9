"""Furniture units: base and wall cabinets (doors, drawer stacks), a sliding-door wardrobe
and a chest of drawers; appliances live in ``appliances.py``.

Each builder returns a :class:`Unit` in its own frame (see ``fronts.py``: x right, y into
the unit, z up, origin at the bottom of the front plane, centred in x). The layout places it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from funrec.synth.fronts import FrontStyle, drawer, hinged_door, objects_on, sliding_door
from funrec.synth.scene import Body, Front, Geom, box, rod, vec3

PANEL = 0.018
"""Carcass board thickness, metres."""
GAP = 0.003
"""Gap between neighbouring fronts, metres."""
PLINTH = 0.1
"""Height of the recessed kick board under base units, metres."""


@dataclass(frozen=True)
class Palette:
    """Material names a scene's furniture draws from (defined by the layout)."""

    carcass: str
    """Cabinet boards."""
    interior: str
    """Inside of cabinets and drawer boxes."""
    fronts: tuple[str, ...]
    """Door and drawer panels (one is picked per unit)."""
    handles: tuple[str, ...]
    """Handle metals."""
    appliance: str
    """Fridge, oven, dishwasher, microwave shells."""
    appliance_inside: str
    """Appliance cavities and liners."""
    glass: str
    """Dark appliance windows and recessed grips."""
    objects: tuple[str, ...]
    """Things stored inside furniture."""
    pane: str = ""
    """Clear glass of glazed wall-cabinet doors; empty: wall cabinets have solid doors."""


@dataclass(frozen=True)
class Unit:
    """A built furniture unit in its own frame."""

    body: Body
    """Static body of the unit (its pos is set by the layout) with the fronts as children."""
    fronts: tuple[Front, ...]
    """Articulable fronts of the unit."""
    width: float
    """Extent along x, metres."""
    depth: float
    """Extent along y, metres."""
    height: float
    """Extent along z, metres."""


def front_style(
    rng: np.random.Generator, palette: Palette, panel: str, shapes: tuple[str, ...] = ("bar", "knob", "recessed")
) -> FrontStyle:
    shape = shapes[int(rng.integers(len(shapes)))]
    return FrontStyle(panel, palette.handles[int(rng.integers(len(palette.handles)))], shape, palette.glass)


def carcass(
    w: float,
    d: float,
    h: float,
    z0: float,
    material: str,
    inner: str,
    shelves: tuple[float, ...] = (),
    shelf_front: float = 0.02,
) -> tuple[Geom, ...]:
    """An open-front box of boards: sides, bottom at z0, top, back and shelves at given heights
    (shelves start ``shelf_front`` behind the front plane)."""
    x0, x1 = -w / 2, w / 2
    geoms = [
        box((x0, 0, z0), (x0 + PANEL, d, h), material),
        box((x1 - PANEL, 0, z0), (x1, d, h), material),
        box((x0 + PANEL, 0, z0), (x1 - PANEL, d, z0 + PANEL), inner),
        box((x0 + PANEL, 0, h - PANEL), (x1 - PANEL, d, h), inner),
        box((x0 + PANEL, d - PANEL, z0 + PANEL), (x1 - PANEL, d, h - PANEL), inner),
    ]
    geoms += [box((x0 + PANEL, shelf_front, z), (x1 - PANEL, d - PANEL, z + PANEL), inner) for z in shelves]
    return tuple(geoms)


def interior_objects(
    rng: np.random.Generator,
    palette: Palette,
    w: float,
    d: float,
    levels: tuple[float, ...],
    clear: float,
    y0: float = 0.06,
) -> tuple[Geom, ...]:
    """Objects on each level (bottom board and shelves) of a cabinet interior."""
    geoms: tuple[Geom, ...] = ()
    for z in levels:
        area = (-w / 2 + PANEL + 0.01, w / 2 - PANEL - 0.01, y0, d - PANEL - 0.02)
        geoms += objects_on(rng, area, z, clear, palette.objects, int(rng.integers(1, 4)))
    return geoms


def base_cabinet(
    name: str, rng: np.random.Generator, palette: Palette, width: float, depth: float, height: float, config: str
) -> Unit:
    """A base cabinet on a plinth.

    Args:
        config: "door_left", "door_right" (single door hinged on that side), "double",
            "drawers" (a stack of 2-4) or "drawer_door" (a drawer above a door).
    """
    panel = palette.fronts[int(rng.integers(len(palette.fronts)))]
    shelf = round(PLINTH + (height - PLINTH) * float(rng.uniform(0.45, 0.6)), 3)
    static = list(
        carcass(
            width,
            depth,
            height,
            PLINTH,
            palette.carcass,
            palette.interior,
            (shelf,) if "door" in config or config == "double" else (),
        )
    )
    static.append(box((-width / 2, 0.05, 0), (width / 2, 0.07, PLINTH), palette.carcass))
    bodies: list[Body] = []
    fronts: list[Front] = []
    x0, x1, z0, z1 = -width / 2 + GAP / 2, width / 2 - GAP / 2, PLINTH + GAP, height - GAP
    unit = {"furniture": "base_cabinet"}
    if config in ("door_left", "door_right", "drawer_door"):
        top = z1
        if config == "drawer_door":
            top = z1 - float(rng.uniform(0.13, 0.18))
            body, front = drawer(
                f"{name}_drawer",
                (x0, x1, top + GAP, z1),
                depth - 0.05,
                front_style(rng, palette, panel),
                palette.interior,
                objects_on(rng, (x0 + 0.05, x1 - 0.05, 0.03, depth - 0.1), top + 0.04, 0.05, palette.objects, 3),
                details={**unit, "level": "top"},
            )
            bodies.append(body)
            fronts.append(front)
            static.append(
                box((-width / 2 + PANEL, 0, top - PANEL), (width / 2 - PANEL, depth - PANEL, top), palette.interior)
            )
        hinge = (
            "right"
            if config == "door_right"
            else "left"
            if config == "door_left"
            else ("left", "right")[int(rng.integers(2))]
        )
        body, front = hinged_door(
            f"{name}_door",
            "door",
            (x0, x1, z0, top - GAP * (config == "drawer_door")),
            hinge,
            0.019,
            front_style(rng, palette, panel),
            top - 0.08,
            float(rng.uniform(1.6, 1.9)),
            details=unit,
        )
        bodies.append(body)
        fronts.append(front)
        static += interior_objects(
            rng, palette, width, depth, (PLINTH + PANEL, shelf + PANEL), min(shelf - PLINTH, top - shelf) - 0.06
        )
    elif config == "double":
        style = front_style(rng, palette, panel)
        mid = 0.0
        for hinge, rect in (("left", (x0, mid - GAP / 2, z0, z1)), ("right", (mid + GAP / 2, x1, z0, z1))):
            body, front = hinged_door(
                f"{name}_{hinge}",
                "double_door",
                rect,
                hinge,
                0.019,
                style,
                z1 - 0.08,
                float(rng.uniform(1.6, 1.9)),
                details=unit,
            )
            bodies.append(body)
            fronts.append(front)
        static += interior_objects(
            rng, palette, width, depth, (PLINTH + PANEL, shelf + PANEL), min(shelf - PLINTH, height - shelf) - 0.06
        )
    elif config == "drawers":
        count = int(rng.integers(2, 5))
        weights = np.sort(rng.uniform(0.7, 1.4, count))[::-1] if rng.random() < 0.6 else np.ones(count)
        edges = z1 - np.concatenate([[0.0], np.cumsum(weights[::-1]) / weights.sum()]) * (z1 - z0)
        style = front_style(rng, palette, panel)
        for k in range(count):
            top, bottom = edges[k], edges[k + 1]
            level = "top" if k == 0 else "bottom" if k == count - 1 else "middle"
            contents = objects_on(
                rng, (x0 + 0.05, x1 - 0.05, 0.03, depth - 0.1), bottom + 0.04, (top - bottom) * 0.5, palette.objects, 3
            )
            body, front = drawer(
                f"{name}_drawer{k}",
                (x0, x1, bottom + GAP / 2, top - GAP / 2),
                depth - 0.05,
                style,
                palette.interior,
                contents,
                details={**unit, "level": level, "row": k},
            )
            bodies.append(body)
            fronts.append(front)
    else:
        raise ValueError(f"unknown base cabinet config {config!r}")
    return Unit(Body(name, (0.0, 0.0, 0.0), tuple(static), tuple(bodies)), tuple(fronts), width, depth, height)


def wall_cabinet(
    name: str, rng: np.random.Generator, palette: Palette, width: float, depth: float, height: float, config: str
) -> Unit:
    """A wall-hung cabinet with one ("door_left"/"door_right") or two ("double") doors; handles low."""
    panel = palette.fronts[int(rng.integers(len(palette.fronts)))]
    shelf = round(height * float(rng.uniform(0.45, 0.55)), 3)
    static = list(carcass(width, depth, height, 0.0, palette.carcass, palette.interior, (shelf,)))
    static += interior_objects(rng, palette, width, depth, (PANEL, shelf + PANEL), min(shelf, height - shelf) - 0.06)
    x0, x1, z0, z1 = -width / 2 + GAP / 2, width / 2 - GAP / 2, GAP, height - GAP
    style = front_style(rng, palette, panel)
    if palette.pane:
        style = FrontStyle(style.panel, style.handle, style.handle_shape, style.inset, palette.pane)
    unit = {"furniture": "wall_cabinet", "glazed": "yes" if palette.pane else "no"}
    if config == "double":
        leaves = (("left", (x0, -GAP / 2, z0, z1)), ("right", (GAP / 2, x1, z0, z1)))
        kind = "wall_double_door"
    else:
        leaves = (("left" if config == "door_left" else "right", (x0, x1, z0, z1)),)
        kind = "wall_door"
    bodies, fronts = [], []
    for hinge, rect in leaves:
        body, front = hinged_door(
            f"{name}_{hinge}", kind, rect, hinge, 0.019, style, z0 + 0.08, float(rng.uniform(1.6, 1.9)), details=unit
        )
        bodies.append(body)
        fronts.append(front)
    return Unit(Body(name, (0.0, 0.0, 0.0), tuple(static), tuple(bodies)), tuple(fronts), width, depth, height)


def wardrobe(name: str, rng: np.random.Generator, palette: Palette, width: float, height: float) -> Unit:
    """A wardrobe with two sliding doors on two tracks, a rail of clothes and a top shelf."""
    depth = 0.6
    shelf = height - 0.35
    static = list(carcass(width, depth, height, 0.06, palette.carcass, palette.interior, (shelf,)))
    static.append(
        rod(
            (-width / 2 + PANEL, depth / 2, shelf - 0.06),
            (width / 2 - PANEL, depth / 2, shelf - 0.06),
            0.012,
            palette.handles[0],
        )
    )
    static.append(box((-width / 2, -0.05, 0), (width / 2, -0.001, 0.06), palette.carcass))
    static.append(box((-width / 2, -0.05, height - 0.05), (width / 2, -0.001, height), palette.carcass))
    xs = np.sort(rng.uniform(-width / 2 + 0.06, width / 2 - 0.06, int(width * 14)))
    for x in xs:
        drop = float(rng.uniform(0.5, 1.1))
        material = palette.objects[int(rng.integers(len(palette.objects)))]
        static.append(
            box(
                (x - 0.012, depth / 2 - 0.22, shelf - 0.08 - drop),
                (x + 0.012, depth / 2 + 0.22, shelf - 0.08),
                material,
            )
        )
    static += objects_on(
        rng, (-width / 2 + 0.05, width / 2 - 0.05, 0.06, depth - 0.05), shelf + PANEL, 0.25, palette.objects, 4
    )
    panel = palette.fronts[int(rng.integers(len(palette.fronts)))]
    style = front_style(rng, palette, panel, ("bar", "recessed"))
    half, overlap = width / 2, 0.03
    z0, z1 = 0.065, height - 0.055
    # The travel stops the rear door's handle short of the front door it slides behind.
    left, left_front = sliding_door(
        f"{name}_left",
        (-half + GAP, overlap, z0, z1),
        -0.004,
        1.0,
        half - 0.13,
        style,
        {"furniture": "wardrobe", "side": "left"},
    )
    right, right_front = sliding_door(
        f"{name}_right",
        (-overlap, half - GAP, z0, z1),
        -0.027,
        -1.0,
        half - 0.13,
        style,
        {"furniture": "wardrobe", "side": "right"},
    )
    return Unit(
        Body(name, (0.0, 0.0, 0.0), tuple(static), (left, right)), (left_front, right_front), width, depth, height
    )


def chest_of_drawers(name: str, rng: np.random.Generator, palette: Palette, width: float, height: float) -> Unit:
    """A free-standing chest of 3-5 drawer rows of varied heights with things on top."""
    depth = float(rng.uniform(0.42, 0.5))
    static = list(carcass(width, depth, height, 0.08, palette.carcass, palette.interior))
    static += [
        box((x - 0.02, 0.02, 0), (x + 0.02, 0.06, 0.08), palette.carcass) for x in (-width / 2 + 0.04, width / 2 - 0.04)
    ]
    static += objects_on(
        rng, (-width / 2 + 0.05, width / 2 - 0.05, 0.05, depth - 0.05), height, 0.3, palette.objects, 3
    )
    panel = palette.fronts[int(rng.integers(len(palette.fronts)))]
    style = front_style(rng, palette, panel)
    count = int(rng.integers(3, 6))
    weights = np.sort(rng.uniform(0.7, 1.5, count))
    z0, z1 = 0.08 + GAP, height - PANEL - GAP
    edges = z1 - np.concatenate([[0.0], np.cumsum(weights) / weights.sum()]) * (z1 - z0)
    bodies, fronts = [], []
    x0, x1 = -width / 2 + PANEL + GAP, width / 2 - PANEL - GAP
    for k in range(count):
        top, bottom = edges[k], edges[k + 1]
        level = "top" if k == 0 else "bottom" if k == count - 1 else "middle"
        contents = objects_on(
            rng, (x0 + 0.05, x1 - 0.05, 0.03, depth - 0.1), bottom + 0.04, (top - bottom) * 0.45, palette.objects, 4
        )
        body, front = drawer(
            f"{name}_drawer{k}",
            (x0, x1, bottom + GAP / 2, top - GAP / 2),
            depth - 0.04,
            style,
            palette.interior,
            contents,
            details={"furniture": "chest_of_drawers", "level": level, "row": k},
        )
        bodies.append(body)
        fronts.append(front)
    return Unit(Body(name, (0.0, 0.0, 0.0), tuple(static), tuple(bodies)), tuple(fronts), width, depth, height)


def placed(unit: Unit, x: float, y_wall: float, z: float = 0.0) -> Unit:
    """The unit with its body moved so its back touches the wall at ``y_wall``, centred at ``x``."""
    body = Body(unit.body.name, vec3((x, y_wall - unit.depth, z)), unit.body.geoms, unit.body.bodies)
    return Unit(body, unit.fronts, unit.width, unit.depth, unit.height)


__all__ = [
    "GAP",
    "PANEL",
    "PLINTH",
    "Palette",
    "Unit",
    "base_cabinet",
    "carcass",
    "chest_of_drawers",
    "front_style",
    "interior_objects",
    "placed",
    "wall_cabinet",
    "wardrobe",
]
