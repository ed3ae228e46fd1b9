"""Procedural scenes: a row of furniture against the back wall of a room that holds the
requested fronts (kitchen, bedroom or a single tiny cabinet).

The room floor is z = 0, centred on the origin; the back wall is at y = +depth/2 and the
furniture fronts face -y (towards the room).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from funrec.synth.appliances import drop_down_appliance, fridge, microwave
from funrec.synth.assets import METAWORLD_CREDIT, asset_unit
from funrec.synth.fronts import objects_on
from funrec.synth.room import PAINTS, MaterialBank, ceiling_lights, make_palette, room_geoms, vary_lighting
from funrec.synth.scene import Body, Front, Scene, box
from funrec.synth.spec import PartRequest
from funrec.synth.units import Palette, Unit, base_cabinet, carcass, chest_of_drawers, placed, wall_cabinet, wardrobe

WALK_MARGIN = 0.35
"""Closest the camera may come to a wall or a furniture front, metres."""


@dataclass(frozen=True)
class Layout:
    """A sampled scene and the front chosen for each :class:`PartRequest`."""

    scene: Scene
    """The scene; every front still has its provisional joint."""
    targets: tuple[Front, ...]
    """targets[k] is the front that becomes part_k."""


def _pick_front(unit: Unit, request: PartRequest, rng: np.random.Generator) -> Front:
    """The front of ``unit`` matching ``request`` (hinge side, leaf or drawer level)."""
    fronts = [f for f in unit.fronts if f.kind == request.kind]
    if request.kind == "drawer" and request.level is not None:
        levels = [f for f in fronts if f.details.get("level") == request.level]
        fronts = levels or fronts
    if request.hinge is not None and request.kind in ("double_door", "wall_double_door"):
        fronts = [f for f in fronts if f.details.get("hinge") == request.hinge] or fronts
    if request.kind == "sliding_door" and request.hinge is not None:
        fronts = [f for f in fronts if f.details.get("side") == request.hinge] or fronts
    return fronts[int(rng.integers(len(fronts)))]


@dataclass(frozen=True)
class _Row:
    """Furniture against one wall, in the row frame: the wall is y = 0, x runs from 0 to length."""

    body: Body
    """Static body holding the units (children) and shared geoms (countertop, backsplash)."""
    length: float
    """Extent along x, metres."""
    depth: float
    """Largest unit depth, metres."""
    fronts: tuple[Front, ...]
    """Every articulable front in the row."""
    targets: dict[int, Front]
    """Request index -> chosen front."""
    mesh_files: dict[str, bytes] = field(default_factory=dict)
    """Third-party meshes the row's geoms use (path relative to scene.xml -> bytes)."""


