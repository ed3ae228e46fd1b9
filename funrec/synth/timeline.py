"""When things happen in a sequence: walks, reaches, grasps, joint strokes, releases.

Phase durations are sampled around natural values and then fitted to the requested number
of frames: walking, standing and looking around absorb the slack first; only when the
interactions alone do not fit are they sped up (at most :data:`MAX_SPEEDUP` times).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from funrec.synth.spec import SequenceSpec

MAX_SPEEDUP = 4.0
"""Largest factor by which reaching and joint motions may be sped up to fit a short sequence."""
WALK_SPEED_MAX = 1.3
"""Fastest walking speed used when time is short, metres per second."""


@dataclass(frozen=True)
class Stroke:
    """One minimum-jerk joint motion."""

    part: int
    """Part index."""
    t0: float
    """Start time, seconds."""
    t1: float
    """End time, seconds."""
    start: float
    """Joint state at t0 (radians or metres)."""
    end: float
    """Joint state at t1."""


@dataclass(frozen=True)
class Hold:
    """The hand's visit to one part, in seconds: reach from rest to in front of the handle,
    approach it, hold it (the part moves only in [t_grasp, t_release]), back off, withdraw."""

    part: int
    """Part index."""
    t_reach: float
    """The hand leaves its rest pose."""
    t_approach: float
    """The hand is in front of the handle."""
    t_grasp: float
    """The hand closes on the handle."""
    t_release: float
    """The hand lets go."""
    t_back: float
    """The hand is back in front of the handle."""
    t_clear: float
    """The hand is back at rest."""


@dataclass(frozen=True)
class Timeline:
    """The schedule of one sequence (times in seconds from the first frame)."""

    walks: tuple[tuple[float, float], ...]
    """(start, end) of the walk (or idle wait) before each interaction."""
    holds: tuple[Hold, ...]
    """One per interaction, in order."""
    strokes: tuple[Stroke, ...]
    """Joint motions in temporal order."""
    t_observe: float
    """Start of the final look-around."""
    duration: float
    """Length of the sequence (frames / fps)."""


def schedule(
    spec: SequenceSpec,
    joint_types: tuple[str, ...],
    uppers: tuple[float, ...],
    walk_lengths: tuple[float, ...],
    rng: np.random.Generator,
) -> Timeline:
    """Schedule the interactions of ``spec``.

    Args:
        spec: the sequence.
        joint_types: joint type of each part.
        uppers: upper joint limit of each part (targets are fractions of it).
        walk_lengths: distance walked before each interaction, metres (0 = stay).
        rng: random generator.

    Raises:
        ValueError: the interactions cannot fit into the sequence even when sped up.
    """
    duration = spec.num_frames / spec.fps
    state = [0.0] * len(uppers)
    fixed: list[list[float]] = []  # per interaction: reach, approach, grip, strokes/pauses..., after, release, withdraw
    plans: list[list[tuple[float, float]]] = []  # per interaction: (start, end) joint states per stroke
    for interaction in spec.interactions:
        k = interaction.part
        speed = (rng.uniform(0.9, 1.3) if joint_types[k] == "revolute" else rng.uniform(0.22, 0.35)) * spec.joint_speed
        phases = [rng.uniform(0.7, 1.0), rng.uniform(0.25, 0.4), rng.uniform(0.15, 0.3)]
        strokes = []
        for j, target in enumerate(interaction.targets):
            end = float(target) * uppers[k]
            phases.append(max(0.6, abs(end - state[k]) / speed) if end != state[k] else 0.3)
            if j + 1 < len(interaction.targets):
                phases.append(interaction.pause_s)
            strokes.append((state[k], end))
            state[k] = end
        phases += [rng.uniform(0.1, 0.3), rng.uniform(0.25, 0.4), rng.uniform(0.5, 0.8)]
        fixed.append([float(p) for p in phases])
        plans.append(strokes)
    walk_nominal = [
        (length / rng.uniform(0.8, 1.0) + 0.5) if length > 0 else rng.uniform(0.3, 0.8) for length in walk_lengths
    ]
    walk_min = [(length / WALK_SPEED_MAX + 0.3) if length > 0 else 0.1 for length in walk_lengths]
    settle_nominal, observe_nominal = float(rng.uniform(0.3, 0.8)), float(rng.uniform(0.8, 1.6))
    flex_nominal = np.array([settle_nominal, *walk_nominal, observe_nominal])
    flex_min = np.array([0.1, *walk_min, 0.3])
    fixed_total = sum(sum(p) for p in fixed)
    speedup = 1.0
    if fixed_total + flex_min.sum() > duration:
        speedup = fixed_total / max(duration - flex_min.sum(), 1e-9)
        if duration <= flex_min.sum() or speedup > MAX_SPEEDUP:
            needed = int(np.ceil((fixed_total / MAX_SPEEDUP + flex_min.sum()) * spec.fps))
            raise ValueError(
                f"{spec.name}: {spec.num_frames} frames are too few for its interactions; need at least {needed}"
            )
        flex = flex_min
    elif fixed_total + flex_nominal.sum() > duration:
        share = (duration - fixed_total - flex_min.sum()) / (flex_nominal.sum() - flex_min.sum())
        flex = flex_min + share * (flex_nominal - flex_min)
    else:
        # Slack: walk up to 1.6x slower, stand a little longer, look around for the rest.
        slack = duration - fixed_total - flex_nominal.sum()
        flex = flex_nominal.copy()
        walk_extra = np.minimum(flex[1:-1] * 0.6, slack * 0.4 * flex[1:-1] / max(flex[1:-1].sum(), 1e-9))
        flex[1:-1] += walk_extra
        settle_extra = min(1.0, 0.2 * slack)
        flex[0] += settle_extra
        flex[-1] += slack - walk_extra.sum() - settle_extra
    scale = 1.0 / speedup
    t = float(flex[0])
    walks, holds, strokes = [], [], []
    for i, interaction in enumerate(spec.interactions):
        walks.append((t, t + float(flex[1 + i])))
        t += float(flex[1 + i])
        phases = [p * scale for p in fixed[i]]
        t_reach = t
        t_approach = t_reach + phases[0]
        t_grasp = t_approach + phases[1]
        t = t_grasp + phases[2]
        for j, (start, end) in enumerate(plans[i]):
            strokes.append(Stroke(interaction.part, t, t + phases[3 + 2 * j], start, end))
            t += phases[3 + 2 * j]
            if j + 1 < len(plans[i]):
                t += phases[4 + 2 * j]
        t_release = t + phases[-3]
        t_back = t_release + phases[-2]
        t = t_back + phases[-1]
        holds.append(Hold(interaction.part, t_reach, t_approach, t_grasp, t_release, t_back, t))
    return Timeline(tuple(walks), tuple(holds), tuple(strokes), t, duration)


__all__ = ["MAX_SPEEDUP", "WALK_SPEED_MAX", "Hold", "Stroke", "Timeline", "schedule"]
