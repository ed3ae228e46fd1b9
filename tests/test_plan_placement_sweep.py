"""Base placement keeps each base pose clear of the part where the part is while the base is there (issue 14): a
stop keeps clear of the sweep around the moment it stands there, the base on its way between stops of the sweep
meanwhile, and every instant of the sweep is kept clear by the pose the IK is then asked to hold."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from funrec_robot import build_mujoco_model, default_robot_path, load_robot
from funrec_robot.plan import _stop_weights, _sweep_windows
from funrec_robot.scene import part_joint, part_sweep_footprint, part_travel
from funrec_robot.trajopt import BasePlacement
from funrec_robot.whole_body import posture_along
from tests.helpers.robot_scenes import REVOLUTE_CASE, write_gt_scene

BAND = (0.0, 0.4)
"""Heights of a base's discs, m."""
STEP = 0.06
"""Window length: the placement's clearance, m."""
STATES = np.linspace(0.0, 1.4, 36)
"""A cabinet door opened 80 degrees in the planner's 2-degree steps."""


@pytest.fixture(scope="module")
def door(tmp_path_factory: pytest.TempPathFactory) -> tuple[mujoco.MjModel, int]:
    robot = load_robot(default_robot_path())
    gt = write_gt_scene(REVOLUTE_CASE, tmp_path_factory.mktemp("sweep"))
    model = build_mujoco_model(robot, Path(gt) / "scene.xml")
    return model, part_joint(model, "part_0")


def _inside(polygons, footprint) -> bool:  # noqa: ANN001
    """Whether each of ``footprint``'s polygons, shrunk by 2 mm towards its centre (the hull's numerical slack), lies
    in one of ``polygons`` (a window's footprint is one hull of all the part's geoms)."""
    for piece in footprint:
        centre = piece.vertices.mean(axis=0)
        points = (
            piece.vertices
            + 0.002 * (centre - piece.vertices) / np.linalg.norm(centre - piece.vertices, axis=1)[:, None]
        )
        if not any(np.all(p.lower_distance(points) <= 0.0) for p in polygons):
            return False
    return True


def test_the_stop_weights_are_the_posture_the_ik_follows() -> None:
    """The placement asks the base to be clear at the poses ``whole_body.posture_along`` gives the IK."""
    robot = load_robot(default_robot_path())
    poses = np.random.default_rng(3).uniform(-1.0, 1.0, (3, 3))
    placement = BasePlacement(poses=poses, cost=0.0, clearance=0.0, distances=np.zeros(1))
    for n in (1, 2, 7, 36):
        posture = posture_along(robot, placement, n)
        for k in range(n):
            np.testing.assert_allclose(posture[k, :3], _stop_weights(k, n, 3) @ poses, atol=1e-12)


def test_every_instant_of_the_sweep_is_kept_clear_where_the_base_then_is(door) -> None:
    """At every path state the part's footprint lies inside footprints checked against a base pose at most half a
    window from the one the IK then holds (a window is as many states as the door's far corner needs to travel
    ``STEP``, so half of one is that many states over two, plus the state cut at each end)."""
    model, joint = door
    travel = part_travel(model, joint, STATES)
    assert travel.max() > 0.01  # the door's far corner moves centimetres per state
    n, bases = len(STATES), 3
    half_window = (math.ceil(STEP / travel.min()) + 2) / 2.0
    sweeps, passing = _sweep_windows(model, joint, STATES, bases, BAND, STEP)
    checks = [(np.eye(bases)[b], sweeps[b]) for b in range(bases)] + list(passing)
    for k, state in enumerate(STATES):
        footprint = part_sweep_footprint(model, joint, [state], BAND)
        w = _stop_weights(k, n, bases)
        near = [
            polygons
            for weights, polygons in checks
            if np.abs(weights - w).sum() <= 2.0 * half_window * bases / n + 1e-9
        ]
        assert any(_inside(polygons, footprint) for polygons in near), k


def test_a_stop_keeps_clear_only_of_the_sweep_around_it(door) -> None:
    """Of three stops the first does not keep clear of the door opened (it moved on before), nor the last of the door
    closed; one stop keeps clear of the whole sweep, and stands there throughout (nothing on the way)."""
    model, joint = door
    sweeps, passing = _sweep_windows(model, joint, STATES, 3, BAND, STEP)
    opened, closed = (part_sweep_footprint(model, joint, [s], BAND) for s in (STATES[-1], STATES[0]))
    assert _inside(sweeps[0], closed) and not _inside(sweeps[0], opened)
    assert _inside(sweeps[2], opened) and not _inside(sweeps[2], closed)
    assert passing and all(np.all(w < 1.0) and w.sum() == pytest.approx(1.0) for w, _ in passing)
    one, none = _sweep_windows(model, joint, STATES, 1, BAND, STEP)
    assert not none
    assert all(_inside(one[0], part_sweep_footprint(model, joint, [s], BAND)) for s in STATES)


def test_a_placement_of_stops_keeps_the_base_clear_on_its_way(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The cabinet door's path placed from three stops (the robot's own plan needs one): the stops and the base's
    way between them, where the door is meanwhile, clear every footprint by the clearance (less 1 mm: the
    placement's violation bound)."""
    import funrec_robot.plan as plan_module
    from funrec_robot.plan import plan_interaction
    from funrec_robot.task_sources import task_from_ground_truth
    from funrec_robot.trajopt import PlacementConfig, exact_clearance, place_base

    robot = load_robot(default_robot_path())
    gt = write_gt_scene(REVOLUTE_CASE, tmp_path)
    model = build_mujoco_model(robot, Path(gt) / "scene.xml")
    calls: list[tuple] = []
    pose = plan_module._placement_problem

    def record(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        calls.append((args, kwargs))
        return pose(*args, **kwargs)

    monkeypatch.setattr(plan_module, "_placement_problem", record)
    plan_interaction(robot, Path(gt) / "scene.xml", task_from_ground_truth(gt, "part_0", model), "open", model=model)
    args, kwargs = next(call for call in calls if len(call[0][5]) > 3)  # the handle path's (not the reach check's)
    problem = pose(*args[:6], 3, *args[7:], **kwargs)
    assert problem.bases == 3 and problem.passing and len(problem.stretch_sweep) == 3
    config = PlacementConfig()
    placement = place_base(problem, config)
    assert exact_clearance(placement.poses, problem) >= config.clearance - 1e-3
