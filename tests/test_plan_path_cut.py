"""'open' cut where the whole-body IK loses the handle late on the path (``plan._search_or_cut``): the path is cut a
margin before the state missed, as where the arm's reach ends, unless the miss came early or the part would fall on
once let go there. The search itself is replaced: these tests are about what is done with its outcome."""

from __future__ import annotations

import time

import numpy as np
import pytest

from funrec.errors import PlanningError
from funrec_robot import build_mujoco_model, default_robot_path, load_robot
from funrec_robot import plan as planner
from funrec_robot.plan import PlanConfig
from funrec_robot.robot_geometry import measure_robot
from funrec_robot.scene import part_joint
from funrec_robot.task_sources import task_from_ground_truth
from funrec_robot.whole_body import PathNotReached
from tests.helpers.robot_scenes import REVOLUTE_CASE, write_gt_scene


@pytest.fixture(scope="module")
def door(tmp_path_factory):
    """The bench cabinet door (a vertical hinge: its weight does not turn it), its task and 'open' handle path."""
    robot = load_robot(default_robot_path())
    gt = write_gt_scene(REVOLUTE_CASE, tmp_path_factory.mktemp("cut"))
    model = build_mujoco_model(robot, gt / "scene.xml", textures=False)
    task = task_from_ground_truth(gt, "part_0", model)
    joint = part_joint(model, "part_0")
    geometry = measure_robot(robot)
    handle = planner._handle_path(robot, model, joint, task, geometry, "open", None, PlanConfig())
    return robot, model, joint, task, geometry, handle


def _searching(monkeypatch: pytest.MonkeyPatch, missed: float) -> list:
    """Replace the search: a path reaching beyond ``missed`` fails there (ending the search at once when asked to
    stop at a miss beyond its mark, as ``_search`` does); a shorter one succeeds. Returns the calls' handles."""
    calls = []

    def search(robot, model, joint, task, geometry, handle, cpu_started, stop_at_path_miss=None):
        calls.append((handle, stop_at_path_miss))
        if handle.states[-1] >= missed:
            raise PathNotReached(f"handle path not reached at {missed}", missed)
        return {"states": handle.states}

    monkeypatch.setattr(planner, "_search", search)
    return calls


def test_a_late_miss_cuts_the_target_short_of_it(door, monkeypatch: pytest.MonkeyPatch) -> None:
    """Missed at 90 % of the way: the second search plans to at least path_cut_back_rad short of the state missed,
    recorded as capped by the whole-body IK; the part does not fall, so it is held there."""
    robot, model, joint, task, geometry, handle = door
    missed = float(handle.states[int(0.9 * (len(handle.states) - 1))])
    calls = _searching(monkeypatch, missed)
    solution, cut = planner._search_or_cut(robot, model, joint, task, geometry, handle, "open", time.process_time())
    assert len(calls) == 2 and calls[0][1] is not None and calls[1][1] is None
    assert cut.target_state <= missed - PlanConfig().path_cut_back_rad + 1e-9
    assert cut.target_state > handle.start_state + 0.8 * (handle.target_state - handle.start_state) - PlanConfig().path_cut_back_rad
    assert cut.final_state is None and cut.reach_capped["by"] == "whole-body IK"
    assert cut.reach_capped["requested"] == handle.target_state
    np.testing.assert_array_equal(solution["states"], cut.states)


def test_an_early_miss_is_the_search_s_error(door, monkeypatch: pytest.MonkeyPatch) -> None:
    """Missed at 40 % of the way: no cut, the error reaches the caller as the search raised it."""
    robot, model, joint, task, geometry, handle = door
    missed = float(handle.states[int(0.4 * (len(handle.states) - 1))])
    calls = _searching(monkeypatch, missed)
    with pytest.raises(PlanningError, match="not reached"):
        planner._search_or_cut(robot, model, joint, task, geometry, handle, "open", time.process_time())
    assert len(calls) == 1


def test_a_number_target_is_never_cut(door, monkeypatch: pytest.MonkeyPatch) -> None:
    """A state asked for by number is exact: the search runs as it is, without the stop at a miss."""
    robot, model, joint, task, geometry, handle = door
    calls = _searching(monkeypatch, float(handle.states[-1]))
    with pytest.raises(PathNotReached):
        planner._search_or_cut(robot, model, joint, task, geometry, handle, float(handle.target_state), time.process_time())
    assert calls == [(handle, None)]