def _kitchen(mats: MaterialBank, palette: Palette, requests: tuple[PartRequest, ...], varied: bool = False) -> _Row:
    """Base units (one per request that needs one, plus fillers), a fridge at one end, wall
    cabinets over some base units, a countertop with a tiled backsplash and a microwave.
    ``varied`` hangs the wall cabinets so their handles are at 1.4-1.9 m (instead of about
    1.5-1.6 m) and stands small appliances (boxes and cylinders) on the counter."""
    rng = mats.rng
    depth, height = float(rng.uniform(0.55, 0.6)), float(rng.uniform(0.84, 0.9))
    fillers = ("door_left", "door_right", "double", "drawers", "drawers", "drawer_door")

    def filler(n: int, width: float) -> Unit:
        return base_cabinet(f"u{n}", rng, palette, width, depth, height, fillers[int(rng.integers(len(fillers)))])

    base: list[Unit] = []
    wall: dict[int, Unit] = {}
    where: dict[int, tuple[str, int]] = {}
    fridge_unit: Unit | None = None
    for k, request in enumerate(requests):
        hinge = request.hinge or ("left", "right")[int(rng.integers(2))]
        n = len(base)
        if request.kind == "door":
            base.append(
                base_cabinet(f"u{n}", rng, palette, float(rng.uniform(0.4, 0.6)), depth, height, f"door_{hinge}")
            )
        elif request.kind == "double_door":
            base.append(base_cabinet(f"u{n}", rng, palette, float(rng.uniform(0.7, 1.0)), depth, height, "double"))
        elif request.kind == "drawer":
            config = "drawer_door" if request.level == "top" and rng.random() < 0.3 else "drawers"
            base.append(base_cabinet(f"u{n}", rng, palette, float(rng.uniform(0.4, 0.9)), depth, height, config))
        elif request.kind in ("oven_door", "dishwasher_door"):
            base.append(drop_down_appliance(f"u{n}", rng, palette, depth, height, request.kind))
        elif request.kind in ("wall_door", "wall_double_door"):
            double = request.kind == "wall_double_door"
            width = float(rng.uniform(0.7, 0.9)) if double else float(rng.uniform(0.4, 0.6))
            base.append(filler(n, width))
            wall[n] = wall_cabinet(
                f"w{n}",
                rng,
                palette,
                width,
                float(rng.uniform(0.3, 0.35)),
                float(rng.uniform(0.6, 0.75)),
                "double" if double else f"door_{hinge}",
            )
            where[k] = ("wall", n)
            continue
        elif request.kind == "microwave_door":
            base.append(filler(n, float(rng.uniform(0.6, 0.9))))
            where[k] = ("microwave", n)
            continue
        elif request.kind == "fridge_door":
            fridge_unit = fridge(
                "fridge", rng, palette, float(rng.uniform(0.6, 0.75)), float(rng.uniform(1.75, 2.0)), hinge
            )
            where[k] = ("fridge", -1)
            continue
        where[k] = ("base", n)
    target_length = float(rng.uniform(2.2, 3.2))
    while sum(u.width for u in base) < target_length or len(base) < 3:
        base.append(filler(len(base), float(rng.uniform(0.4, 0.8))))
    for n in range(len(base)):
        if n not in wall and rng.random() < 0.5:
            config = ("door_left", "door_right", "double")[int(rng.integers(3))]
            wall[n] = wall_cabinet(
                f"w{n}",
                rng,
                palette,
                base[n].width,
                float(rng.uniform(0.3, 0.35)),
                float(rng.uniform(0.6, 0.75)),
                config,
            )
    order = [int(n) for n in rng.permutation(len(base))]
    # Requested units stay off the row ends so the camera can stand in front of them.
    requested = {n for kind, n in where.values() if kind != "fridge"}
    if len(order) > 2:
        inner = [n for n in order if n not in requested]
        ends = inner[:1] + inner[-1:] if len(inner) >= 2 else inner
        middle = [n for n in order if n not in ends]
        order = ends[:1] + middle + ends[1:]
    offset = 0.0
    fridge_left = fridge_unit is not None and rng.random() < 0.5
    if fridge_left and fridge_unit is not None:
        offset = fridge_unit.width + 0.01
    lefts = offset + np.concatenate([[0.0], np.cumsum([base[n].width for n in order])])
    units = [placed(base[n], lefts[i] + base[n].width / 2, 0.0) for i, n in enumerate(order)]
    run = float(lefts[-1] - offset)
    targets: dict[int, Front] = {}
    wall_z = float(rng.uniform(1.32, 1.82)) if varied else float(rng.uniform(1.45, 1.55))
    stone = rng.random() < 0.6
    counter = mats.textured(
        "speckle" if stone else "wood",
        mats.pick(((0.35, 0.35, 0.36), (0.8, 0.78, 0.74), (0.55, 0.45, 0.35))),
        0.8,
        paintable=not stone,  # laminate in a plain kitchen; stone keeps its grain
    )
    geoms = [
        box((offset - 0.01, -depth - 0.03, height), (offset + run + 0.01, 0.0, height + 0.035), counter),
        box(
            (offset, -0.012, height + 0.035),
            (offset + run, 0.0, wall_z),
            mats.textured("tiles", mats.pick(PAINTS), float(rng.uniform(0.4, 0.9)), paintable=True),
        ),
    ]
    micro_x = None
    for i, n in enumerate(order):
        centre = float(lefts[i]) + base[n].width / 2
        if n in wall:
            units.append(placed(wall[n], centre, 0.0, wall_z))
        for k, (kind, owner) in where.items():
            if owner != n:
                continue
            if kind == "base":
                targets[k] = _pick_front(base[n], requests[k], rng)
            elif kind == "wall":
                targets[k] = _pick_front(wall[n], requests[k], rng)
            elif kind == "microwave":
                micro_x = centre
    if micro_x is not None:
        micro = microwave("mw", rng, palette)
        units.append(placed(micro, micro_x + float(rng.uniform(-0.05, 0.05)), -0.03, height + 0.035))
        targets.update(
            {k: _pick_front(micro, requests[k], rng) for k, (kind, _) in where.items() if kind == "microwave"}
        )
    length = offset + run
    if fridge_unit is not None:
        x = fridge_unit.width / 2 if fridge_left else length + 0.01 + fridge_unit.width / 2
        units.append(placed(fridge_unit, x, 0.0))
        length = max(length, x + fridge_unit.width / 2)
        targets.update(
            {k: _pick_front(fridge_unit, requests[k], rng) for k, (kind, _) in where.items() if kind == "fridge"}
        )
    if varied:  # kettle, toaster, jars: things standing on the counter
        geoms += objects_on(
            rng, (offset + 0.05, offset + run - 0.05, -depth + 0.04, -0.08), height + 0.035, 0.3, palette.objects, 6
        )
    max_depth = max(u.depth for u in units if u.body.pos[2] < 0.5)
    fronts = tuple(f for u in units for f in u.fronts)
    return _Row(
        Body("row", (0.0, 0.0, 0.0), tuple(geoms), tuple(u.body for u in units)), length, max_depth, fronts, targets
    )


