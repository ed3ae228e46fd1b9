"""Materials and procedural textures of a scene, the room shell (floor, walls, ceiling,
skirting, pictures, rug) and the ceiling lights."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from funrec.synth.scene import Geom, Light, Material, Texture, box, vec3
from funrec.synth.textures import make_texture
from funrec.synth.units import Palette
from funrec.typed import FloatArray

WALL = 0.1
"""Wall, floor and ceiling slab thickness, metres."""
WOODS = ((0.62, 0.42, 0.26), (0.45, 0.3, 0.2), (0.78, 0.62, 0.45), (0.55, 0.36, 0.22), (0.86, 0.74, 0.58))
"""Base colours of wood textures (RGB in [0, 1])."""
PAINTS = (
    (0.86, 0.84, 0.78),
    (0.7, 0.78, 0.82),
    (0.82, 0.74, 0.66),
    (0.74, 0.8, 0.7),
    (0.9, 0.88, 0.84),
    (0.6, 0.64, 0.7),
)
"""Base colours of painted surfaces."""
APPLIANCES = ((0.88, 0.88, 0.86), (0.7, 0.71, 0.72), (0.3, 0.3, 0.32))
"""Appliance shell colours (white, steel, black)."""
METALS = ((0.75, 0.75, 0.77, 1.0), (0.12, 0.12, 0.13, 1.0), (0.72, 0.58, 0.32, 1.0))
"""Handle metals (RGBA: steel, black, brass)."""


APPEARANCES = ("textured", "plain", "dark")
"""Material styles of a scene: "textured" gives every surface a procedural texture; "plain"
paints furniture, appliances, walls and ceiling in flat matte or glossy colours (floor, counter
tops, pictures, rugs and stored objects keep their textures, as in a real kitchen); "dark" is
plain with near-black or deep-coloured fronts, black glossy appliances and glazed wall
cabinets (clear glass the depth sensor sees through)."""
DARKS = ((0.05, 0.05, 0.055), (0.1, 0.1, 0.11), (0.08, 0.1, 0.16), (0.07, 0.12, 0.09), (0.16, 0.12, 0.1))
"""Base colours of dark fronts (black, charcoal, navy, bottle green, dark brown)."""
BLACK_APPLIANCES = ((0.04, 0.04, 0.045), (0.1, 0.1, 0.1))
"""Appliance shell colours of the dark appearance (black glass, black steel)."""
CLEAR_GLASS = (0.8, 0.9, 0.92, 0.18)
"""RGBA of clear glass panes (mostly transparent, a slight green-blue tint)."""
GLOSS_CHOICES = ((0.08, 0.05), (0.3, 0.3), (0.7, 0.8), (0.9, 0.95))
"""(specular, shininess) of flat paint: matte, eggshell, gloss lacquer, high-gloss laminate."""


class MaterialBank:
    """Collects the textures and materials of one scene while it is being built."""

    def __init__(self, rng: np.random.Generator, texture_px: int, appearance: str = "textured") -> None:
        if appearance not in APPEARANCES:
            raise ValueError(f"unknown appearance {appearance!r}; expected one of {APPEARANCES}")
        self.rng = rng
        self.texture_px = texture_px
        self.appearance = appearance
        self.textures: list[Texture] = []
        self.materials: list[Material] = []

    def textured(
        self,
        kind: str,
        color: tuple[float, float, float],
        tile_m: float,
        big: bool = False,
        specular: float = 0.15,
        paintable: bool = False,
    ) -> str:
        """Add a procedural texture of ``kind`` and a material using it; returns the material name.

        Args:
            kind: texture kind (see ``textures.TEXTURE_KINDS``).
            color: (3,) base RGB in [0, 1].
            tile_m: metres per texture repeat on surfaces.
            big: twice the usual resolution (floors and walls).
            specular: MuJoCo specular reflectance.
            paintable: in a "plain" bank the surface is flat paint of ``color`` (matte or
                glossy, drawn from the texture's own stream) instead of a texture.
        """
        name = f"{kind}_{len(self.textures)}"
        size = self.texture_px * (2 if big else 1)
        # A child stream per texture: the layout does not depend on the texture resolution,
        # and a plain scene has the same layout as the textured scene of the same seed.
        texture_rng = np.random.default_rng(int(self.rng.integers(1 << 62)))
        if paintable and self.appearance != "textured":
            gloss, shine = GLOSS_CHOICES[int(texture_rng.integers(len(GLOSS_CHOICES)))]
            return self.plain((*color, 1.0), gloss, shine)
        self.textures.append(Texture(name, make_texture(kind, texture_rng, size, color)))
        self.materials.append(Material(f"mat_{name}", (1.0, 1.0, 1.0, 1.0), name, tile_m, specular))
        return f"mat_{name}"

    def plain(self, rgba: tuple[float, float, float, float], specular: float = 0.5, shininess: float = 0.5) -> str:
        """Add an untextured material (metal, glass, trim); returns its name."""
        name = f"plain_{len(self.materials)}"
        self.materials.append(Material(name, rgba, None, 1.0, specular, shininess))
        return name

    def pick(self, colors: tuple[tuple[float, float, float], ...], jitter: float = 0.04) -> tuple[float, float, float]:
        """One of ``colors`` with a little random variation."""
        base = np.asarray(colors[int(self.rng.integers(len(colors)))])
        return vec3(np.clip(base + self.rng.normal(0.0, jitter, 3), 0.05, 0.97))


def make_palette(mats: MaterialBank) -> Palette:
    rng = mats.rng
    dark = mats.appearance == "dark"  # same draws as the other appearances: only colours change
    woods, paints = (DARKS, DARKS) if dark else (WOODS, PAINTS)
    fronts = tuple(
        mats.textured("wood", mats.pick(woods), float(rng.uniform(0.5, 0.8)), paintable=True)
        if rng.random() < 0.6
        else mats.textured("plaster", mats.pick(paints, 0.02 if dark else 0.04), float(rng.uniform(0.4, 0.7)),
                           specular=0.3, paintable=True)
        for _ in range(2)
    )
    carcass = mats.textured("wood", mats.pick(WOODS), 0.6, paintable=True) if rng.random() < 0.5 else fronts[0]
    appliance = mats.textured(
        "brushed", mats.pick(BLACK_APPLIANCES if dark else APPLIANCES, 0.02), 0.5, specular=0.4, paintable=True
    )
    objects = tuple(
        mats.textured(
            ("wallpaper", "speckle", "tiles")[k % 3], vec3(rng.uniform(0.15, 0.95, 3)), float(rng.uniform(0.1, 0.2))
        )
        for k in range(4)
    )
    return Palette(
        carcass=carcass,
        interior=mats.textured("plaster", mats.pick(PAINTS), 0.4, paintable=True),
        fronts=fronts,
        handles=tuple(mats.plain(METALS[k]) for k in rng.permutation(len(METALS))[:2]),
        appliance=appliance,
        appliance_inside=mats.textured("plaster", (0.8, 0.82, 0.84), 0.3, paintable=True),
        glass=mats.plain((0.05, 0.06, 0.07, 1.0), 0.8, 0.8),
        objects=objects,
        pane=mats.plain(CLEAR_GLASS, 0.9, 0.95) if dark else "",
    )


def room_geoms(mats: MaterialBank, size: tuple[float, float, float]) -> tuple[Geom, ...]:
    """Floor, ceiling, four walls, skirting boards, framed pictures and maybe a rug."""
    rng = mats.rng
    lx, ly, lz = size
    floor = mats.textured(
        "planks" if rng.random() < 0.6 else "tiles",
        mats.pick(WOODS + ((0.7, 0.7, 0.68),)),
        float(rng.uniform(1.2, 2.0)),
        big=True,
    )
    walls = mats.textured(
        "wallpaper" if rng.random() < 0.5 else "plaster",
        mats.pick(PAINTS),
        float(rng.uniform(1.5, 2.5)),
        big=True,
        paintable=True,
    )
    ceiling = mats.textured("plaster", (0.92, 0.92, 0.9), 2.0, paintable=True)
    skirting = mats.plain(vec3(rng.uniform(0.3, 0.9, 3)) + (1.0,), 0.2, 0.2)
    x0, x1, y0, y1 = -lx / 2, lx / 2, -ly / 2, ly / 2
    geoms = [
        box((x0 - WALL, y0 - WALL, -WALL), (x1 + WALL, y1 + WALL, 0.0), floor),
        box((x0 - WALL, y0 - WALL, lz), (x1 + WALL, y1 + WALL, lz + WALL), ceiling),
        box((x0 - WALL, y0 - WALL, 0.0), (x0, y1 + WALL, lz), walls),
        box((x1, y0 - WALL, 0.0), (x1 + WALL, y1 + WALL, lz), walls),
        box((x0, y0 - WALL, 0.0), (x1, y0, lz), walls),
        box((x0, y1, 0.0), (x1, y1 + WALL, lz), walls),
        box((x0, y0, 0.0), (x0 + 0.015, y1, 0.08), skirting),
        box((x1 - 0.015, y0, 0.0), (x1, y1, 0.08), skirting),
        box((x0, y0, 0.0), (x1, y0 + 0.015, 0.08), skirting),
    ]
    frame = mats.plain((0.1, 0.08, 0.07, 1.0), 0.3, 0.3)
    for _ in range(int(rng.integers(2, 5))):
        art = mats.textured(
            ("speckle", "wallpaper", "tiles")[int(rng.integers(3))],
            vec3(rng.uniform(0.2, 0.9, 3)),
            float(rng.uniform(0.3, 0.6)),
        )
        w, h, zc = float(rng.uniform(0.4, 0.9)), float(rng.uniform(0.3, 0.7)), float(rng.uniform(1.3, 1.8))
        side = int(rng.integers(3))
        if side < 2:  # left or right wall
            x = x0 if side == 0 else x1
            sign = 1.0 if side == 0 else -1.0
            yc = float(rng.uniform(y0 + w, y1 - 1.0 - w))
            geoms.append(
                box(
                    (x, yc - w / 2 - 0.03, zc - h / 2 - 0.03),
                    (x + sign * 0.02, yc + w / 2 + 0.03, zc + h / 2 + 0.03),
                    frame,
                )
            )
            geoms.append(
                box((x + sign * 0.02, yc - w / 2, zc - h / 2), (x + sign * 0.025, yc + w / 2, zc + h / 2), art)
            )
        else:  # wall behind the starting camera
            xc = float(rng.uniform(x0 + w, x1 - w))
            geoms.append(
                box(
                    (xc - w / 2 - 0.03, y0, zc - h / 2 - 0.03), (xc + w / 2 + 0.03, y0 + 0.02, zc + h / 2 + 0.03), frame
                )
            )
            geoms.append(box((xc - w / 2, y0 + 0.02, zc - h / 2), (xc + w / 2, y0 + 0.025, zc + h / 2), art))
    if rng.random() < 0.6:
        rug = mats.textured(
            ("wallpaper", "tiles", "speckle")[int(rng.integers(3))],
            vec3(rng.uniform(0.2, 0.8, 3)),
            float(rng.uniform(0.5, 1.0)),
        )
        w, d = float(rng.uniform(1.2, 2.2)), float(rng.uniform(0.8, 1.6))
        xc, yc = float(rng.uniform(x0 + w / 2 + 0.2, x1 - w / 2 - 0.2)), float(rng.uniform(y0 + 0.3 + d / 2, 0.0))
        geoms.append(box((xc - w / 2, yc - d / 2, 0.0), (xc + w / 2, yc + d / 2, 0.006), rug))
    return tuple(geoms)


def ceiling_lights(
    rng: np.random.Generator, size: tuple[float, float, float], focus: tuple[float, float]
) -> tuple[Light, ...]:
    """Two or three ceiling spots (the first, near the furniture, casts shadows)."""
    lx, ly, lz = size
    lights = []
    count = int(rng.integers(2, 4))
    warmth = float(rng.uniform(-0.08, 0.08))
    for k in range(count):
        if k == 0:
            x, y = focus[0] + float(rng.uniform(-0.6, 0.6)), focus[1] - float(rng.uniform(0.8, 1.6))
        else:
            x, y = float(rng.uniform(-lx / 2 + 0.5, lx / 2 - 0.5)), float(rng.uniform(-ly / 2 + 0.5, ly / 2 - 0.8))
        intensity = float(rng.uniform(0.45, 0.75)) / np.sqrt(count / 2.0)
        diffuse = vec3(np.clip(intensity * np.array([1.0 + warmth, 1.0, 1.0 - warmth]), 0, 1))
        tilt = rng.normal(0.0, 0.15, 2)
        lights.append(
            Light(
                f"light_{k}",
                "spot",
                (x, y, lz - 0.05),
                vec3((tilt[0], tilt[1] + (0.25 if k == 0 else 0.0), -1.0)),
                diffuse,
                cast_shadow=k == 0,
                cutoff_deg=float(rng.uniform(70, 88)),
            )
        )
    return tuple(lights)


def vary_lighting(
    kind: str,
    lights: tuple[Light, ...],
    ambient: float,
    size: tuple[float, float, float],
    rng: np.random.Generator,
) -> tuple[tuple[Light, ...], float]:
    """The ceiling lights and ambient level changed for a light set-up of ``spec.LIGHTINGS``
    ("ceiling" and "changing" keep them; "changing" varies them per frame at render time)."""
    if kind in ("ceiling", "changing"):
        return lights, ambient

    def scaled(light: Light, factor: float, **changes: object) -> Light:
        diffuse = vec3(np.clip(np.asarray(light.diffuse) * factor, 0.0, 1.0))
        return replace(light, diffuse=diffuse, **changes)  # type: ignore[arg-type]

    if kind == "dim":
        return tuple(scaled(light, float(rng.uniform(0.35, 0.55))) for light in lights), ambient * 0.35
    if kind == "harsh":
        return (scaled(lights[0], float(rng.uniform(1.5, 1.9)), cutoff_deg=float(rng.uniform(40, 55))),), 0.08
    if kind == "window":
        lx, ly, lz = size
        side = float(rng.choice([-1.0, 1.0]))
        sun = Light(
            "window",
            "directional",
            (-side * lx / 2, float(rng.uniform(-ly / 4, ly / 4)), lz * 0.8),
            vec3((side, float(rng.uniform(-0.3, 0.3)), -float(rng.uniform(0.3, 0.7)))),
            vec3(np.array([1.0, 0.97, 0.9]) * float(rng.uniform(0.6, 0.85))),
            cast_shadow=True,
        )
        return (sun, scaled(lights[0], 0.5, cast_shadow=False)), ambient * 0.6
    raise ValueError(f"unknown lighting {kind!r}")


def light_schedule(kind: str, count: int, frames: int, rng: np.random.Generator) -> FloatArray:
    """(F, L) factor on each light's diffuse colour at each frame: all ones except for
    "changing", where one light is switched off or on (over 3 frames) at 30-70 % of the
    sequence and the others drift by up to +-25 % with a slow sine."""
    scale = np.ones((frames, count))
    if kind != "changing" or count == 0:
        return scale
    t = np.arange(frames) / max(frames - 1, 1)
    switched = int(rng.integers(count))
    at = float(rng.uniform(0.3, 0.7))
    step = np.clip((t - at) * (frames - 1) / 3.0, 0.0, 1.0)
    off = 0.12
    scale[:, switched] = 1.0 - (1.0 - off) * step if rng.random() < 0.5 else off + (1.0 - off) * step
    for k in range(count):
        if k != switched:
            scale[:, k] = 1.0 + float(rng.uniform(0.1, 0.25)) * np.sin(2 * np.pi * (t * rng.uniform(0.5, 1.5) + rng.uniform()))
    return scale


__all__ = [
    "APPEARANCES",
    "APPLIANCES",
    "BLACK_APPLIANCES",
    "CLEAR_GLASS",
    "DARKS",
    "GLOSS_CHOICES",
    "METALS",
    "PAINTS",
    "WALL",
    "WOODS",
    "MaterialBank",
    "ceiling_lights",
    "light_schedule",
    "make_palette",
    "vary_lighting",
    "room_geoms",
]
