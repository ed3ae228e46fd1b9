"""The planner's shortcuts give the answers of the long way round: base placement against the footprints near
the base first (grown until all are clear), the placement grid scored by its reach bound first, and the IK's
collision limit culling pairs with boxes instead of spheres (the same constraint rows as mink's)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import casadi as ca
import mink
import mujoco
import numpy as np
import pytest

import funrec_robot.plan as plan_module
from funrec_robot import build_mujoco_model, default_robot_path, load_robot
from funrec_robot.collision_limit import BoxedCollisionLimit, GeomBoxes
from funrec_robot.ik import IKConfig, WholeBodyIK
from funrec_robot.plan import plan_interaction
from funrec_robot.scene import part_joint
from funrec_robot.task_sources import task_from_ground_truth
from funrec_robot.trajopt import (
    PlacementConfig,
    PlacementProblem,
    _best_guess,
    _grid,
    _stop_functions,
    _violation,
    exact_clearance,
    place_base,
)
from tests.helpers.robot_scenes import REVOLUTE_CASE, write_gt_scene


@pytest.fixture(scope="module")
def robot():
    return load_robot(default_robot_path())


@pytest.fixture(scope="module")
def scene(robot, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, mujoco.MjModel]:
    gt = write_gt_scene(REVOLUTE_CASE, tmp_path_factory.mktemp("speed"))
    return gt, build_mujoco_model(robot, gt / "scene.xml")


@pytest.fixture(scope="module")
def problems(robot, scene, monkeypatch_module) -> list[PlacementProblem]:
    """The placement problem of the cabinet door as the planner poses it, and the same path split over 2 and 3
    base stops (the robot's own plan needs one)."""
    gt, model = scene
    seen: list[PlacementProblem] = []

    def record(problem: PlacementProblem, config: PlacementConfig):  # noqa: ANN202
        seen.append(problem)
        return place_base(problem, config)

    monkeypatch_module.setattr(plan_module, "place_base", record)
    plan_interaction(robot, gt / "scene.xml", task_from_ground_truth(gt, "part_0", model), "open", model=model)
    problem = seen[0]
    out = [problem]
    K = len(problem.stretch)
    for stops in (2, 3):
        stretch = np.minimum((np.arange(K) * stops) // K, stops - 1)
        out.append(dataclasses.replace(problem, stretch=stretch, sweep=problem.sweep[:1] * stops))
    return out


@pytest.fixture(scope="module")
def monkeypatch_module():
    with pytest.MonkeyPatch.context() as patch:
        yield patch


def test_placement_against_near_footprints_is_the_full_placement(problems) -> None:
    """IPOPT against the footprints near the grid's guess ends where it ends against all of them (``active_rounds``
    0 is the full problem), or lower: with three stops the full problem's barrier terms of ~2000 inactive
    constraints keep IPOPT from converging in 80 (or 500) iterations, 5 mm and 0.01 rad from where the lazy one
    converges in 48. 1e-6 on the cost is IPOPT's tolerance; 1 mm / 1 mrad on one or two stops likewise."""
    config = PlacementConfig()
    for problem in problems:
        lazy, full = place_base(problem, config), place_base(problem, dataclasses.replace(config, active_rounds=0))
        assert lazy.cost <= full.cost + 1e-6
        if problem.bases < 3:
            np.testing.assert_allclose(lazy.poses, full.poses, atol=1e-3)
        assert lazy.clearance >= config.clearance - 1e-3


def test_footprints_left_out_are_added_until_the_base_clears_all(problems, monkeypatch) -> None:
    """Start from the footprints that touch the robot's discs at the guess only: where IPOPT then puts a disc
    into a footprint left out, that footprint joins and IPOPT runs again; the result clears every footprint."""
    import funrec_robot.trajopt as trajopt

    runs: list[int] = []
    solve = trajopt._ipopt

    def counted(x, terms, *args):  # noqa: ANN001, ANN202
        runs.append(sum(int(g.numel()) for g in terms.g))
        return solve(x, terms, *args)

    monkeypatch.setattr(trajopt, "_ipopt", counted)
    config = PlacementConfig(active_radius=0.0)
    for problem in problems:
        runs.clear()
        placement = place_base(problem, config)
        assert exact_clearance(placement.poses, problem) >= config.clearance - 1e-3
        full = sum(int(g.numel()) for g in trajopt._assemble(problem, ca.MX.sym("x", 3 * problem.bases), config, None).g)
        assert runs[0] < full  # the first run really left footprints out


def test_grid_scored_by_its_reach_bound_first_picks_the_grids_best_point(problems) -> None:
    config = PlacementConfig()
    for problem in problems:
        for b in range(problem.bases):
            functions, terms = _stop_functions(problem, b, config, None)
            grid = _grid(problem, b, config)
            cost, g = functions[0].map(len(grid))(grid.T)
            lbg, ubg = terms.bounds()
            score = np.asarray(cost).ravel() + 1e3 * _violation(np.asarray(g), lbg, ubg)
            best = _best_guess(problem, b, functions, terms, config)
            assert np.isclose(score[np.flatnonzero(np.all(grid == best, axis=1))[0]], score.min())


def test_boxed_collision_limit_gives_minks_rows(robot, scene) -> None:
    """Random arm postures with the base scattered around the door: every constraint row mink's limit gives
    (finite bound) is given, and no other, its bound times the step time (ours bounds the step, mink's the step
    over dt; no relaxation); the box broad phase sends fewer pairs to the narrow phase. (The robot's own pairs are
    compared without ``recover``, mink's bound: with it a pair inside its floor has a negative bound instead of 0,
    tested in test_robot_fetch.)"""
    gt, model = scene
    joint = part_joint(model, "part_0")
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    door = data.xpos[model.jnt_bodyid[joint]].copy()
    ik = WholeBodyIK(robot, model, joint, door[None], [], IKConfig())
    rng = np.random.default_rng(3)
    culled = []
    for limit in [lim for lim in ik.limits if isinstance(lim, BoxedCollisionLimit)]:
        limit.recover = False
        reference = mink.CollisionAvoidanceLimit(
            model, [], gain=limit.gain,
            minimum_distance_from_collisions=limit.minimum_distance_from_collisions,
            collision_detection_distance=limit.collision_detection_distance,
        )
        reference.geom_id_pairs, reference.max_num_contacts = limit.geom_id_pairs, len(limit.geom_id_pairs)
        reference.broadphase = False
        for _ in range(60):
            q = model.qpos0.copy()
            arm = ik.indices.qpos[ik.n_base :]
            low, high = robot.q_min[ik.n_base :], robot.q_max[ik.n_base :]
            q[arm] = rng.uniform(np.maximum(low, -3.0), np.minimum(high, 3.0))
            base = ik.indices.qpos[: ik.n_base]
            q[base[:2]] = door[:2] + rng.uniform(-0.9, 0.9, 2)
            q[base[2]] = rng.uniform(-np.pi, np.pi)
            configuration = mink.Configuration(model)
            configuration.update(q)
            dt = 0.02
            ours = limit.compute_qp_inequalities(configuration, dt)
            theirs = reference.compute_qp_inequalities(configuration, dt)
            keep = np.isfinite(theirs.h)
            assert reference.bound_relaxation == 0.0
            expected = np.column_stack([theirs.G[keep], theirs.h[keep] * dt])
            got = np.zeros((0, model.nv + 1)) if ours.G is None else np.column_stack([ours.G, ours.h])
            assert got.shape == expected.shape
            np.testing.assert_allclose(got[np.lexsort(got.T[::-1])], expected[np.lexsort(expected.T[::-1])], atol=1e-12)
            culled.append(np.mean(limit.lower_distances(configuration.data) > limit.collision_detection_distance))
    assert np.mean(culled) > 0.5


def test_a_planning_model_without_textures_is_the_same_model_to_the_planner(robot, scene) -> None:
    """The planner's model is built without the scene's textures (``textures=False``): nothing the planner reads
    changes, bit for bit (bodies, joints, geoms and their materials' colours, the same number of each), only the
    images are one texel each."""
    gt, model = scene
    bare = build_mujoco_model(robot, gt / "scene.xml", textures=False)
    assert model.ntex == bare.ntex > 0 and model.ntexdata > 3 * 32 * 32 and bare.ntexdata <= 6 * 4 * bare.ntex
    for field in ("body_pos", "body_quat", "body_mass", "jnt_range", "jnt_qposadr", "qpos0", "geom_type", "geom_size",
                  "geom_pos", "geom_quat", "geom_contype", "geom_conaffinity", "geom_friction", "geom_matid",
                  "geom_rgba", "geom_aabb", "geom_rbound", "mat_rgba", "mesh_vert", "opt.timestep"):
        first, second = model, bare
        for part in field.split("."):
            first, second = getattr(first, part), getattr(second, part)
        np.testing.assert_array_equal(first, second, err_msg=field)


def test_lower_distances_of_many_footprints_are_each_footprints(problems) -> None:
    """All footprints of the door's placement at once give each footprint's own lower distances, bit for bit
    (the placement's footprint selection and its reported clearance compare them with thresholds)."""
    from funrec_robot.scene import lower_distances

    problem = problems[0]
    polygons = problem.static + problem.start_part + sum(problem.sweep, ())
    points = problem.wrist_world[0, :2] + np.random.default_rng(5).uniform(-2.0, 2.0, (9, 2))
    assert len(polygons) > 3
    np.testing.assert_array_equal(lower_distances(polygons, points), np.column_stack([p.lower_distance(points) for p in polygons]))
    assert lower_distances((), points).shape == (9, 0)


def test_the_ik_limits_share_one_broad_phase_with_each_limits_own_distances(robot, scene) -> None:
    """The IK's collision limits measure their geoms' boxes once per configuration (``shared_boxes``): each limit
    still gets its own pairs' lower distances, bit for bit those of a limit with its own broad phase, and a new
    configuration is measured anew."""
    gt, model = scene
    joint = part_joint(model, "part_0")
    ik = WholeBodyIK(robot, model, joint, np.zeros((1, 3)), [], IKConfig())
    limits = [lim for lim in ik.limits if isinstance(lim, BoxedCollisionLimit)]
    assert len(limits) > 1 and len({id(lim._boxes) for lim in limits}) == 1
    alone = [BoxedCollisionLimit(model, [], collision_detection_distance=lim.collision_detection_distance) for lim in limits]
    for own, lim in zip(alone, limits):
        own.geom_id_pairs = lim.geom_id_pairs
        own.use_boxes(GeomBoxes(model, lim.geom_id_pairs), 0)
    rng = np.random.default_rng(7)
    configuration = mink.Configuration(model)
    for _ in range(5):
        q = model.qpos0.copy()
        q[ik.indices.qpos[ik.n_base :]] = rng.uniform(np.maximum(robot.q_min[ik.n_base :], -3.0), np.minimum(robot.q_max[ik.n_base :], 3.0))
        q[ik.indices.qpos[:2]] = rng.uniform(-1.0, 1.0, 2)
        configuration.update(q)
        for own, lim in zip(alone, limits):
            np.testing.assert_array_equal(lim.lower_distances(configuration.data), own.lower_distances(configuration.data))


def test_timed_path_sampled_at_once_is_toppras_own_sampling() -> None:
    """``retime._sample`` evaluates toppra's timed path at all times at once: the same positions and velocities
    as toppra's own loop over the times, bit for bit, between and at its gridpoints and at the end."""
    import toppra
    import toppra.algorithm
    import toppra.constraint

    from funrec_robot.retime import _sample

    rng = np.random.default_rng(11)
    waypoints = np.cumsum(rng.uniform(-0.3, 0.3, (9, 4)), axis=0)
    path = toppra.SplineInterpolator(np.linspace(0.0, 1.0, 9), waypoints, bc_type="clamped")
    limits = [toppra.constraint.JointVelocityConstraint(np.column_stack([-np.ones(4), np.ones(4)])),
              toppra.constraint.JointAccelerationConstraint(np.column_stack([-2 * np.ones(4), 2 * np.ones(4)]))]
    timed = toppra.algorithm.TOPPRA(limits, path, gridpoints=np.linspace(0.0, 1.0, 50),
                                    parametrizer="ParametrizeConstAccel").compute_trajectory(0.0, 0.0)
    t = np.r_[np.linspace(0.0, timed.duration, 997), timed._ts, timed.duration]
    for order in (0, 1):
        np.testing.assert_array_equal(_sample(timed, t, order), timed(t, order))


def test_boxed_collision_limit_pairs_are_minks_in_minks_order(robot, scene) -> None:
    """The limit's pairs, filtered at once, are the list mink's pair-by-pair filter gives, in the same order (the
    QP's rows follow it), for each of the IK's groups of the door scene."""
    gt, model = scene
    joint = part_joint(model, "part_0")
    ik = WholeBodyIK(robot, model, joint, np.zeros((1, 3)), [], IKConfig())
    groups = [g for g in ik._collision_pairs(np.zeros((1, 3)), np.zeros(0, dtype=np.int64)) if g]
    limits = [lim for lim in ik.limits if isinstance(lim, BoxedCollisionLimit)]
    assert len(groups) == len(limits) > 1
    for pairs, limit in zip(groups, limits):
        assert limit.geom_id_pairs == mink.CollisionAvoidanceLimit(model, pairs).geom_id_pairs
