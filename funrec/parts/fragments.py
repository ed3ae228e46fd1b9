"""Fragment construction: split a capture into static and dynamic (interaction) fragments from
scene change that the camera motion does not explain, and fragments.json.

The paper asks a video-language model which fragments show an interaction; here the evidence is
geometric: :func:`funrec.parts.scene_change.scene_change` gives, per pair of frames a few steps apart,
the fraction of surface that moved away although the camera poses say it should still be there.
Frames with enough of it, grown by hysteresis, closed over short pauses (longer ones while the
hand stays in view), kept when long enough and padded, are dynamic; the rest is static. With hand
masks, a dynamic fragment also needs the hand in view. The joint type of each dynamic fragment
comes from the articulation fitted to its tracks (:mod:`funrec.parts.articulation`), and its final
span from the fitted part's motion (:func:`motion_span`).

fragments.json is read and written by :mod:`funrec.formats.fragments`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from funrec.formats.fragments import Fragment, Fragments
from funrec.typed import BoolArray, FloatArray


@dataclass(frozen=True)
class FragmentConfig:
    """Settings of :func:`find_fragments`; durations in seconds."""

    enter_fraction: float = 0.01
    """A frame pair in which this fraction of the tested surface moved away starts a dynamic
    fragment: measured at the default scene-change margins, opening doors and drawers peak at 2-15 %
    (synthetic bench and smoke suite), camera-only walks stay below 0.2 % and a real Kinect
    recording (TUM fr1_xyz, tracked poses) below 0.5 %."""
    stay_fraction: float = 0.003
    """...and the fragment continues while pairs keep at least this fraction (hysteresis)."""
    merge_gap_s: float = 1.0
    """Dynamic spans separated by a shorter static gap are one interaction (the hand reverses
    the motion, or regrips)."""
    hand_gap_s: float = 3.0
    """...and so are spans separated by a gap up to this long throughout which the hand stays in
    view: the hand pauses at full opening before closing the part again (measured on the
    synthetic bench: 0.7 s without scene change while the hand held a door open)."""
    min_duration_s: float = 0.5
    """Shorter dynamic spans are dropped: an interaction moves a part for longer than this."""
    padding_s: float = 0.2
    """Dynamic fragments are grown by this at both ends: the hand holds the part a few frames
    before it starts and after it stops moving (measured 2-4 frames on the synthetic bench)."""
    state_change_fraction: float = 0.05
    """Once a part is fitted to a dynamic fragment, the fragment is trimmed to the frames where the
    part's state is more than this fraction of its travel away from its rest states (before and
    after), padded by ``padding_s``: scene change also shows the arm reaching in and out when the
    capture has no hand masks (measured ~1 s on each side on the synthetic bench)."""
    min_rest_s: float = 0.5
    """...a boundary of that span counts only when the part was followed at rest for this long
    beyond it; otherwise the scene-change boundary stays."""
    min_hand_fraction: float = 0.5
    """With hand masks, a dynamic fragment needs a visible hand in at least this fraction of its
    frames (the person's hand moves the part)."""


def _spans(active: BoolArray) -> list[tuple[int, int]]:
    """Inclusive (first, last) runs of True."""
    edges = np.diff(np.r_[0, active.astype(np.int8), 0])
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1, strict=True))


