"""Tests of funrec.query on a twin folder written by hand: one revolute door with an affordance,
one prismatic drawer without."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from funrec.errors import FormatError
from funrec.formats.affordances import Affordances, Interaction, PartAffordance, write_affordances
from funrec.formats.twin import TwinArticulation, make_part, write_articulation
from funrec.geometry.joints import joint_transform
from funrec.geometry.transforms import make_transform, transform_points
from funrec.query import QueryError, format_parts, grasp_frame, list_parts, load_affordances, query_text

AXIS, PIVOT = np.array([0.0, -1.0, 0.0]), np.array([0.3, 0.0, 1.2])
RANGE = (0.0, 1.4)
CONTACT = np.array([-0.1, 0.05, 1.18])
R_WORLD_GRASP = Rotation.from_euler("xyz", [5.0, -80.0, 90.0], degrees=True).as_matrix()
# Grasps are products of a few 4x4 matrices of unit scale: float64 round-off stays below 1e-14.
EXACT = 1e-12


@pytest.fixture()
def twin(tmp_path: Path) -> Path:
    door = make_part("part_0", "revolute", AXIS, PIVOT, [40, 41, 42], [0.0, 0.5, 1.4], RANGE)
    drawer = make_part("part_1", "prismatic", [0.0, 0.0, -1.0], None, [80, 81], [0.0, 0.3])
    write_articulation(tmp_path / "articulation.json", TwinArticulation(120, (door, drawer), static_mesh=None))
    frames = np.array([38, 39, 40, 41, 42])
    affordance = PartAffordance(
        name="part_0",
        joint_type="revolute",
        contact_point=CONTACT,
        T_world_grasp=make_transform(R_WORLD_GRASP, CONTACT),
        handle_found=True,
        interactions=(Interaction(frames, frames / 15.0, np.array([0.0, 0.0, 0.0, 0.5, 1.4])),),
        region_points=CONTACT + np.array([[0.0, 0.0, 0.0], [0.0, 0.01, 0.0]]),
        region_weights=np.array([1.0, 0.5]),
        path_states=np.linspace(*RANGE, 3),
        path_points=transform_points(np.eye(4), np.tile(CONTACT, (3, 1))),
    )
    missing = (("part_1", "the hand never came within the contact distance of it"),)
    write_affordances(tmp_path, Affordances((affordance,), missing, "detected", 15.0))
    return tmp_path


def test_list_parts_reports_every_part_with_its_contact(twin: Path) -> None:
    door, drawer = list_parts(twin)
    assert (door.name, door.joint_type, door.state_range, door.holds, door.note) == ("part_0", "revolute", RANGE, 1, "")
    np.testing.assert_array_equal(door.contact_point, CONTACT)
    assert drawer.contact_point is None and drawer.holds == 0 and "never came within" in drawer.note
    table = format_parts((door, drawer))
    assert table.splitlines()[0].split()[:2] == ["part", "joint"]
    assert "0.0 .. 80.2 deg" in table and "-0.100 +0.050 +1.180" in table and "0.000 .. 0.300 m" in table


def test_grasp_at_the_canonical_state_is_the_stored_grasp(twin: Path) -> None:
    np.testing.assert_allclose(grasp_frame(twin, "part_0", 0.0), make_transform(R_WORLD_GRASP, CONTACT), atol=EXACT)


@settings(deadline=None, max_examples=30, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(state=st.floats(*RANGE))
def test_grasp_at_a_state_is_the_joint_transform_of_the_canonical_grasp(twin: Path, state: float) -> None:
    T_world_grasp0 = grasp_frame(twin, "part_0", 0.0)
    T_world_grasp = grasp_frame(twin, "part_0", state)
    np.testing.assert_allclose(T_world_grasp, joint_transform("revolute", AXIS, PIVOT, state) @ T_world_grasp0, atol=EXACT)
    # The grasp stays on the circle of the contact point about the hinge, as a rigid frame.
    radius = np.linalg.norm(np.cross(CONTACT - PIVOT, AXIS))
    assert np.linalg.norm(np.cross(T_world_grasp[:3, 3] - PIVOT, AXIS)) == pytest.approx(radius, abs=EXACT)
    np.testing.assert_allclose(T_world_grasp[:3, :3].T @ T_world_grasp[:3, :3], np.eye(3), atol=EXACT)


def test_query_errors_list_what_is_available(twin: Path) -> None:
    with pytest.raises(QueryError, match=r"no part 'part_7'; the twin has \['part_0', 'part_1'\]"):
        grasp_frame(twin, "part_7", 0.0)
    with pytest.raises(QueryError, match=r"part 'part_1' has no affordance \(the hand never came .*\); parts with one: \['part_0'\]"):
        grasp_frame(twin, "part_1", 0.1)
    with pytest.raises(QueryError, match=r"state 2.0 of 'part_0' is outside its range \[0, 1.4\] rad"):
        grasp_frame(twin, "part_0", 2.0)
    with pytest.raises(QueryError, match="outside its range"):
        grasp_frame(twin, "part_0", float("nan"))


def test_missing_affordances_file_names_the_file(twin: Path) -> None:
    (twin / "affordances.json").unlink()
    with pytest.raises(FormatError, match=r"affordances\.json: file is missing"):
        load_affordances(twin)
    with pytest.raises(FormatError, match=r"affordances\.json: file is missing"):
        list_parts(twin)


def test_query_text_is_the_table_or_the_grasp(twin: Path) -> None:
    assert query_text(twin) == format_parts(list_parts(twin))
    text = query_text(twin, "part_0", 0.7)
    lines = text.splitlines()
    assert lines[0].startswith("part_0 at state 0.7: T_world_grasp") and len(lines) == 9
    values = np.array([[float(v) for v in line.split()] for line in lines[1:5]])
    T_world_grasp = grasp_frame(twin, "part_0", 0.7)
    np.testing.assert_allclose(values, T_world_grasp, atol=5e-5)  # printed with 4 decimals
    columns = {"position": 3, "approach": 2, "handle axis": 0, "finger axis": 1}
    for line in lines[5:]:
        label, numbers = line.split(":")
        np.testing.assert_allclose([float(v) for v in numbers.split()], T_world_grasp[:3, columns[label.strip().split(" (")[0]]], atol=5e-5)
    grasp = json.loads(query_text(twin, "part_0", 0.7, as_json=True))
    np.testing.assert_allclose(grasp["T_world_grasp"], T_world_grasp, atol=EXACT)
    np.testing.assert_allclose(grasp["approach"], T_world_grasp[:3, 2], atol=EXACT)
    np.testing.assert_allclose(grasp["handle_axis"], T_world_grasp[:3, 0], atol=EXACT)
    rows = json.loads(query_text(twin, as_json=True))
    assert [(r["name"], r["range_unit"], r["holds"]) for r in rows] == [("part_0", "rad", 1), ("part_1", "m", 0)]
    assert rows[1]["contact_point"] is None and "never came within" in rows[1]["note"]
    with pytest.raises(QueryError, match=r"a state \(0.5\) needs a part; the twin has \['part_0', 'part_1'\]"):
        query_text(twin, state=0.5)
