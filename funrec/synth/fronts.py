"""Articulable fronts (hinged, drop-down and sliding doors, drawers), their handles and the
small objects placed inside furniture.

Furniture frame (the ``unit`` frame): x to the right seen from the room, y into the unit
(towards the wall), z up; the carcass front plane is y = 0 and fronts sit just in front of
it (y < 0). Each front is a :class:`Body` whose origin lies on its joint axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from funrec.synth.scene import SEE_THROUGH_GROUP, Body, Front, Geom, Joint, box, rod, shift, vec3

FRONT_GAP = 0.001
"""Clearance between a closed front and the carcass, metres (keeps contacts out of the scene)."""
HANDLE_SHAPES = ("bar", "knob", "recessed")
"""Handle shapes the builders make."""


@dataclass(frozen=True)
class FrontStyle:
    """Materials and handle choice of one front."""

    panel: str
    """Material of the panel."""
    handle: str
    """Material of the handle."""
    handle_shape: str
    """One of :data:`HANDLE_SHAPES`."""
    inset: str = ""
    """Material of a dark inset (appliance window or recessed grip); empty for none."""
    pane: str = ""
    """Material of a clear glass pane filling a hinged door inside a frame; empty for a solid panel."""


def handle_geoms(
    shape: str, centre_surface: npt.ArrayLike, grip_axis: npt.ArrayLike, length: float, material: str, inset: str
) -> tuple[tuple[Geom, ...], npt.NDArray[np.float64]]:
    """Geoms of a handle on a front whose outer face looks along -y.

    Args:
        shape: "bar", "knob" or "recessed".
        centre_surface: (3,) point of the front's outer face under the handle centre, body frame.
        grip_axis: (3,) unit direction of the bar (x or z).
        length: bar length, metres (ignored for knobs).
        material: handle material.
        inset: material of the recessed grip's dark back plate.

    Returns:
        The geoms and the (3,) handle centre in the body frame.
    """
    c = np.asarray(centre_surface, dtype=np.float64)
    g = np.asarray(grip_axis, dtype=np.float64)
    out = np.array([0.0, -1.0, 0.0])
    if shape == "bar":
        standoff, radius = 0.032, 0.0075
        centre = c + standoff * out
        half = g * (length / 2.0)
        post = g * (length / 2.0 - 0.012)
        geoms = (
            rod(centre - half, centre + half, radius, material, "capsule"),
            rod(c + post, c + post + (standoff - 0.004) * out, 0.005, material),
            rod(c - post, c - post + (standoff - 0.004) * out, 0.005, material),
        )
        return geoms, centre
    if shape == "knob":
        centre = c + 0.03 * out
        geoms = (
            rod(c, c + 0.02 * out, 0.0055, material),
            Geom("sphere", (0.016,), vec3(centre), material),
        )
        return geoms, centre
    if shape == "recessed":
        across = np.cross(g, out)
        plate_half = g * (length / 2.0) + np.abs(across) * 0.02 + np.array([0.0, 0.002, 0.0])
        lip_centre = c + 0.012 * out + 0.018 * across
        lip_half = g * (length / 2.0) + np.abs(across) * 0.004 + np.array([0.0, 0.012, 0.0])
        geoms = (
            box(c - plate_half, c + plate_half, inset or material),
            box(lip_centre - lip_half, lip_centre + lip_half, material),
        )
        return geoms, lip_centre
    raise ValueError(f"unknown handle shape {shape!r}; expected one of {HANDLE_SHAPES}")


def hinged_door(
    name: str,
    kind: str,
    rect: tuple[float, float, float, float],
    hinge: str,
    thickness: float,
    style: FrontStyle,
    handle_z: float,
    max_angle: float,
    extra: tuple[Geom, ...] = (),
    details: dict[str, str | float] | None = None,
) -> tuple[Body, Front]:
    """A door on a vertical hinge at its left or right edge.

    Args:
        name: body name (the provisional joint is ``<name>_joint``).
        kind: part kind for the bookkeeping (door, fridge_door, microwave_door, ...).
        rect: (x0, x1, z0, z1) panel extent in the unit frame, metres.
        hinge: "left" or "right" edge, seen from the room.
        thickness: panel thickness, metres.
        style: materials and handle.
        handle_z: handle centre height in the unit frame.
        max_angle: opening limit, radians.
        extra: more geoms in the unit frame (window insets, door shelves).
        details: descriptive facts for gt.json.

    Returns:
        The door body (origin on the hinge axis at the panel's bottom outer corner) and its front.
    """
    x0, x1, z0, z1 = rect
    y_out = -FRONT_GAP - thickness
    pivot = np.array([x0 if hinge == "left" else x1, y_out, z0])
    # Opening swings the free edge towards the room (-y): about -z for a left hinge.
    axis = (0.0, 0.0, -1.0) if hinge == "left" else (0.0, 0.0, 1.0)
    handle_x = x1 - 0.05 if hinge == "left" else x0 + 0.05
    grip = np.array([0.0, 0.0, 1.0])
    bar = min(0.6, max(0.1, (z1 - z0) * 0.3)) if kind == "fridge_door" else 0.14
    handle, centre = handle_geoms(style.handle_shape, (handle_x, y_out, handle_z), grip, bar, style.handle, style.inset)
    panel = box((x0, y_out, z0), (x1, -FRONT_GAP, z1), style.panel)
    frame: tuple[Geom, ...] = ()
    if style.pane:
        panel, frame = _glazed(x0, x1, z0, z1, y_out, style)
    geoms = shift((panel, *frame, *extra, *handle), -pivot)
    joint = Joint(f"{name}_joint", "hinge", axis, (0.0, float(max_angle)))
    body = Body(name, vec3(pivot), geoms, joint=joint, sites=((f"{name}_handle", vec3(centre - pivot)),))
    facts = {
        "hinge": hinge,
        "handle_shape": style.handle_shape,
        "width_m": round(x1 - x0, 3),
        "height_m": round(z1 - z0, 3),
    }
    front = Front(kind, name, joint.name, f"{name}_handle", vec3(grip), {**facts, **(details or {})})
    return body, front


GLAZING_FRAME_M = 0.05
"""Width of the solid frame around a glass pane, metres."""


def _glazed(
    x0: float, x1: float, z0: float, z1: float, y_out: float, style: FrontStyle
) -> tuple[Geom, tuple[Geom, ...]]:
    """A glass pane spanning the door (first, so it stands for the panel's extent) and the four
    frame bars around it; the pane is set 4 mm into the frame so no face of it is coplanar with one."""
    y_in, f = -FRONT_GAP, GLAZING_FRAME_M
    pane = box((x0, y_out + 0.004, z0), (x1, y_in - 0.004, z1), style.pane)
    pane = Geom(pane.shape, pane.size, pane.pos, pane.material, group=SEE_THROUGH_GROUP)
    frame = (
        box((x0, y_out, z0), (x0 + f, y_in, z1), style.panel),
        box((x1 - f, y_out, z0), (x1, y_in, z1), style.panel),
        box((x0 + f, y_out, z0), (x1 - f, y_in, z0 + f), style.panel),
        box((x0 + f, y_out, z1 - f), (x1 - f, y_in, z1), style.panel),
    )
    return pane, frame


def drop_down_door(
    name: str,
    kind: str,
    rect: tuple[float, float, float, float],
    thickness: float,
    style: FrontStyle,
    max_angle: float,
    extra: tuple[Geom, ...] = (),
    details: dict[str, str | float] | None = None,
) -> tuple[Body, Front]:
    """A door hinged at its bottom edge on a horizontal axis (oven, dishwasher); the handle is
    a horizontal bar near the top edge."""
    x0, x1, z0, z1 = rect
    y_out = -FRONT_GAP - thickness
    pivot = np.array([(x0 + x1) / 2.0, y_out, z0])
    grip = np.array([1.0, 0.0, 0.0])
    handle, centre = handle_geoms(
        style.handle_shape, ((x0 + x1) / 2.0, y_out, z1 - 0.045), grip, (x1 - x0) * 0.7, style.handle, style.inset
    )
    panel = box((x0, y_out, z0), (x1, -FRONT_GAP, z1), style.panel)
    geoms = shift((panel, *extra, *handle), -pivot)
    # A positive rotation about +x tips the top edge towards the room.
    joint = Joint(f"{name}_joint", "hinge", (1.0, 0.0, 0.0), (0.0, float(max_angle)))
    body = Body(name, vec3(pivot), geoms, joint=joint, sites=((f"{name}_handle", vec3(centre - pivot)),))
    facts = {
        "hinge": "bottom",
        "handle_shape": style.handle_shape,
        "width_m": round(x1 - x0, 3),
        "height_m": round(z1 - z0, 3),
    }
    return body, Front(kind, name, joint.name, f"{name}_handle", vec3(grip), {**facts, **(details or {})})


def drawer(
    name: str,
    rect: tuple[float, float, float, float],
    depth: float,
    style: FrontStyle,
    box_material: str,
    contents: tuple[Geom, ...],
    handle_shape_axis: str = "x",
    details: dict[str, str | float] | None = None,
) -> tuple[Body, Front]:
    """A drawer: front panel, open box behind it and the objects it holds.

    Args:
        name: body name.
        rect: (x0, x1, z0, z1) front extent in the unit frame.
        depth: box depth behind the front, metres.
        style: materials and handle.
        box_material: material of the drawer box.
        contents: objects in the unit frame (they move with the drawer).
        handle_shape_axis: "x" for a horizontal bar, "z" for a vertical one.
        details: descriptive facts for gt.json.

    Returns:
        The drawer body (origin at the centre of the front's outer face) and its front.
    """
    x0, x1, z0, z1 = rect
    thickness = 0.019
    y_out = -FRONT_GAP - thickness
    origin = np.array([(x0 + x1) / 2.0, y_out, (z0 + z1) / 2.0])
    grip = np.array([1.0, 0.0, 0.0]) if handle_shape_axis == "x" else np.array([0.0, 0.0, 1.0])
    bar = min(0.35, max(0.1, (x1 - x0) * 0.4))
    handle, centre = handle_geoms(
        style.handle_shape, (origin[0], y_out, z1 - min(0.06, (z1 - z0) * 0.35)), grip, bar, style.handle, style.inset
    )
    side, bx0, bx1 = 0.012, x0 + 0.025, x1 - 0.025
    bz0, bz1 = z0 + 0.02, z0 + 0.02 + max(0.06, (z1 - z0) * 0.72)
    y0, y1 = -FRONT_GAP, depth
    walls = (
        box((bx0, y0, bz0), (bx1, y1, bz0 + side), box_material),
        box((bx0, y0, bz0 + side), (bx0 + side, y1, bz1), box_material),
        box((bx1 - side, y0, bz0 + side), (bx1, y1, bz1), box_material),
        box((bx0 + side, y1 - side, bz0 + side), (bx1 - side, y1, bz1), box_material),
    )
    panel = box((x0, y_out, z0), (x1, -FRONT_GAP, z1), style.panel)
    geoms = shift((panel, *walls, *handle, *contents), -origin)
    joint = Joint(f"{name}_joint", "slide", (0.0, -1.0, 0.0), (0.0, round(0.8 * depth, 4)))
    body = Body(name, vec3(origin), geoms, joint=joint, sites=((f"{name}_handle", vec3(centre - origin)),))
    facts = {
        "handle_shape": style.handle_shape,
        "width_m": round(x1 - x0, 3),
        "height_m": round(z1 - z0, 3),
        "depth_m": round(depth, 3),
    }
    return body, Front("drawer", name, joint.name, f"{name}_handle", vec3(grip), {**facts, **(details or {})})


def sliding_door(
    name: str,
    rect: tuple[float, float, float, float],
    y_back: float,
    direction: float,
    travel: float,
    style: FrontStyle,
    details: dict[str, str | float] | None = None,
) -> tuple[Body, Front]:
    """A door sliding along x in a track (wardrobe).

    Args:
        name: body name.
        rect: (x0, x1, z0, z1) panel extent in the unit frame.
        y_back: y of the panel's back face (< 0, in front of the carcass).
        direction: +1 if it opens by sliding right, -1 if left.
        travel: joint limit, metres.
        style: materials and handle (the handle sits near the trailing edge, vertical).
        details: descriptive facts for gt.json.
    """
    x0, x1, z0, z1 = rect
    thickness = 0.02
    y_out = y_back - thickness
    origin = np.array([(x0 + x1) / 2.0, y_out, (z0 + z1) / 2.0])
    grip = np.array([0.0, 0.0, 1.0])
    handle_x = x0 + 0.06 if direction > 0 else x1 - 0.06
    handle, centre = handle_geoms(
        style.handle_shape, (handle_x, y_out, origin[2]), grip, 0.3, style.handle, style.inset
    )
    panel = box((x0, y_out, z0), (x1, y_back, z1), style.panel)
    geoms = shift((panel, *handle), -origin)
    joint = Joint(f"{name}_joint", "slide", (float(np.sign(direction)), 0.0, 0.0), (0.0, round(travel, 4)))
    body = Body(name, vec3(origin), geoms, joint=joint, sites=((f"{name}_handle", vec3(centre - origin)),))
    facts = {"handle_shape": style.handle_shape, "width_m": round(x1 - x0, 3), "height_m": round(z1 - z0, 3)}
    return body, Front("sliding_door", name, joint.name, f"{name}_handle", vec3(grip), {**facts, **(details or {})})


def objects_on(
    rng: np.random.Generator,
    area: tuple[float, float, float, float],
    z: float,
    max_height: float,
    materials: tuple[str, ...],
    count: int,
) -> tuple[Geom, ...]:
    """Boxes and standing cylinders on a horizontal surface, without overlaps.

    Args:
        rng: random generator.
        area: (x0, x1, y0, y1) free rectangle of the surface, unit frame.
        z: surface height.
        max_height: tallest object, metres.
        materials: materials to pick from.
        count: number of objects tried (some may not fit).
    """
    x0, x1, y0, y1 = area
    placed: list[tuple[float, float, float]] = []
    geoms: list[Geom] = []
    for _ in range(count):
        height = float(rng.uniform(0.35, 1.0) * max_height)
        if height < 0.03:
            continue
        for _attempt in range(8):
            radius = float(rng.uniform(0.025, 0.07))
            if x1 - x0 < 2 * radius + 0.01 or y1 - y0 < 2 * radius + 0.01:
                break
            cx = float(rng.uniform(x0 + radius, x1 - radius))
            cy = float(rng.uniform(y0 + radius, y1 - radius))
            if all((cx - px) ** 2 + (cy - py) ** 2 > (radius + pr + 0.005) ** 2 for px, py, pr in placed):
                placed.append((cx, cy, radius))
                material = materials[int(rng.integers(len(materials)))]
                if rng.random() < 0.5:
                    half = radius / np.sqrt(2.0)
                    geoms.append(
                        box((cx - half, cy - half * 0.8, z), (cx + half, cy + half * 0.8, z + height), material)
                    )
                else:
                    geoms.append(Geom("cylinder", (radius * 0.85, height / 2.0), (cx, cy, z + height / 2.0), material))
                break
    return tuple(geoms)


__all__ = [
    "FRONT_GAP",
    "GLAZING_FRAME_M",
    "HANDLE_SHAPES",
    "FrontStyle",
    "drawer",
    "drop_down_door",
    "handle_geoms",
    "hinged_door",
    "objects_on",
    "sliding_door",
]
