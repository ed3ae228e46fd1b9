"""Named suites of synthetic sequences: the fixed benchmark, a quick smoke suite and the
tiny unit-test sequence; generation that skips finished sequences."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from pathlib import Path

from funrec.errors import FunrecError
from funrec.synth.sequence import generate_sequence, is_complete
from funrec.synth.spec import Interaction, PartRequest, SequenceSpec

LOGGER = logging.getLogger(__name__)

_OPEN = (Interaction(0, (0.9,)),)


def _single(
    name: str,
    seed: int,
    scene: str,
    part: PartRequest,
    frames: int,
    hand_masks: bool,
    targets: tuple[float, ...] = (0.9,),
    **family: str | float,
) -> SequenceSpec:
    """A sequence with one interaction on one part; ``family`` sets the family fields (family,
    appearance, lighting, arm, joint_speed, layout)."""
    return SequenceSpec(name, seed, scene, (part,), (Interaction(0, targets),), frames, hand_masks=hand_masks, **family)


def bench_suite() -> tuple[SequenceSpec, ...]:
    """The fixed benchmark: 12 single revolute, 8 single prismatic, 3 multi-interaction and
    2 camera-only sequences at 640x480 and 15 FPS, 90-250 frames each; about half write hand masks."""
    return (
        _single("rev_cabinet_left_00", 1001, "kitchen", PartRequest("door", "left"), 130, True),
        _single("rev_cabinet_right_00", 1002, "kitchen", PartRequest("door", "right"), 140, False),
        _single("rev_cabinet_left_01", 1003, "kitchen", PartRequest("door", "left"), 120, True, (0.6,)),
        _single("rev_double_door_00", 1004, "kitchen", PartRequest("double_door", "left"), 150, False),
        _single("rev_double_door_01", 1005, "kitchen", PartRequest("double_door", "right"), 140, True),
        _single("rev_wall_cabinet_00", 1006, "kitchen", PartRequest("wall_door", "right"), 140, True),
        _single("rev_wall_cabinet_01", 1007, "kitchen", PartRequest("wall_double_door", "left"), 150, False),
        _single("rev_fridge_00", 1008, "kitchen", PartRequest("fridge_door", "left"), 160, True),
        _single("rev_fridge_01", 1009, "kitchen", PartRequest("fridge_door", "right"), 180, False, (0.85, 0.45)),
        _single("rev_microwave_00", 1010, "kitchen", PartRequest("microwave_door"), 130, True),
        _single("rev_oven_00", 1011, "kitchen", PartRequest("oven_door"), 150, False),
        _single("rev_dishwasher_00", 1012, "kitchen", PartRequest("dishwasher_door"), 150, True),
        _single("pri_drawer_00", 2001, "kitchen", PartRequest("drawer", level="top"), 120, True),
        _single("pri_drawer_01", 2002, "kitchen", PartRequest("drawer", level="middle"), 130, False),
        _single("pri_drawer_02", 2003, "kitchen", PartRequest("drawer", level="bottom"), 140, True),
        _single("pri_drawer_03", 2004, "bedroom", PartRequest("drawer", level="top"), 120, False),
        _single("pri_drawer_04", 2005, "bedroom", PartRequest("drawer", level="bottom"), 160, True, (0.9, 0.5)),
        _single("pri_drawer_05", 2006, "kitchen", PartRequest("drawer"), 110, False, (0.7,)),
        _single("pri_wardrobe_00", 2007, "bedroom", PartRequest("sliding_door", "left"), 150, True),
        _single("pri_wardrobe_01", 2008, "bedroom", PartRequest("sliding_door", "right"), 150, False),
        SequenceSpec(
            "multi_kitchen_00",
            3001,
            "kitchen",
            (PartRequest("door"), PartRequest("drawer", level="top")),
            (Interaction(0, (0.9,)), Interaction(1, (0.8,))),
            220,
            hand_masks=True,
        ),
        SequenceSpec(
            "multi_kitchen_01",
            3002,
            "kitchen",
            (PartRequest("wall_door"), PartRequest("oven_door"), PartRequest("drawer")),
            (Interaction(0, (0.85,)), Interaction(1, (0.9,)), Interaction(2, (0.75,))),
            250,
            hand_masks=False,
        ),
        SequenceSpec(
            "multi_same_00",
            3003,
            "kitchen",
            (PartRequest("door"),),
            (Interaction(0, (0.7, 0.15)), Interaction(0, (0.95,))),
            230,
            hand_masks=True,
        ),
        SequenceSpec("static_walk_00", 4001, "kitchen", (), (), 90, hand_masks=False),
        SequenceSpec("static_walk_01", 4002, "bedroom", (), (), 100, hand_masks=True),
    )


def plain_suite() -> tuple[SequenceSpec, ...]:
    """The "plain" family: untextured painted (matte to high-gloss) furniture, appliances and
    walls, as in most real kitchens; 14 sequences, 7 of them without hand masks (the capture
    has no masks/hand/ folder)."""
    plain = {"family": "plain", "appearance": "plain"}
    return (
        _single("plain_rev_cabinet_left_00", 6001, "kitchen", PartRequest("door", "left"), 130, True, **plain),
        _single("plain_rev_cabinet_right_00", 6002, "kitchen", PartRequest("door", "right"), 140, False, **plain),
        _single("plain_rev_double_door_00", 6003, "kitchen", PartRequest("double_door", "left"), 140, True, **plain),
        _single("plain_rev_wall_cabinet_00", 6004, "kitchen", PartRequest("wall_door", "right"), 140, False, **plain),
        _single(
            "plain_rev_wall_cabinet_01", 6005, "kitchen", PartRequest("wall_double_door", "left"), 140, True, **plain
        ),
        _single("plain_rev_fridge_00", 6006, "kitchen", PartRequest("fridge_door", "left"), 160, False, **plain),
        _single("plain_rev_microwave_00", 6007, "kitchen", PartRequest("microwave_door"), 130, True, **plain),
        _single("plain_rev_oven_00", 6008, "kitchen", PartRequest("oven_door"), 150, False, **plain),
        _single("plain_rev_dishwasher_00", 6009, "kitchen", PartRequest("dishwasher_door"), 150, True, **plain),
        _single("plain_pri_drawer_00", 6010, "kitchen", PartRequest("drawer", level="top"), 120, False, **plain),
        _single("plain_pri_drawer_01", 6011, "bedroom", PartRequest("drawer", level="middle"), 130, True, **plain),
        _single("plain_pri_wardrobe_00", 6012, "bedroom", PartRequest("sliding_door", "left"), 150, False, **plain),
        _single(
            "plain_pri_drawer_02", 6013, "kitchen", PartRequest("drawer", level="bottom"), 130, True, (0.5,), **plain
        ),
        SequenceSpec("plain_static_walk_00", 6014, "kitchen", (), (), 90, hand_masks=False, **plain),
    )


def dark_suite() -> tuple[SequenceSpec, ...]:
    """The "dark" family: near-black and deep-coloured painted fronts, black glossy appliances
    and glazed wall cabinets (clear glass panes the depth sensor sees through); 8 sequences,
    half without hand masks."""
    dark = {"family": "dark", "appearance": "dark"}
    return (
        _single("dark_rev_cabinet_left_00", 7001, "kitchen", PartRequest("door", "left"), 130, True, **dark),
        _single("dark_rev_glass_wall_00", 7002, "kitchen", PartRequest("wall_door", "left"), 140, False, **dark),
        _single("dark_rev_glass_wall_01", 7003, "kitchen", PartRequest("wall_double_door", "right"), 140, True, **dark),
        _single("dark_rev_fridge_00", 7004, "kitchen", PartRequest("fridge_door", "right"), 160, False, **dark),
        _single("dark_rev_oven_00", 7005, "kitchen", PartRequest("oven_door"), 150, True, **dark),
        _single("dark_rev_microwave_00", 7006, "kitchen", PartRequest("microwave_door"), 130, False, **dark),
        _single("dark_pri_drawer_00", 7007, "kitchen", PartRequest("drawer", level="top"), 120, True, **dark),
        _single("dark_pri_wardrobe_00", 7008, "bedroom", PartRequest("sliding_door", "right"), 150, False, **dark),
    )


def lighting_suite() -> tuple[SequenceSpec, ...]:
    """The "lighting" family: plain kitchens under dim, harsh, side-window and changing light
    (one light switched during the sequence); 8 sequences, half without hand masks."""

    def lit(kind: str) -> dict[str, str]:
        return {"family": "lighting", "appearance": "plain", "lighting": kind}

    return (
        _single("light_dim_rev_cabinet_00", 8001, "kitchen", PartRequest("door", "right"), 130, True, **lit("dim")),
        _single("light_dim_pri_drawer_00", 8002, "kitchen", PartRequest("drawer", level="middle"), 120, False, **lit("dim")),
        _single("light_harsh_rev_wall_00", 8003, "kitchen", PartRequest("wall_door", "left"), 140, True, **lit("harsh")),
        _single("light_harsh_rev_dishwasher_00", 8004, "kitchen", PartRequest("dishwasher_door"), 150, False, **lit("harsh")),
        _single("light_window_rev_fridge_00", 8005, "kitchen", PartRequest("fridge_door", "left"), 160, True, **lit("window")),
        _single("light_window_pri_drawer_00", 8006, "bedroom", PartRequest("drawer", level="top"), 120, False, **lit("window")),
        _single("light_changing_rev_cabinet_00", 8007, "kitchen", PartRequest("door", "left"), 140, True, **lit("changing")),
        SequenceSpec("light_changing_static_00", 8008, "kitchen", (), (), 100, hand_masks=False, **lit("changing")),
    )


def geometry_suite() -> tuple[SequenceSpec, ...]:
    """The "geometry" family: plain kitchens whose row is turned 8-25 degrees off the wall or
    stands free (island, up to 15 degrees), small appliances on the counter, wall cabinets
    with handles at 1.4-1.9 m; the base units keep their 5 cm toe-kick recess and the counter
    its 3 cm overhang. 8 sequences, half without hand masks."""

    def shaped(layout: str) -> dict[str, str]:
        return {"family": "geometry", "appearance": "plain", "layout": layout}

    return (
        _single("geo_angled_rev_cabinet_00", 9001, "kitchen", PartRequest("door", "left"), 140, True, **shaped("angled")),
        _single("geo_angled_pri_drawer_00", 9002, "kitchen", PartRequest("drawer", level="top"), 130, False, **shaped("angled")),
        _single("geo_angled_rev_wall_00", 9003, "kitchen", PartRequest("wall_door", "right"), 140, True, **shaped("angled")),
        _single("geo_island_rev_cabinet_00", 9004, "kitchen", PartRequest("door", "right"), 140, False, **shaped("island")),
        _single("geo_island_pri_drawer_00", 9005, "kitchen", PartRequest("drawer", level="bottom"), 130, True, **shaped("island")),
        _single("geo_island_rev_wall_00", 9006, "kitchen", PartRequest("wall_double_door", "left"), 150, False, **shaped("island")),
        _single("geo_angled_rev_microwave_00", 9007, "kitchen", PartRequest("microwave_door"), 130, True, **shaped("angled")),
        _single("geo_island_rev_oven_00", 9008, "kitchen", PartRequest("oven_door"), 150, False, **shaped("island")),
    )


def person_suite() -> tuple[SequenceSpec, ...]:
    """The "person" family: plain kitchens, a rigid arm in a patterned sleeve or an arm bent at
    the elbow, slower (0.4x), faster (2.2x) and partial (25-45 %) openings; 8 sequences, half
    without hand masks."""

    def by(arm: str, speed: float = 1.0) -> dict[str, str | float]:
        return {"family": "person", "appearance": "plain", "arm": arm, "joint_speed": speed}

    return (
        _single("person_sleeve_rev_cabinet_00", 10001, "kitchen", PartRequest("door", "left"), 130, False, **by("sleeve")),
        _single("person_sleeve_pri_drawer_00", 10002, "kitchen", PartRequest("drawer", level="top"), 120, True, **by("sleeve")),
        _single("person_elbow_rev_wall_00", 10003, "kitchen", PartRequest("wall_door", "right"), 140, False, **by("elbow")),
        _single("person_elbow_pri_wardrobe_00", 10004, "bedroom", PartRequest("sliding_door", "left"), 150, True, **by("elbow")),
        _single("person_slow_rev_cabinet_00", 10005, "kitchen", PartRequest("door", "right"), 200, False, **by("sleeve", 0.4)),
        _single("person_fast_rev_fridge_00", 10006, "kitchen", PartRequest("fridge_door", "left"), 120, True, **by("elbow", 2.2)),
        _single(
            "person_partial_rev_cabinet_00", 10007, "kitchen", PartRequest("door", "left"), 130, False, (0.25,), **by("sleeve")
        ),
        _single(
            "person_partial_pri_drawer_00", 10008, "kitchen", PartRequest("drawer", level="middle"), 120, True, (0.45,), **by("proxy")
        ),
    )


def assets_suite() -> tuple[SequenceSpec, ...]:
    """The "assets" family: Meta-World's drawer, safe door and vertical and horizontal sliding
    windows (MIT License; needs an installed metaworld, see ``assets.py``) at human scale in
    plain paint in a plain room; 8 sequences, half without hand masks."""
    mw = {"family": "assets", "appearance": "plain"}
    return (
        _single("mw_drawer_00", 11001, "assets", PartRequest("mw_drawer"), 120, True, **mw),
        _single("mw_drawer_01", 11002, "assets", PartRequest("mw_drawer"), 120, False, (0.6,), **mw),
        _single("mw_door_00", 11003, "assets", PartRequest("mw_door"), 140, False, **mw),
        _single("mw_door_01", 11004, "assets", PartRequest("mw_door"), 140, True, **mw),
        _single("mw_window_00", 11005, "assets", PartRequest("mw_window"), 120, True, **mw),
        _single("mw_window_01", 11006, "assets", PartRequest("mw_window"), 120, False, **mw),
        _single("mw_window_horiz_00", 11007, "assets", PartRequest("mw_window_horiz"), 120, False, **mw),
        _single("mw_window_horiz_01", 11008, "assets", PartRequest("mw_window_horiz"), 120, True, **mw),
    )


def smoke_suite() -> tuple[SequenceSpec, ...]:
    """Three short 320x240 sequences (revolute, prismatic, camera-only) for quick end-to-end checks."""
    return (
        SequenceSpec(
            "smoke_rev_00", 5001, "kitchen", (PartRequest("door", "left"),), _OPEN, 75, 320, 240, hand_masks=True
        ),
        SequenceSpec(
            "smoke_pri_00", 5002, "kitchen", (PartRequest("drawer", level="top"),), _OPEN, 75, 320, 240, hand_masks=True
        ),
        SequenceSpec("smoke_static_00", 5003, "kitchen", (), (), 45, 320, 240, hand_masks=False),
    )


def tiny_spec(seed: int = 0) -> SequenceSpec:
    """A 24-frame 80x60 sequence of one cabinet door being opened (hand masks on), for unit tests."""
    return SequenceSpec(
        f"tiny_{seed:02d}", seed, "tiny", (PartRequest("door"),), (Interaction(0, (0.7,)),), 24, 80, 60, hand_masks=True
    )


FAMILY_SUITES: dict[str, Callable[[], tuple[SequenceSpec, ...]]] = {
    "bench": bench_suite,
    "plain": plain_suite,
    "dark": dark_suite,
    "lighting": lighting_suite,
    "geometry": geometry_suite,
    "person": person_suite,
    "assets": assets_suite,
}
"""The bench families, each a suite of its own ("bench" is the textured family)."""


def families_suite() -> tuple[SequenceSpec, ...]:
    """Every family of :data:`FAMILY_SUITES` in one suite (``funrec bench`` reports a row per family)."""
    return tuple(spec for make in FAMILY_SUITES.values() for spec in make())


SUITES: dict[str, Callable[[], tuple[SequenceSpec, ...]]] = {
    **FAMILY_SUITES,
    "families": families_suite,
    "smoke": smoke_suite,
}
"""Suite names accepted by :func:`generate_suite`."""


RESEED_STRIDE = 1_000_003
"""Seed distance between reseeded copies; a prime far above every suite seed (1001-11008)."""


def reseeded(spec: SequenceSpec, reseed: int) -> SequenceSpec:
    """``spec`` with a fresh seed: the same family, part, interaction and length, but a new room
    layout, materials, camera and hand paths. Named ``<name>_r<reseed>``; ``reseed`` 0 is ``spec``."""
    if reseed < 0:
        raise FunrecError(f"reseed must be 0 or positive, got {reseed}")
    if reseed == 0:
        return spec
    return dataclasses.replace(spec, name=f"{spec.name}_r{reseed}", seed=spec.seed + RESEED_STRIDE * reseed)


def generate_suite(
    out_dir: Path,
    suite: str = "bench",
    only: Sequence[str] | None = None,
    progress: Callable[[int, int], None] | None = None,
    scenes_only: bool = False,
    reseed: int = 0,
) -> list[Path]:
    """Generate a named suite into ``out_dir``, skipping sequences that are already complete.

    Args:
        out_dir: parent folder of the sequences.
        suite: a name of :data:`SUITES` ("bench", "plain", "smoke", ...).
        only: names of the suite's sequences to generate (default: all), as the suite names them
            (without the ``_r<K>`` of ``reseed``).
        progress: called as progress(frames_done, frames_total) over the frames still to render.
        scenes_only: only the ground-truth scenes (``generate_sequence``), no frames.
        reseed: 0 for the suite as named; K > 0 for fresh scenes of the same recipes
            (:func:`reseeded`), a held-out set nobody has tuned on.

    Returns:
        The folders of the selected sequences, in suite order.

    Raises:
        FunrecError: unknown suite or sequence names.
    """
    if suite not in SUITES:
        raise FunrecError(f"unknown suite {suite!r}; available: {sorted(SUITES)}")
    named = SUITES[suite]()
    if only is not None:
        known = {s.name for s in named}
        unknown = sorted(set(only) - known)
        if unknown:
            raise FunrecError(f"suite {suite!r} has no sequences {unknown}; it has {sorted(known)}")
        named = tuple(s for s in named if s.name in set(only))
    specs = tuple(reseeded(s, reseed) for s in named)
    out_dir = Path(out_dir)
    todo = [s for s in specs if not is_complete(out_dir / s.name, scenes_only)]
    total = sum(s.num_frames for s in todo)
    done = 0
    for spec in todo:
        LOGGER.info("generating %s (%d frames)", spec.name, spec.num_frames)
        offset = done

        def report(frames: int, _total: int, offset: int = offset) -> None:
            if progress is not None:
                progress(offset + frames, total)

        generate_sequence(spec, out_dir, report, scenes_only)
        done += spec.num_frames
    return [out_dir / s.name for s in specs]


__all__ = [
    "FAMILY_SUITES",
    "SUITES",
    "assets_suite",
    "bench_suite",
    "dark_suite",
    "families_suite",
    "generate_suite",
    "geometry_suite",
    "lighting_suite",
    "person_suite",
    "plain_suite",
    "reseeded",
    "smoke_suite",
    "tiny_spec",
]
