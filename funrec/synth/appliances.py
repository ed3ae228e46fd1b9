"""Appliances: a tall fridge, a countertop microwave and the oven and dishwasher that fill a
60 cm slot of the base row (doors that drop down on a horizontal hinge).

Same unit frame as ``units.py``: x right, y into the unit, z up, origin at the bottom of the
front plane.
"""

from __future__ import annotations

import numpy as np

from funrec.synth.fronts import FrontStyle, drop_down_door, hinged_door, objects_on
from funrec.synth.scene import Body, Geom, box, rod
from funrec.synth.units import GAP, PANEL, PLINTH, Palette, Unit, carcass, front_style, interior_objects


def fridge(name: str, rng: np.random.Generator, palette: Palette, width: float, height: float, hinge: str) -> Unit:
    """A tall fridge: shell, lit liner with shelves and food, a full-height or upper door with a long bar."""
    depth = 0.65
    shelves = tuple(round(z, 3) for z in np.linspace(0.45, height - 0.35, int(rng.integers(3, 5))))
    freezer = rng.random() < 0.5
    door_z0 = 0.62 if freezer else 0.05
    # Shelves and food start behind the door bins (which reach 7 cm into the cabinet).
    static = list(
        carcass(width, depth, height, 0.03, palette.appliance, palette.appliance_inside, shelves, shelf_front=0.09)
    )
    static += interior_objects(rng, palette, width, depth, tuple(z + PANEL for z in shelves), 0.2, y0=0.12)
    if freezer:
        static.append(
            box((-width / 2 + GAP, -0.052, 0.05), (width / 2 - GAP, -0.001, door_z0 - GAP), palette.appliance)
        )
        static.append(
            rod(
                (-width * 0.3, -0.08, door_z0 - 0.08),
                (width * 0.3, -0.08, door_z0 - 0.08),
                0.009,
                palette.handles[0],
                "capsule",
            )
        )
        static.append(
            box((-width * 0.32, -0.08, door_z0 - 0.085), (-width * 0.3, -0.05, door_z0 - 0.075), palette.handles[0])
        )
        static.append(
            box((width * 0.3, -0.08, door_z0 - 0.085), (width * 0.32, -0.05, door_z0 - 0.075), palette.handles[0])
        )
    x0, x1 = -width / 2 + GAP, width / 2 - GAP
    bins = tuple(
        box((x0 + 0.05, -0.001, z), (x1 - 0.05, 0.07, z + 0.06), palette.appliance_inside)
        for z in np.linspace(door_z0 + 0.25, height - 0.4, 3)
    )
    style = FrontStyle(
        palette.appliance, palette.handles[int(rng.integers(len(palette.handles)))], "bar", palette.glass
    )
    body, front = hinged_door(
        f"{name}_door",
        "fridge_door",
        (x0, x1, door_z0, height - GAP),
        hinge,
        0.05,
        style,
        float(np.clip(rng.uniform(1.05, 1.25), door_z0 + 0.3, height - 0.3)),
        float(rng.uniform(1.7, 2.0)),
        extra=bins,
        details={"furniture": "fridge"},
    )
    static.append(box((-width / 2, 0.03, 0.0), (width / 2, depth, 0.03), palette.appliance))
    return Unit(Body(name, (0.0, 0.0, 0.0), tuple(static), (body,)), (front,), width, depth, height)


def microwave(name: str, rng: np.random.Generator, palette: Palette) -> Unit:
    """A countertop microwave: hollow shell, turntable and bowl, side-hinged door with a window."""
    w, h, d = float(rng.uniform(0.46, 0.56)), float(rng.uniform(0.27, 0.32)), float(rng.uniform(0.34, 0.4))
    wall = 0.02
    shell, inside = palette.appliance, palette.appliance_inside
    static = [
        box((-w / 2, 0, 0), (w / 2, d, wall), shell),
        box((-w / 2, 0, h - wall), (w / 2, d, h), shell),
        box((-w / 2, 0, wall), (-w / 2 + wall, d, h - wall), shell),
        box((w / 2 - wall, 0, wall), (w / 2, d, h - wall), shell),
        box((-w / 2 + wall, d - wall, wall), (w / 2 - wall, d, h - wall), shell),
        box((-w / 2 + wall, 0.01, wall), (-w / 2 + wall + 0.002, d - wall, h - wall), inside),
        box((-w / 2 + wall, 0.01, wall), (w / 2 - 0.13, d - wall, wall + 0.002), inside),
    ]
    panel_x0 = w / 2 - 0.12
    static.append(box((panel_x0, -0.028, wall), (w / 2 - wall, d - wall, h - wall), shell))
    static += [
        Geom("cylinder", (0.009, 0.004), (panel_x0 + 0.06, -0.031, z), palette.glass, (0.0, 1.0, 0.0))
        for z in np.linspace(0.07, h - 0.07, 4)
    ]
    mid_x = (-w / 2 + panel_x0) / 2
    static.append(Geom("cylinder", (min(0.13, d / 2 - 0.04), 0.004), (mid_x, d / 2, wall + 0.006), palette.glass))
    static.append(
        Geom(
            "cylinder",
            (0.055, 0.03),
            (mid_x + 0.02, d / 2, wall + 0.04),
            palette.objects[int(rng.integers(len(palette.objects)))],
        )
    )
    rect = (-w / 2 + GAP, panel_x0 - GAP, GAP, h - GAP)
    window = box((rect[0] + 0.04, -0.028, rect[2] + 0.04), (rect[1] - 0.07, -0.0275, rect[3] - 0.04), palette.glass)
    style = front_style(rng, palette, shell, ("bar", "recessed"))
    body, front = hinged_door(
        f"{name}_door",
        "microwave_door",
        rect,
        "left",
        0.026,
        style,
        h / 2,
        float(rng.uniform(1.6, 1.85)),
        extra=(window,),
        details={"furniture": "microwave"},
    )
    return Unit(Body(name, (0.0, 0.0, 0.0), tuple(static), (body,)), (front,), w, d, h)