def _bedroom(mats: MaterialBank, palette: Palette, requests: tuple[PartRequest, ...]) -> _Row:
    """A sliding-door wardrobe, a chest of drawers and an open bookshelf, in random order."""
    rng = mats.rng
    pieces = {
        "wardrobe": wardrobe("wardrobe", rng, palette, float(rng.uniform(1.2, 1.8)), float(rng.uniform(2.0, 2.2))),
        "chest": chest_of_drawers("chest", rng, palette, float(rng.uniform(0.8, 1.2)), float(rng.uniform(0.75, 1.05))),
        "shelf": _bookshelf(mats, palette),
    }
    names = [str(n) for n in rng.permutation(list(pieces))]
    gaps = rng.uniform(0.1, 0.4, len(names))
    units, x = [], 0.0
    for name, gap in zip(names, gaps):
        unit = pieces[name]
        units.append(placed(unit, x + unit.width / 2, 0.0))
        x += unit.width + float(gap)
    targets = {}
    for k, request in enumerate(requests):
        source = pieces["wardrobe"] if request.kind == "sliding_door" else pieces["chest"]
        targets[k] = _pick_front(source, request, rng)
    fronts = tuple(f for u in units for f in u.fronts)
    return _Row(
        Body("row", (0.0, 0.0, 0.0), (), tuple(u.body for u in units)), x, max(u.depth for u in units), fronts, targets
    )


