"""What one synthetic sequence shows: scene family, the parts that move, the interactions on
them, image size and sensor switches. Plain frozen data; everything random comes from ``seed``."""

from __future__ import annotations

from dataclasses import dataclass

from funrec.synth.room import APPEARANCES
from funrec.synth.scene import PART_KINDS

SCENE_FAMILIES: dict[str, tuple[str, ...]] = {
    "kitchen": (
        "door",
        "double_door",
        "wall_door",
        "wall_double_door",
        "drawer",
        "fridge_door",
        "microwave_door",
        "oven_door",
        "dishwasher_door",
    ),
    "bedroom": ("sliding_door", "drawer"),
    "assets": ("mw_drawer", "mw_door", "mw_window", "mw_window_horiz"),
    "tiny": ("door",),
}
"""Scene families and the part kinds each can hold."""
LIGHTINGS = ("ceiling", "dim", "harsh", "window", "changing")
"""Light set-ups: "ceiling" (2-3 ceiling spots, the default), "dim" (half the light, low
ambient), "harsh" (one strong shadowing spot, little fill), "window" (a bright low directional
light from one side plus one ceiling spot) and "changing" (ceiling spots whose brightness
changes during the sequence: one is switched off or on, the others drift)."""
ARMS = ("proxy", "sleeve", "elbow")
"""Arms: "proxy" (skin capsules, the default), "sleeve" (a rigid box arm in a patterned
textured sleeve) and "elbow" (skin capsules bent at the elbow)."""
LAYOUTS = ("row", "angled", "island", "corner")
"""Kitchen arrangements: "row" (one row against the back wall, the default), "angled" (the row
turned 8-25 degrees off the wall, so no front is axis-aligned), "island" (the row stands free,
0.6-1.2 m off the wall and turned up to 15 degrees) and "corner" (an L: a second row with
fronts on a side wall)."""
DRAWER_LEVELS = ("top", "middle", "bottom")
"""Allowed :attr:`PartRequest.level` values."""


@dataclass(frozen=True)
class PartRequest:
    """A front the scene must contain because an interaction moves it."""

    kind: str
    """One of ``scene.PART_KINDS`` (door, drawer, fridge_door, sliding_door, ...)."""
    hinge: str | None = None
    """Side-hinged doors: "left" or "right" hinge (for double doors: which leaf); sliding
    doors: "left" or "right" panel; None picks at random."""
    level: str | None = None
    """Drawers: "top", "middle" or "bottom" of the stack; None picks at random."""

    def __post_init__(self) -> None:
        if self.kind not in PART_KINDS:
            raise ValueError(f"unknown part kind {self.kind!r}; expected one of {PART_KINDS}")
        if self.hinge not in (None, "left", "right"):
            raise ValueError(f"hinge must be 'left', 'right' or None, got {self.hinge!r}")
        if self.level not in (None, *DRAWER_LEVELS):
            raise ValueError(f"level must be one of {DRAWER_LEVELS} or None, got {self.level!r}")


@dataclass(frozen=True)
class Interaction:
    """The hand grasps a part, drives it through successive targets, then lets go."""

    part: int
    """Index into :attr:`SequenceSpec.parts` (ground-truth name part_<index>)."""
    targets: tuple[float, ...]
    """Successive joint targets as fractions of the part's upper limit, each in [0, 1]; the
    joint moves from its current state to each in turn with a minimum-jerk profile,
    e.g. (0.9,) opens, (0.8, 0.3) opens then closes part way."""
    pause_s: float = 0.4
    """Hold between successive targets, seconds."""

    def __post_init__(self) -> None:
        if not self.targets or any(not 0.0 <= t <= 1.0 for t in self.targets):
            raise ValueError(f"targets must be a non-empty tuple of fractions in [0, 1], got {self.targets}")
        if self.pause_s < 0.0:
            raise ValueError(f"pause_s must be >= 0, got {self.pause_s}")


