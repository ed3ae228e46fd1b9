"""Hand and forearm proxy: skin-coloured capsules and a palm box, posed kinematically.

Frames: ``grasp`` has its origin at the grasp point on the handle, z into the front (away
from the person), x along the handle bar and y = z x x pointing from the wrist to the
finger tips. ``forearm`` has its origin at the wrist and z pointing to the elbow.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from funrec.synth.scene import Geom, Material, Scene, Texture, rod, vec3
from funrec.synth.textures import make_texture

SKIN_TONES = ((0.87, 0.69, 0.56), (0.76, 0.57, 0.42), (0.55, 0.38, 0.26), (0.94, 0.78, 0.66))
"""RGB skin tones the proxy is drawn in."""
WRIST_IN_GRASP = np.array([0.0, -0.095, -0.03])
"""(3,) wrist position p_grasp, metres."""
FOREARM_LENGTH = 0.27
"""Forearm capsule length from the wrist towards the elbow, metres."""
UPPER_ARM_LENGTH = 0.6
"""Length of the (straight) upper-arm capsule continuing the forearm, metres; it passes the
shoulder and leaves the view at the image border like a real arm."""
ELBOW_BEND_DEG = 70.0
"""Angle between forearm and upper arm of the "elbow" arm, degrees (0: straight)."""
SLEEVE_MATERIAL = "sleeve_mat"
"""Material name of the "sleeve" arm's textured sleeve."""
FINGER_REACH = 0.027
"""How far behind the grasp point (along grasp z) the curled fingers reach, metres; handles
must stand at least this far off their front or the grasp point is moved back."""


def hand_geoms(material: str) -> tuple[Geom, ...]:
    """Palm, four two-segment curled fingers and a thumb, in the grasp frame.

    The bar of the handle runs along grasp x through the origin; the palm lies in front of it
    (grasp z < 0) and the fingers curl over it to reach behind (grasp z > 0).
    """
    geoms = [Geom("box", (0.043, 0.05, 0.013), (0.0, -0.045, -0.03), material)]
    radius = 0.0085
    for x, scale in zip((-0.03, -0.01, 0.01, 0.03), (0.85, 1.0, 0.97, 0.9)):
        knuckle = np.array([x, 0.0, -0.03])
        middle = np.array([x, 0.026 * scale, -0.014])
        tip = np.array([x, 0.02 * scale, 0.012])
        hook = np.array([x, 0.004, 0.018])
        geoms += [
            rod(knuckle, middle, radius, material, "capsule"),
            rod(middle, tip, radius, material, "capsule"),
            rod(tip, hook, radius * 0.9, material, "capsule"),
        ]
    geoms.append(rod((0.045, -0.075, -0.032), (0.04, -0.02, -0.024), 0.011, material, "capsule"))
    geoms.append(rod((0.03, -0.02, -0.024), (0.012, 0.0, -0.02), 0.0095, material, "capsule"))
    geoms.append(rod(WRIST_IN_GRASP + (0.0, 0.01, 0.0), WRIST_IN_GRASP + (0.0, 0.04, 0.0), 0.03, material, "capsule"))
    return tuple(geoms)


def forearm_geoms(material: str, arm: str = "proxy", sleeve: str = "") -> tuple[Geom, ...]:
    """The arm in the forearm frame (origin at the wrist, +z towards the shoulder, +y down for
    a level arm).

    Args:
        material: skin material.
        arm: "proxy": capsules from the wrist along +z, thickening towards the elbow, then the
            straight upper arm; "elbow": the same capsules bent :data:`ELBOW_BEND_DEG` down at
            the elbow (the elbow hangs below the wrist-shoulder line, the upper arm rises back);
            "sleeve": a rigid arm of boxes in the textured ``sleeve`` material, skin only at
            the wrist.
        sleeve: material of the sleeve (arm "sleeve").
    """
    half = FOREARM_LENGTH / 2.0
    if arm == "sleeve":
        wrist = rod((0.0, 0.0, 0.0), (0.0, 0.0, 0.04), 0.027, material, "capsule")
        fore = Geom("box", (0.04, 0.04, half), (0.0, 0.0, half + 0.03), sleeve)
        upper = Geom("box", (0.05, 0.05, UPPER_ARM_LENGTH / 2.0), (0.0, 0.0, FOREARM_LENGTH + UPPER_ARM_LENGTH / 2.0), sleeve)
        return (wrist, fore, upper)
    if arm == "elbow":
        down = np.radians(ELBOW_BEND_DEG) / 2.0
        elbow = FOREARM_LENGTH * np.array([0.0, np.sin(down), np.cos(down)])
        shoulder = elbow + UPPER_ARM_LENGTH * np.array([0.0, -np.sin(down), np.cos(down)])
        return (
            rod((0.0, 0.0, 0.0), elbow / 2.0, 0.028, material, "capsule"),
            rod(elbow / 2.0, elbow, 0.035, material, "capsule"),
            rod(elbow, shoulder, 0.04, material, "capsule"),
        )
    if arm != "proxy":
        raise ValueError(f"unknown arm {arm!r}; expected 'proxy', 'elbow' or 'sleeve'")
    return (
        rod((0.0, 0.0, 0.0), (0.0, 0.0, half), 0.028, material, "capsule"),
        rod((0.0, 0.0, half), (0.0, 0.0, FOREARM_LENGTH), 0.035, material, "capsule"),
        rod((0.0, 0.0, FOREARM_LENGTH), (0.0, 0.0, FOREARM_LENGTH + UPPER_ARM_LENGTH), 0.04, material, "capsule"),
    )


def with_sleeve(scene: Scene, rng: np.random.Generator, texture_px: int) -> Scene:
    """The scene with the sleeve's patterned texture and material added (arm "sleeve")."""
    color = vec3(rng.uniform(0.15, 0.85, 3))
    kind = ("wallpaper", "tiles", "speckle")[int(rng.integers(3))]
    texture = Texture("sleeve", make_texture(kind, rng, max(64, texture_px // 2), color))
    material = Material(SLEEVE_MATERIAL, (1.0, 1.0, 1.0, 1.0), "sleeve", 0.12, 0.1, 0.1)
    return replace(scene, textures=(*scene.textures, texture), materials=(*scene.materials, material))


def skin_color(rng: np.random.Generator) -> tuple[float, float, float, float]:
    """A random skin tone as RGBA."""
    tone = np.asarray(SKIN_TONES[int(rng.integers(len(SKIN_TONES)))]) * rng.uniform(0.95, 1.05)
    return (*vec3(np.clip(tone, 0.0, 1.0)), 1.0)


__all__ = [
    "ELBOW_BEND_DEG",
    "FINGER_REACH",
    "SLEEVE_MATERIAL",
    "FOREARM_LENGTH",
    "SKIN_TONES",
    "UPPER_ARM_LENGTH",
    "WRIST_IN_GRASP",
    "forearm_geoms",
    "hand_geoms",
    "skin_color",
    "with_sleeve",
]