def dynamic_spans(evidence: FloatArray, fps: float, lag_frames: int, config: FragmentConfig = FragmentConfig(),  # noqa: B008
                  hand_visible: BoolArray | None = None) -> list[tuple[int, int]]:
    """Dynamic (first, last) frame spans from per-pair scene-change evidence.

    Hysteresis (pairs with ``enter_fraction`` start a span, it extends over pairs with
    ``stay_fraction``); pair i covers frames i .. i + ``lag_frames``. Spans closer than
    ``merge_gap_s`` are joined (closer than ``hand_gap_s`` with the hand in view throughout),
    shorter than ``min_duration_s`` dropped, then padded by ``padding_s`` and, with
    ``hand_visible`` (F,), kept only where the hand is in view in ``min_hand_fraction`` of it.
    """
    F, lag = len(evidence), max(lag_frames, 0)
    strong, weak = evidence >= config.enter_fraction, evidence >= config.stay_fraction
    spans = [(a, min(b + lag, F - 1)) for a, b in _spans(weak) if strong[a : b + 1].any()]
    joined: list[tuple[int, int]] = []
    for a, b in spans:
        gap = a - joined[-1][1] - 1 if joined else 0
        held = hand_visible is not None and gap < config.hand_gap_s * fps and bool(hand_visible[a - gap : a].all())
        if joined and (gap < config.merge_gap_s * fps or held):
            joined[-1] = (joined[-1][0], max(b, joined[-1][1]))
        else:
            joined.append((a, b))
    pad = int(round(config.padding_s * fps))
    out: list[tuple[int, int]] = []
    for a, b in joined:
        if b - a + 1 < config.min_duration_s * fps:
            continue
        a, b = max(0, a - pad), min(F - 1, b + pad)
        if hand_visible is not None and np.mean(hand_visible[a : b + 1]) < config.min_hand_fraction:
            continue
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], b)
        else:
            out.append((a, b))
    return [(int(a), int(b)) for a, b in out]


def evidence_span(evidence: FloatArray, fps: float, lag_frames: int, first: int, last: int,
                  config: FragmentConfig = FragmentConfig()) -> tuple[int, int] | None:  # noqa: B008 (frozen)
    """The scene-change runs (pairs with at least ``stay_fraction``, each covering its pair's
    ``lag_frames``) that overlap frames ``first`` .. ``last``, padded by ``padding_s``; None when
    none does. Where a part was seen moving, these are its motion's scene change, and runs apart
    from them (the arm reaching in or out when there are no hand masks) are left out."""
    F, lag = len(evidence), max(lag_frames, 0)
    runs = [(a, min(b + lag, F - 1)) for a, b in _spans(np.asarray(evidence) >= config.stay_fraction)
            if a <= last and b + lag >= first]
    if not runs:
        return None
    pad = int(round(config.padding_s * fps))
    return max(0, int(runs[0][0]) - pad), min(F - 1, int(runs[-1][1]) + pad)


def _rest_state(side: FloatArray, travel: float) -> float:
    """Median of the states of one side of a motion (``side[-1]`` the far end from the motion)
    within a quarter of the travel of that far end: the part at rest, not the ramp into it."""
    return float(np.median(side[np.abs(side - side[-1]) <= 0.25 * travel]))