@dataclass(frozen=True)
class SequenceSpec:
    """One synthetic RGB-D sequence with ground truth; deterministic for its seed."""

    name: str
    """Folder name of the sequence, e.g. rev_cabinet_left_00."""
    seed: int
    """Seed of every random choice (scene, textures, motion, sensor noise)."""
    scene: str
    """Scene family: "kitchen", "bedroom" or "tiny" (see :data:`SCENE_FAMILIES`)."""
    parts: tuple[PartRequest, ...]
    """Fronts that move; parts[k] becomes ground-truth part_k. Empty for camera-only sequences."""
    interactions: tuple[Interaction, ...]
    """Interactions in temporal order (a part may be used more than once)."""
    num_frames: int
    """Number of frames F."""
    width: int = 640
    """Image width W, pixels."""
    height: int = 480
    """Image height H, pixels."""
    fps: float = 15.0
    """Frame rate, frames per second."""
    hand_masks: bool = True
    """Write masks/hand/ into the capture (ground-truth hand masks are always written)."""
    noise: bool = True
    """Apply the Kinect-like depth and RGB noise; False writes exact (mm-quantised) depth."""
    family: str = "textured"
    """Bench family the sequence belongs to (``funrec bench`` reports one row per family)."""
    appearance: str = "textured"
    """Material style: "textured" (every surface textured), "plain" (flat matte or glossy
    paint on furniture, appliances and walls) or "dark" (near-black fronts and appliances,
    glazed wall cabinets); see ``room.APPEARANCES``."""
    lighting: str = "ceiling"
    """Light set-up, one of :data:`LIGHTINGS`."""
    arm: str = "proxy"
    """The person's arm, one of :data:`ARMS`."""
    joint_speed: float = 1.0
    """Factor on the sampled joint speed (0.3-1.3 rad/s revolute, 0.22-0.35 m/s prismatic):
    below 1 slower openings, above 1 faster ones (short sequences may speed them up further)."""
    layout: str = "row"
    """Furniture arrangement, one of :data:`LAYOUTS`."""

    def __post_init__(self) -> None:
        if not self.name or "/" in self.name or self.name.startswith("."):
            raise ValueError(f"name must be a plain folder name, got {self.name!r}")
        if self.scene not in SCENE_FAMILIES:
            raise ValueError(
                f"{self.name}: unknown scene family {self.scene!r}; expected one of {tuple(SCENE_FAMILIES)}"
            )
        for request in self.parts:
            if request.kind not in SCENE_FAMILIES[self.scene]:
                raise ValueError(
                    f"{self.name}: a {self.scene} scene cannot hold a {request.kind}; it holds {SCENE_FAMILIES[self.scene]}"
                )
        for interaction in self.interactions:
            if not 0 <= interaction.part < len(self.parts):
                raise ValueError(
                    f"{self.name}: interaction on part {interaction.part}, but only {len(self.parts)} parts"
                )
        unused = set(range(len(self.parts))) - {i.part for i in self.interactions}
        if unused:
            raise ValueError(f"{self.name}: parts {sorted(unused)} are never interacted with")
        for value, allowed, what in (
            (self.lighting, LIGHTINGS, "lighting"),
            (self.arm, ARMS, "arm"),
            (self.layout, LAYOUTS, "layout"),
        ):
            if value not in allowed:
                raise ValueError(f"{self.name}: unknown {what} {value!r}; expected one of {allowed}")
        if self.layout != "row" and self.scene != "kitchen":
            raise ValueError(f"{self.name}: layout {self.layout!r} needs a kitchen scene, got {self.scene!r}")
        if not 0.1 <= self.joint_speed <= 5.0:
            raise ValueError(f"{self.name}: joint_speed must be in [0.1, 5], got {self.joint_speed}")
        if self.appearance not in APPEARANCES:
            raise ValueError(f"{self.name}: unknown appearance {self.appearance!r}; expected one of {APPEARANCES}")
        if not self.family or not self.family.replace("_", "").isalnum():
            raise ValueError(f"{self.name}: family must be a plain word, got {self.family!r}")
        if self.num_frames < 8 or self.width < 16 or self.height < 16 or self.fps <= 0:
            raise ValueError(f"{self.name}: need >= 8 frames, >= 16x16 pixels and fps > 0")


__all__ = ["ARMS", "DRAWER_LEVELS", "LAYOUTS", "LIGHTINGS", "SCENE_FAMILIES", "Interaction", "PartRequest", "SequenceSpec"]
