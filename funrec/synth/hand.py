"""Hand and forearm proxy: skin-coloured capsules and a palm box, posed kinematically.

Frames: ``grasp`` has its origin at the grasp point on the handle, z into the front (away
from the person), x along the handle bar and y = z x x pointing from the wrist to the
finger tips. ``forearm`` has its origin at the wrist and z pointing to the elbow.
"""

from __future__ import annotations

import numpy as np

from funrec.synth.scene import Geom, rod, vec3

SKIN_TONES = ((0.87, 0.69, 0.56), (0.76, 0.57, 0.42), (0.55, 0.38, 0.26), (0.94, 0.78, 0.66))
"""RGB skin tones the proxy is drawn in."""
WRIST_IN_GRASP = np.array([0.0, -0.095, -0.03])
"""(3,) wrist position p_grasp, metres."""
FOREARM_LENGTH = 0.27
"""Forearm capsule length from the wrist towards the elbow, metres."""
UPPER_ARM_LENGTH = 0.6
"""Length of the (straight) upper-arm capsule continuing the forearm, metres; it passes the
shoulder and leaves the view at the image border like a real arm."""
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


def forearm_geoms(material: str) -> tuple[Geom, ...]:
    """The arm in the forearm frame: capsules from the wrist (origin) along +z, thickening
    towards the elbow, then the upper arm."""
    half = FOREARM_LENGTH / 2.0
    return (
        rod((0.0, 0.0, 0.0), (0.0, 0.0, half), 0.028, material, "capsule"),
        rod((0.0, 0.0, half), (0.0, 0.0, FOREARM_LENGTH), 0.035, material, "capsule"),
        rod((0.0, 0.0, FOREARM_LENGTH), (0.0, 0.0, FOREARM_LENGTH + UPPER_ARM_LENGTH), 0.04, material, "capsule"),
    )


def skin_color(rng: np.random.Generator) -> tuple[float, float, float, float]:
    """A random skin tone as RGBA."""
    tone = np.asarray(SKIN_TONES[int(rng.integers(len(SKIN_TONES)))]) * rng.uniform(0.95, 1.05)
    return (*vec3(np.clip(tone, 0.0, 1.0)), 1.0)


__all__ = [
    "FINGER_REACH",
    "FOREARM_LENGTH",
    "SKIN_TONES",
    "UPPER_ARM_LENGTH",
    "WRIST_IN_GRASP",
    "forearm_geoms",
    "hand_geoms",
    "skin_color",
]
