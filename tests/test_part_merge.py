"""Merging the parts of two fragments that are one part (a door opened twice)."""

from __future__ import annotations

import dataclasses

import numpy as np

from funrec.geometry.joints import joint_transforms
from funrec.parts.articulation import JointEvidence, PartEstimate
from funrec.parts.part_merge import canonical_part_points, merge_parts, merge_two, rest_state, same_part
from funrec.parts.point_tracks import PointTracks

AXIS = np.array([0.0, 1.0, 0.0])
PIVOT = np.array([0.0, 0.0, 1.8])
_EVIDENCE = JointEvidence(0.01, 0.01, 0.005, 0.0, 0.0, 1.0, 0.01)


def _door_tracks(states: np.ndarray, rng: np.random.Generator, offset: np.ndarray | None = None, count: int = 50,
                 axis: np.ndarray = AXIS, pivot: np.ndarray = PIVOT) -> np.ndarray:
    """(F, count, 3) points of a 0.5 m door leaf at the given states (3 mm noise)."""
    offset = np.zeros(3) if offset is None else offset
    x = np.c_[rng.uniform(0.05, 0.5, count), rng.uniform(-0.3, 0.3, count), np.full(count, 1.8)] + offset
    T = joint_transforms("revolute", axis, pivot + offset, states)
    return np.einsum("fij,nj->fni", T[:, :3, :3], x) + T[:, None, :3, 3] + rng.normal(0, 0.003, (len(states), count, 3))


def _estimate(joint_type: str, axis: np.ndarray, pivot: np.ndarray | None, frames: np.ndarray, states: np.ndarray,
              tracks: np.ndarray) -> PartEstimate:
    """A stage-3 estimate over ``frames`` with states from its first frame (as per fragment)."""
    return PartEstimate(joint_type, axis, pivot, frames, states - states[0], np.zeros(len(frames), bool), tracks,
                        _EVIDENCE, float(len(tracks)), None)


def _same(earlier: PartEstimate, later: PartEstimate, tracks: PointTracks) -> bool:
    return same_part(earlier, later, canonical_part_points(earlier, tracks), canonical_part_points(later, tracks))


def _merge(parts: list[PartEstimate], tracks: PointTracks) -> tuple[list[PartEstimate], list[int]]:
    return merge_parts(parts, [canonical_part_points(p, tracks) for p in parts])


def _two_openings() -> tuple[np.ndarray, PointTracks]:
    """A door opened to 1.2 rad, closed to 0.3 (frames 10-50), left, then opened to 1.8 (frames
    100-130); its states and the tracks of the door over 140 frames."""
    F = 140
    t = np.arange(F, dtype=np.float64)
    states = np.interp(t, [0, 10, 30, 50, 100, 130, 139], [0, 0, 1.2, 0.3, 0.3, 1.8, 1.8])
    p = _door_tracks(states, np.random.default_rng(0))
    return states, PointTracks(p, np.zeros((*p.shape[:2], 2)), np.ones(p.shape[:2], bool))


def test_door_opened_twice_becomes_one_part_with_both_ranges() -> None:
    true_states, tracks = _two_openings()
    all_tracks = np.arange(tracks.num_tracks)
    first = _estimate("revolute", AXIS, PIVOT, np.arange(5, 56), true_states[5:56], all_tracks)
    # the second fragment's fit found the axis the other way round (its sign is arbitrary)
    second = _estimate("revolute", -AXIS, PIVOT, np.arange(95, 136), -true_states[95:136], all_tracks)
    assert _same(first, second, tracks)
    # the door rested at 0.3 rad; stage 3 lost it early (its states end at 1.0), the geometry tells
    lost = _estimate("revolute", AXIS, PIVOT, np.arange(5, 26), true_states[5:26], all_tracks)
    assert abs(rest_state(lost, second, canonical_part_points(lost, tracks), canonical_part_points(second, tracks)) - 0.3) < 0.01  # as above
    merged, owner = _merge([first, second], tracks)
    assert owner == [0, 0] and len(merged) == 1
    part = merged[0]
    np.testing.assert_array_equal(part.frames, np.arange(5, 136))
    sign = np.sign(part.axis_world @ AXIS)
    # exact states went in; the rest state between the openings is found from the tracks (50
    # points, 3 mm noise, levers 5-50 cm: ~1 mrad), so 0.01 rad (0.6 deg) bounds the merged states
    np.testing.assert_allclose(sign * part.states, true_states[5:136] - true_states[5], atol=0.01)
    assert part.interpolated[60:90].all() and not part.interpolated[:51].any()
    assert np.ptp(part.states) > 1.7  # the union of both ranges: 0 .. 1.8 rad