def _bookshelf(mats: MaterialBank, palette: Palette) -> Unit:
    """An open shelf unit full of objects (static texture for the tracker)."""
    rng = mats.rng
    width, depth, height = float(rng.uniform(0.6, 0.9)), 0.32, float(rng.uniform(1.4, 1.9))
    levels = tuple(float(z) for z in np.linspace(0.05, height - 0.3, int(rng.integers(3, 6))))
    geoms = list(carcass(width, depth, height, 0.0, palette.carcass, palette.interior, levels[1:]))
    for z in levels:
        geoms += objects_on(
            rng, (-width / 2 + 0.03, width / 2 - 0.03, 0.03, depth - 0.04), z + 0.018, 0.22, palette.objects, 5
        )
    return Unit(Body("shelf", (0.0, 0.0, 0.0), tuple(geoms)), (), width, depth, height)


def _assets(mats: MaterialBank, palette: Palette, requests: tuple[PartRequest, ...]) -> _Row:
    """One Meta-World object at human scale on a plain stand (``assets.py``), beside an open
    bookshelf, in random order."""
    rng = mats.rng
    if len(requests) != 1:
        raise ValueError(f"an assets scene holds exactly one part, got {len(requests)} requests")
    unit, meshes = asset_unit(requests[0].kind, mats, palette)
    shelf = _bookshelf(mats, palette)
    order = (unit, shelf) if rng.random() < 0.5 else (shelf, unit)
    units, x = [], 0.0
    for piece in order:
        units.append(placed(piece, x + piece.width / 2, 0.0))
        x += piece.width + float(rng.uniform(0.3, 0.6))
    return _Row(
        Body("row", (0.0, 0.0, 0.0), (), tuple(u.body for u in units)),
        x,
        max(u.depth for u in units),
        unit.fronts,
        {0: unit.fronts[0]},
        meshes,
    )


def _tiny(mats: MaterialBank, palette: Palette, requests: tuple[PartRequest, ...]) -> _Row:
    """One small cabinet with a single hinged door."""
    rng = mats.rng
    hinge = requests[0].hinge if requests and requests[0].hinge else ("left", "right")[int(rng.integers(2))]
    unit = base_cabinet("u0", rng, palette, float(rng.uniform(0.45, 0.55)), 0.45, 0.8, f"door_{hinge}")
    targets = {k: _pick_front(unit, r, rng) for k, r in enumerate(requests)}
    body = placed(unit, unit.width / 2, 0.0).body
    return _Row(Body("row", (0.0, 0.0, 0.0), (), (body,)), unit.width, unit.depth, unit.fronts, targets)


def _placement(
    arrangement: str, row: _Row, size: tuple[float, float, float], rng: np.random.Generator
) -> tuple[tuple[float, float], float, float]:
    """Where the row frame goes in the room: origin (x, y), yaw, and the largest y the camera
    may reach (in front of the row's nearest front corner, less the walk margin).

    The row frame has the wall side at y = 0 and its fronts at y = -depth, x in [0, length]."""
    lx, ly, _ = size
    if arrangement == "row":
        slack = lx - row.length - 2 * 0.3
        x_start = -lx / 2 + 0.3 + float(rng.uniform(0.0, max(slack, 0.0)))
        return (x_start, ly / 2), 0.0, ly / 2 - row.depth - WALK_MARGIN
    if arrangement == "angled":
        yaw = float(rng.choice([-1.0, 1.0]) * np.radians(rng.uniform(8.0, 25.0)))
        gap = 0.02
    elif arrangement == "island":
        yaw = float(np.radians(rng.uniform(-15.0, 15.0)))
        gap = float(rng.uniform(0.6, 1.2))
    else:
        raise ValueError(f"unknown layout {arrangement!r}")
    c, s = np.cos(yaw), np.sin(yaw)
    corners = np.array([[0.0, 0.0], [row.length, 0.0], [0.0, -row.depth], [row.length, -row.depth]])
    turned = corners @ np.array([[c, s], [-s, c]])  # rows: R(yaw) @ corner
    y0 = ly / 2 - gap - turned[:, 1].max()
    slack = lx - np.ptp(turned[:, 0]) - 2 * 0.3
    x0 = -lx / 2 + 0.3 - turned[:, 0].min() + float(rng.uniform(0.0, max(slack, 0.0)))
    return (float(x0), float(y0)), yaw, float(y0 + turned[:, 1].min()) - WALK_MARGIN