def drop_down_appliance(
    name: str, rng: np.random.Generator, palette: Palette, depth: float, height: float, kind: str
) -> Unit:
    """An oven (control strip, windowed door, racks and tray) or a dishwasher (full-height
    door, racks and plates) in a 60 cm slot of the base row; the door drops down."""
    width = 0.6
    shell, inside = palette.appliance, palette.appliance_inside
    static = list(carcass(width, depth, height, PLINTH, palette.carcass, inside))
    static.append(box((-width / 2, 0.05, 0), (width / 2, 0.07, PLINTH), palette.carcass))
    x0, x1 = -width / 2 + GAP, width / 2 - GAP
    if kind == "oven_door":
        strip = height - 0.13
        static.append(box((x0, -0.022, strip), (x1, -0.001, height - GAP), shell))
        static += [
            Geom("cylinder", (0.018, 0.01), (x, -0.03, (strip + height) / 2), palette.glass, (0.0, 1.0, 0.0))
            for x in np.linspace(x0 + 0.08, x1 - 0.08, 4)
        ]
        rect = (x0, x1, PLINTH + GAP, strip - GAP)
        for z in (PLINTH + 0.18, PLINTH + 0.35):
            static += [
                rod((x0 + 0.03, y, z), (x1 - 0.03, y, z), 0.004, palette.handles[0])
                for y in np.linspace(0.08, depth - 0.06, 6)
            ]
        static.append(
            box((x0 + 0.06, 0.1, PLINTH + 0.18 + 0.004), (x1 - 0.06, depth - 0.1, PLINTH + 0.2), palette.glass)
        )
        static += objects_on(rng, (x0 + 0.1, x1 - 0.1, 0.15, depth - 0.15), PLINTH + 0.2, 0.1, palette.objects, 2)
        extra = (box((rect[0] + 0.07, -0.032, rect[2] + 0.12), (rect[1] - 0.07, -0.031, rect[3] - 0.1), palette.glass),)
        style = FrontStyle(shell, palette.handles[int(rng.integers(len(palette.handles)))], "bar", palette.glass)
        max_angle = float(rng.uniform(1.35, 1.52))
    else:
        rect = (x0, x1, PLINTH + GAP, height - GAP)
        for z in (PLINTH + 0.1, PLINTH + 0.42):
            static += [
                rod((x0 + 0.04, y, z), (x1 - 0.04, y, z), 0.004, palette.handles[0])
                for y in np.linspace(0.08, depth - 0.06, 7)
            ]
            static += [
                Geom(
                    "cylinder",
                    (0.11, 0.004),
                    (x, depth / 2, z + 0.12),
                    palette.objects[k % len(palette.objects)],
                    (1.0, 0.0, 0.0),
                )
                for k, x in enumerate(np.linspace(x0 + 0.08, x1 - 0.08, int(rng.integers(4, 9))))
            ]
        extra = ()
        style = front_style(rng, palette, shell, ("bar", "recessed"))
        max_angle = float(rng.uniform(1.4, 1.57))
    body, front = drop_down_door(
        f"{name}_door", kind, rect, 0.03, style, max_angle, extra, {"furniture": kind.split("_")[0]}
    )
    return Unit(Body(name, (0.0, 0.0, 0.0), tuple(static), (body,)), (front,), width, depth, height)


__all__ = ["drop_down_appliance", "fridge", "microwave"]