def test_parallel_door_elsewhere_is_another_part() -> None:
    true_states, tracks = _two_openings()
    rng = np.random.default_rng(1)
    # a second door 0.8 m to the side, hinge axis parallel, opened in frames 100-130
    other = _door_tracks(true_states, rng, offset=np.array([0.8, 0.0, 0.0]))
    p = np.concatenate([tracks.p_world, other], axis=1)
    both = PointTracks(p, np.zeros((*p.shape[:2], 2)), np.ones(p.shape[:2], bool))
    first = _estimate("revolute", AXIS, PIVOT, np.arange(5, 56), true_states[5:56], np.arange(50))
    second = _estimate("revolute", AXIS, PIVOT + [0.8, 0, 0], np.arange(95, 136), true_states[95:136], np.arange(50, 100))
    assert not _same(first, second, both)
    merged, owner = _merge([first, second], both)
    assert owner == [0, 1] and len(merged) == 2


def test_parallel_drawers_are_told_apart_by_their_place() -> None:
    F = 100
    s = np.interp(np.arange(F, dtype=np.float64), [0, 10, 30, 60, 80, 99], [0, 0, 0.3, 0.3, 0.3, 0.3])
    rng = np.random.default_rng(2)
    axis = np.array([0.0, 0.0, -1.0])
    x_top = np.c_[rng.uniform(-0.2, 0.2, 40), rng.uniform(-0.05, 0.05, 40), np.full(40, 2.0)]
    x_low = x_top + [0.0, 0.25, 0.0]  # the drawer below: same axis, 25 cm lower
    p_top = x_top[None] + s[:, None, None] * axis
    p_low = np.broadcast_to(x_low, (F, 40, 3)).copy()
    p_low[60:] += (s[:, None, None] * axis)[:40]  # opened later by the same amount
    p = np.concatenate([p_top, p_low], axis=1)
    tracks = PointTracks(p, np.zeros((F, 80, 2)), np.ones((F, 80), bool))
    top = _estimate("prismatic", axis, None, np.arange(5, 35), s[5:35], np.arange(40))
    low = _estimate("prismatic", axis, None, np.arange(65, 95), s[5:35], np.arange(40, 80))
    assert not _same(top, low, tracks)


def _door_parts(first: tuple[int, int], second: tuple[int, int]) -> tuple[PartEstimate, PartEstimate, PointTracks, np.ndarray]:
    """Stage-3 estimates of the door of :func:`_two_openings` over two frame ranges (exact joint)."""
    true_states, tracks = _two_openings()
    every = np.arange(tracks.num_tracks)
    parts = [_estimate("revolute", AXIS, PIVOT, np.arange(a, b), true_states[a:b], every) for a, b in (first, second)]
    return parts[0], parts[1], tracks, true_states


def test_joint_type_and_axis_must_agree() -> None:
    first, second, tracks, _ = _door_parts((5, 56), (95, 136))
    tilted = np.array([np.sin(0.3), np.cos(0.3), 0.0])  # 17 deg off, above the 8 deg gate
    assert not _same(first, dataclasses.replace(second, axis_world=tilted), tracks)
    slide = dataclasses.replace(second, joint_type="prismatic", pivot_world=None)
    assert not _same(first, slide, tracks)
    far = dataclasses.replace(second, pivot_world=PIVOT + [0.2, 0.0, 0.0])  # axis lines 20 cm apart
    assert not _same(first, far, tracks)


def test_overlapping_spans_take_the_later_states_after_the_earlier_end() -> None:
    first, second, _, true_states = _door_parts((5, 80), (70, 136))
    part = merge_two(first, second)
    np.testing.assert_array_equal(part.frames, np.arange(5, 136))
    np.testing.assert_allclose(part.states, true_states[5:136] - true_states[5], atol=1e-9)
