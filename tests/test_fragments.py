"""Fragment detection on synthetic world-frame tracks, fragments.json round trip."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from funrec.errors import FormatError
from funrec.formats.fragments import Fragments, read_fragments, write_fragments
from funrec.parts.fragments import (
    FragmentConfig,
    dynamic_spans,
    evidence_span,
    find_fragments,
    fragments_from_spans,
    motion_span,
)

FPS = 15.0


def test_quiet_capture_has_no_dynamic_fragment() -> None:
    # camera-only walks on the synthetic bench stay below 0.2 % scene change (the stay threshold
    # is 0.3 %); add 0.2 % noise
    evidence = np.random.default_rng(0).uniform(0.0, 0.002, 90)
    fragments = find_fragments(evidence, FPS, 3)
    assert fragments.dynamic == ()
    assert [(f.kind, f.first, f.last) for f in fragments.fragments] == [("static", 0, 89)]


def test_two_interactions_give_two_dynamic_fragments() -> None:
    evidence = np.zeros(180)
    evidence[30:48] = 0.03  # pairs 30..47 cover frames 30..50
    evidence[120:138] = 0.02
    fragments = find_fragments(evidence, FPS, 3)
    pad = round(FragmentConfig().padding_s * FPS)
    assert [(f.first, f.last) for f in fragments.dynamic] == [(30 - pad, 50 + pad), (120 - pad, 140 + pad)]
    assert [f.kind for f in fragments.fragments] == ["static", "dynamic", "static", "dynamic", "static"]
    assert fragments.fragments[-1].last == 179


def test_hysteresis_gap_merging_and_minimum_duration() -> None:
    config = FragmentConfig(padding_s=0.0, merge_gap_s=1.0, min_duration_s=0.5, enter_fraction=0.01, stay_fraction=0.004)
    evidence = np.zeros(200)
    evidence[10:20] = 0.005  # weak only: never enters
    evidence[40:50] = 0.02
    evidence[50:55] = 0.005  # weak after strong: the span continues (hysteresis)
    evidence[58:62] = 0.02  # 3-frame gap (< 15): joined to the previous span
    evidence[70:75] = 0.005  # weak only, even within the gap: never enters
    evidence[100:104] = 0.05  # 4 frames < 0.5 s: dropped
    evidence[150:170] = 0.012
    assert dynamic_spans(evidence, FPS, 0, config) == [(40, 61), (150, 169)]
    assert dynamic_spans(evidence, FPS, 2, config) == [(40, 63), (150, 171)]  # pair i covers i .. i + lag


def test_hand_in_view_bridges_a_longer_gap_and_gates_fragments() -> None:
    config = FragmentConfig(padding_s=0.0, merge_gap_s=1.0, hand_gap_s=3.0, min_duration_s=0.5)
    evidence = np.zeros(120)
    evidence[20:30] = 0.02
    evidence[55:65] = 0.02  # 25-frame gap: joined only while the hand stays in view
    evidence[95:110] = 0.02
    hand = np.zeros(120, dtype=bool)
    hand[15:70] = True  # no hand at the third span: not an interaction
    assert dynamic_spans(evidence, FPS, 0, config) == [(20, 29), (55, 64), (95, 109)]
    assert dynamic_spans(evidence, FPS, 0, config, hand) == [(20, 64)]
    with pytest.raises(ValueError, match="hand_visible"):
        find_fragments(evidence, FPS, 0, hand[:-1], config)


def test_motion_span_only_where_the_part_was_seen_at_rest() -> None:
    config = FragmentConfig(padding_s=0.0, state_change_fraction=0.05, min_rest_s=0.5)
    frames = np.arange(20, 100)
    states = np.interp(frames, [20, 40, 60, 99], [0.0, 0.0, 1.0, 1.0])  # moves over frames 40-60
    first, last = motion_span(frames, states, FPS, config)
    # the state passes 5 % of the travel (0.05, i.e. 1 frame of the 20-frame ramp) at frame 42
    # and is last that far from the end state at frame 58; the span keeps one frame more each side
    assert (first, last) == (41, 59)
    # followed only from frame 35 (5 frames < 0.5 s of rest before the motion): start unknown
    assert motion_span(frames[15:], states[15:], FPS, config) == (None, 59)
    assert motion_span(frames, np.zeros(len(frames)), FPS, config) == (None, None)


def test_side_the_states_miss_comes_from_the_scene_change_of_the_motion() -> None:
    # no hand masks: the arm reaching in (frames 10-19) and out (70-79) is scene change too,
    # separated from the part's motion (frames 38-55) by quiet gaps, as on the synthetic bench
    config = FragmentConfig(padding_s=0.0, state_change_fraction=0.05, min_rest_s=0.5)
    evidence = np.zeros(100)
    evidence[10:20], evidence[38:56], evidence[70:80] = 0.03, 0.10, 0.03
    assert evidence_span(evidence, FPS, 3, 45, 50, config) == (38, 58)  # the run 38-55 and its lag of 3
    assert evidence_span(evidence, FPS, 3, 60, 65, config) is None
    # the part's tracks are lost at frame 50, mid-motion: the states show the start (at rest
    # from frame 20; the state first passes 5 % of the travel at frame 41, the span keeps frame 40),
    # and the end comes from the motion's run, not from the arm leaving
    frames = np.arange(20, 51)
    states = np.interp(frames, [20, 40, 50], [0.0, 0.0, 0.5])
    assert motion_span(frames, states, FPS, config) == (40, None)
    assert motion_span(frames, states, FPS, config, evidence, 3) == (40, 58)


def test_fragments_cover_the_capture_and_round_trip(tmp_path: Path) -> None:
    parts = ["part_0", None, "part_0"]
    fragments = Fragments(fragments_from_spans([(0, 9), (30, 40), (60, 99)], 100, parts), 100, FPS, np.zeros(100))
    assert [(f.kind, f.first, f.last, f.part) for f in fragments.fragments] == [
        ("dynamic", 0, 9, "part_0"), ("static", 10, 29, None), ("dynamic", 30, 40, None), ("static", 41, 59, None),
        ("dynamic", 60, 99, "part_0")]
    write_fragments(tmp_path, fragments)
    back = read_fragments(tmp_path / "fragments.json")
    assert back.fragments == fragments.fragments and back.frame_count == 100 and back.fps == FPS


def test_bad_fragments_file_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "fragments.json"
    path.write_text('{"format": "funrec-fragments/0", "fragments": []}')
    with pytest.raises(FormatError, match="fragments.json.*funrec-fragments/1"):
        read_fragments(path)
    path.write_text('{"format": "funrec-fragments/1", "frame_count": 10, "fps": 15, '
                    '"fragments": [{"index": 0, "kind": "moving", "first": 0, "last": 9}]}')
    with pytest.raises(FormatError, match="fragments.json.*kind"):
        read_fragments(path)


def test_fragments_must_tile_the_capture() -> None:
    tiles = fragments_from_spans([(5, 9)], 20)
    with pytest.raises(ValueError, match="end at frame"):
        Fragments(tiles, 30, FPS, np.zeros(30))
    with pytest.raises(ValueError, match="start at frame"):
        Fragments(tuple(dataclasses.replace(f, first=f.first + 1) if f.index == 1 else f for f in tiles), 20, FPS, np.zeros(20))


def test_motion_span_ignores_a_small_step_before_the_motion() -> None:
    # refined drawer states on multi_kitchen_01 (no hand masks) stepped by 8 % of the travel while
    # the arm reached in, 34 frames before the drawer moved; the start must be the drawer's
    config = FragmentConfig(padding_s=0.0, state_change_fraction=0.05, min_rest_s=0.5)
    frames = np.arange(164, 250)
    states = np.interp(frames, [164, 169, 170, 203, 215, 249], [0.0, 0.0, 0.028, 0.032, 0.345, 0.345])
    # 5 % of the 0.345 m travel is 1.7 cm: the ramp reaches the end within it at frame 215 (the
    # span keeps that frame) and stays; before the motion the part was not at rest throughout
    # (the step), so the start comes from the scene-change run of the motion, not the arm's
    assert motion_span(frames, states, FPS, config) == (None, 215)
    evidence = np.zeros(250)
    evidence[166:172], evidence[203:213] = 0.02, 0.08  # arm reaching in, drawer moving
    assert motion_span(frames, states, FPS, config, evidence, 3) == (203, 215)