def motion_span(frames: npt.ArrayLike, states: npt.ArrayLike, fps: float,
                config: FragmentConfig = FragmentConfig(),  # noqa: B008 (frozen)
                evidence: FloatArray | None = None, lag_frames: int = 0) -> tuple[int | None, int | None]:
    """Where a fitted part started and stopped moving, where its states show it.

    The start is the last frame before the motion passes half its travel whose state is within
    ``state_change_fraction`` of the travel of the median state before that, minus ``padding_s``;
    it is known only when the part was followed at rest for ``min_rest_s`` before it (else None:
    its tracks may have started late).
    The end likewise, after the motion last passes half its travel. With the capture's scene-change
    ``evidence``, a side the states do not show comes from the scene-change runs that overlap the
    frames where the part was seen moving (:func:`evidence_span`): a door's tracks are often lost
    as it swings open, before it stops.

    Args:
        frames: (F_k,) increasing frame indices of the part's states.
        states: (F_k,) joint states at those frames (rad or m).
        fps: frame rate, frames per second.
        config: thresholds.
        evidence: optional (F,) scene-change fraction per frame pair of the capture.
        lag_frames: frames between the two frames of a pair.

    Returns:
        (first, last) frames, each None where neither the states nor the evidence show it.
    """
    frames, states = np.asarray(frames, dtype=np.int64), np.asarray(states, dtype=np.float64)
    travel = float(np.ptp(states)) if len(states) else 0.0
    if travel <= 0.0:
        return None, None
    tolerance, middle = config.state_change_fraction * travel, 0.5 * (states.min() + states.max())
    # the rest states before (after) the motion: those before it first crosses (after it last
    # crosses) half its travel, near their rest state: a step of a few % of the travel while the
    # hand grips the part (seen in refined states) is not the motion
    first_past = int(np.flatnonzero((states > middle) != (states[0] > middle))[0])
    last_before = int(np.flatnonzero((states > middle) != (states[-1] > middle))[-1])
    before, after = states[:first_past], states[last_before + 1 :]
    still_before = np.abs(states - _rest_state(before[::-1], travel)) <= tolerance
    still_after = np.abs(states - _rest_state(after, travel)) <= tolerance
    near_before, near_after = np.flatnonzero(still_before[:first_past]), np.flatnonzero(still_after[last_before + 1 :])
    left = int(near_before[-1]) if near_before.size else first_past - 1
    right = last_before + 1 + (int(near_after[0]) if near_after.size else 0)
    pad, rest = int(round(config.padding_s * fps)), config.min_rest_s * fps
    # a boundary counts only when the part stayed at rest beyond it, for at least min_rest_s and up
    # to the end of its states (a door held open a moment, then closed, is still in its interaction)
    at_rest_before = frames[left] - frames[0] >= rest and bool(still_before[: left + 1].all())
    at_rest_after = frames[-1] - frames[right] >= rest and bool(still_after[right:].all())
    first = int(frames[left]) - pad if at_rest_before else None
    last = int(frames[right]) + pad if at_rest_after else None
    # seen moving: from the start of the motion to the last clear state step (a door held open a
    # moment and then closed moved again after the rest found above)
    steps = np.flatnonzero(np.abs(np.diff(states)) > 0.25 * tolerance)
    moved_until = max(right - 1, int(steps[-1]) + 1 if steps.size else 0)
    seen = None if evidence is None else evidence_span(evidence, fps, lag_frames, int(frames[left + 1]),
                                                       int(frames[moved_until]), config)
    if seen is not None:
        first, last = seen[0] if first is None else first, seen[1] if last is None else last
    return first, last


def fragments_from_spans(spans: list[tuple[int, int]], frame_count: int, parts: list[str | None] | None = None,
                         reasons: list[str | None] | None = None) -> tuple[Fragment, ...]:
    """Consecutive fragments covering ``frame_count`` frames: the dynamic spans (sorted, disjoint,
    inclusive) with their ``parts`` names (and, where a part is None, the ``reasons`` why), and
    static fragments between them."""
    parts = [None] * len(spans) if parts is None else parts
    reasons = [None] * len(spans) if reasons is None else reasons
    out: list[Fragment] = []
    start = 0
    for (a, b), part, reason in zip(spans, parts, reasons, strict=True):
        if a > start:
            out.append(Fragment(len(out), "static", start, a - 1))
        out.append(Fragment(len(out), "dynamic", a, b, part, reason if part is None else None))
        start = b + 1
    if start < frame_count:
        out.append(Fragment(len(out), "static", start, frame_count - 1))
    return tuple(out)


def find_fragments(
    evidence: FloatArray,
    fps: float,
    lag_frames: int,
    hand_visible: BoolArray | None = None,
    config: FragmentConfig = FragmentConfig(),  # noqa: B008 (frozen, immutable default)
) -> Fragments:
    """Split a capture into static and dynamic fragments from its scene-change evidence.

    Args:
        evidence: (F,) scene-change fraction of the frame pair starting at each frame
            (:func:`funrec.parts.scene_change.scene_change`).
        fps: frame rate, frames per second.
        lag_frames: frames between the two frames of a pair.
        hand_visible: optional (F,) bool, True where the hand is in view (from hand masks).
        config: thresholds.

    Returns:
        :class:`Fragments`; dynamic fragments have no part name yet.
    """
    evidence = np.asarray(evidence, dtype=np.float64)
    F = len(evidence)
    if hand_visible is not None and np.shape(hand_visible) != (F,):
        raise ValueError(f"hand_visible must be ({F},) like the evidence, got {np.shape(hand_visible)}")
    spans = dynamic_spans(evidence, fps, lag_frames, config, hand_visible)
    return Fragments(fragments_from_spans(spans, F), F, float(fps), evidence)


__all__ = ["FragmentConfig", "dynamic_spans", "evidence_span", "find_fragments", "fragments_from_spans", "motion_span"]