def sample_layout(
    family: str,
    requests: tuple[PartRequest, ...],
    rng: np.random.Generator,
    texture_px: int = 512,
    appearance: str = "textured",
    lighting: str = "ceiling",
    arrangement: str = "row",
) -> Layout:
    """Sample a room of the given family holding the requested fronts.

    Args:
        family: "kitchen", "bedroom" or "tiny".
        requests: the fronts that will move, in part order.
        rng: random generator (the only source of randomness).
        texture_px: side of ordinary textures in pixels (walls and floor use twice that).
        appearance: material style, one of ``room.APPEARANCES``.
        lighting: light set-up, one of ``spec.LIGHTINGS``.
        arrangement: kitchen arrangement, one of ``spec.LAYOUTS``.

    Returns:
        The scene (scene frame: z up, floor at z = 0, back wall at +y) and the target fronts.
    """
    mats = MaterialBank(rng, texture_px, appearance)
    palette = make_palette(mats)
    builders = {"kitchen": _kitchen, "bedroom": _bedroom, "tiny": _tiny, "assets": _assets}
    if family not in builders:
        raise ValueError(f"unknown scene family {family!r}; expected one of {tuple(builders)}")
    row = (
        _kitchen(mats, palette, requests, varied=True)
        if arrangement != "row"
        else builders[family](mats, palette, requests)
    )
    if family == "tiny":
        size = (3.0, 3.4, 2.5)
    else:
        size = (
            max(float(rng.uniform(4.0, 5.5)), row.length + 1.2),
            float(rng.uniform(4.6, 5.6)),
            float(rng.uniform(2.5, 2.8)),
        )
    if arrangement != "row":  # room enough for a turned row and the walk in front of it
        size = (size[0] + 0.6, size[1] + 0.5, size[2])
    lx, ly, _ = size
    (x_start, y_wall), yaw, y_walk = _placement(arrangement, row, size, rng)
    row_body = replace(row.body, pos=(x_start, y_wall, 0.0), yaw=yaw)
    room = Body("room", (0.0, 0.0, 0.0), room_geoms(mats, size))
    centre = np.array([row.length / 2, -row.depth])
    focus = (
        x_start + np.cos(yaw) * centre[0] - np.sin(yaw) * centre[1],
        y_wall + np.sin(yaw) * centre[0] + np.cos(yaw) * centre[1],
    )
    walk = (-lx / 2 + WALK_MARGIN, lx / 2 - WALK_MARGIN, -ly / 2 + WALK_MARGIN, y_walk)
    lights, ambient = vary_lighting(
        lighting, ceiling_lights(rng, size, focus), float(rng.uniform(0.3, 0.45)), size, rng
    )
    scene = Scene(
        bodies=(room, row_body),
        materials=tuple(mats.materials),
        textures=tuple(mats.textures),
        lights=lights,
        fronts=row.fronts,
        walk_area=walk,
        ambient=ambient,
        mesh_files=tuple(sorted(row.mesh_files.items())),
        description={
            "family": family,
            "room_x_m": round(lx, 3),
            "room_y_m": round(ly, 3),
            "room_z_m": round(size[2], 3),
            "appearance": appearance,
            "lighting": lighting,
            "layout": arrangement,
            **({"third_party_assets": METAWORLD_CREDIT} if row.mesh_files else {}),
            "row_yaw_deg": round(float(np.degrees(yaw)), 2),
            "row_off_wall_m": round(float(ly / 2 - y_wall), 3) if arrangement == "island" else 0.0,
        },
    )
    return Layout(scene, tuple(row.targets[k] for k in range(len(requests))))


__all__ = ["Layout", "WALK_MARGIN", "sample_layout"]
