"""Stage 5 on synthetic tracks: joint-constrained pose graph with loop-closure confidences."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from funrec.geometry.joints import joint_transforms
from funrec.geometry.transforms import make_transform
from funrec.parts.articulation import PartEstimate, estimate_articulation
from funrec.parts.joint_problem import JointProblem
from funrec.parts.part_motion import (
    PartMotionConfig,
    _measure_edges,
    _solve_joint,
    refine_part_motion,
)
from tests.helpers.track_scenes import SyntheticScene, errors, make_scene


def scene_and_part(seed: int, joint_type: str, noise_m: float = 0.003, num_frames: int = 40) -> tuple[SyntheticScene, PartEstimate]:
    scene = make_scene(np.random.default_rng(seed), (joint_type,), num_frames=num_frames, part_tracks=100, static_tracks=100,
                       hand_tracks=15, noise_m=noise_m)
    part = estimate_articulation(scene.tracks).interacted
    assert part is not None and part.joint_type == joint_type
    return scene, part


@pytest.mark.parametrize("joint_type", ["revolute", "prismatic"])
def test_refined_poses_are_joint_transforms(joint_type: str) -> None:
    scene, part = scene_and_part(0, joint_type)
    motion = refine_part_motion(scene.tracks, part)
    expected = joint_transforms(motion.joint_type, motion.axis_world, motion.pivot_world, motion.states)
    # Built by the same function from the same numbers: equal to round-off.
    np.testing.assert_allclose(motion.T_world_part, expected, atol=1e-12)
    np.testing.assert_allclose(motion.T_world_part[0], np.eye(4), atol=1e-12)  # canonical state 0
    assert motion.states[0] == 0.0
    assert motion.state_range == (motion.states.min(), motion.states.max())
    assert abs(np.linalg.norm(motion.axis_world) - 1.0) < 1e-12
    if joint_type == "revolute":
        assert abs(motion.pivot_world @ motion.axis_world) < 1e-12
    np.testing.assert_array_equal(motion.frames, part.frames)
    assert np.all((motion.edge_confidence >= 0) & (motion.edge_confidence <= 1))
    assert motion.edge_is_loop.any() and (~motion.edge_is_loop).any()
    assert motion.track_rms_m <= motion.track_rms_init_m * 1.01


def test_refinement_improves_on_the_initialisation_under_noise() -> None:
    # 5 mm noise: the joint optimisation uses every track and edge at once and should keep
    # stage 3's accuracy (see the slack below).
    init, refined = [], []
    for seed in range(3):
        scene, part = scene_and_part(10 + seed, "revolute", noise_m=0.005)
        motion = refine_part_motion(scene.tracks, part)
        init.append(errors(part, scene.parts[0]))
        refined.append(errors(motion, scene.parts[0]))
    # Stage 3 now fits the joint to the tracks themselves (robust joint least squares), so it
    # starts stage 5 at the optimum of the track term (~0.6 mm pivot, ~0.04 deg axis here); the
    # pose-graph edges can then move the estimate only by their own noise. Hence "no worse than
    # the initialisation by more than 0.25 mm / 0.05 deg" rather than "strictly better".
    slack = {"axis_deg": 0.05, "pivot_m": 0.00025}
    for key in ("axis_deg", "pivot_m"):
        assert np.mean([e[key] for e in refined]) < np.mean([e[key] for e in init]) + slack[key], (key, init, refined)
    # States are pinned to the first frame's noise in both, so they may only match, not improve.
    assert np.mean([e["state"] for e in refined]) < np.mean([e["state"] for e in init]) + np.deg2rad(0.05)
    for e in refined:
        assert e["axis_deg"] < 0.5 and e["pivot_m"] < 0.005 and e["state"] < np.deg2rad(1.0), e


def test_corrupted_loop_closure_loses_its_confidence() -> None:
    scene, part = scene_and_part(1, "revolute")
    config = PartMotionConfig(use_track_term=False)
    p = scene.tracks.p_world[part.frames][:, part.track_indices]
    vis = scene.tracks.visible[part.frames][:, part.track_indices]
    edges, sigma_p = _measure_edges(p, vis, config, np.random.default_rng(0))
    bad = int(np.flatnonzero(edges.loop)[2])
    # A wrong loop closure (e.g. a symmetric look-alike): 8 deg and 3 cm off.
    edges.M[bad] = make_transform(Rotation.from_rotvec([0.0, 0.14, 0.0]).as_matrix(), [0.03, 0.0, 0.0]) @ edges.M[bad]
    _, _, _, confidence, _, _ = _solve_joint(part, edges, None, sigma_p, config)
    others = np.delete(confidence[edges.loop], 2)
    assert confidence[bad] < 0.01, confidence[bad]
    assert np.median(others) > 0.5, others


def test_joint_problem_jacobian_matches_finite_differences() -> None:
    for joint_type in ("revolute", "prismatic"):
        scene, part = scene_and_part(2, joint_type, num_frames=20)
        config = PartMotionConfig()
        p = scene.tracks.p_world[part.frames][:, part.track_indices[:12]]
        vis = scene.tracks.visible[part.frames][:, part.track_indices[:12]]
        edges, sigma_p = _measure_edges(p, vis, PartMotionConfig(min_correspondences=4), np.random.default_rng(0))
        f, track = np.nonzero(vis)
        problem = JointProblem(part, edges, (f, track, p[f, track]), sigma_p, config.loop_regulariser, config.track_weight)
        rng = np.random.default_rng(3)
        theta = problem.initial() + rng.normal(0, 0.01, problem.x_col0 + 3 * problem.n_tracks)
        theta[problem.n_joint + len(problem.var) : problem.x_col0] = rng.uniform(0.2, 0.9, problem.n_loop)
        analytic = problem.jacobian(theta).toarray()
        numeric = np.zeros_like(analytic)
        h = 1e-6
        for k in range(len(theta)):
            d = np.zeros(len(theta))
            d[k] = h
            numeric[:, k] = (problem.residuals(theta + d) - problem.residuals(theta - d)) / (2 * h)
        # Residuals are whitened (O(1)-O(100) per unit); central differences at h = 1e-6 are
        # good to ~1e-6 relative, the per-edge FD inside the Jacobian likewise.
        np.testing.assert_allclose(analytic, numeric, atol=1e-4 * np.abs(numeric).max())


def test_ablation_switches() -> None:
    scene, part = scene_and_part(3, "revolute")
    off = refine_part_motion(scene.tracks, part, PartMotionConfig(use_pose_graph=False))
    np.testing.assert_allclose(off.states, part.states)
    np.testing.assert_allclose(off.axis_world, part.axis_world)
    assert off.evaluations == 0 and len(off.edge_frames) == 0
    no_loop = refine_part_motion(scene.tracks, part, PartMotionConfig(use_loop_closures=False))
    assert not no_loop.edge_is_loop.any()
    free = refine_part_motion(scene.tracks, part, PartMotionConfig(use_joint_constraint=False))
    np.testing.assert_allclose(free.T_world_part, joint_transforms("revolute", free.axis_world, free.pivot_world, free.states), atol=1e-12)
    for motion in (no_loop, free):
        err = errors(motion, scene.parts[0])
        assert err["axis_deg"] < 1.0 and err["pivot_m"] < 0.01 and err["state"] < np.deg2rad(1.0), err


def _casadi_solve(part: PartEstimate, edges, config: PartMotionConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The same L(phi, l) (no track term) in CasADi/IPOPT with exact derivatives; also returns
    the wall time of the IPOPT solve alone (without building the expression graph)."""
    import casadi as ca

    revolute = part.joint_type == "revolute"
    a0 = part.axis_world
    B = np.linalg.svd(np.eye(3) - np.outer(a0, a0))[0][:, :2]
    n_s = len(part.frames) - 1
    n_loop = int(edges.loop.sum())
    u, w, s, b = ca.SX.sym("u", 2), ca.SX.sym("w", 2), ca.SX.sym("s", n_s), ca.SX.sym("b", n_loop)
    a_raw = a0 + B @ u
    a = a_raw / ca.norm_2(a_raw)
    q = part.pivot_world + B @ w if revolute else ca.DM.zeros(3)
    states = ca.vertcat(0, s)
    K = ca.skew(a)
    cost = 0
    loop_k = 0
    for e in range(len(edges.i)):
        ds = states[int(edges.j[e])] - states[int(edges.i[e])]
        if revolute:
            R = ca.DM.eye(3) + ca.sin(ds) * K + (1 - ca.cos(ds)) * (K @ K)
            t = q - R @ q
        else:
            R, t = ca.DM.eye(3), ds * a
        M_inv = np.linalg.inv(edges.M[e])
        c = edges.centre[e]
        # E' = C^-1 Delta M^-1 C
        R_e = R @ M_inv[:3, :3]
        t_e = R @ M_inv[:3, 3] + t + R_e @ c - c
        cos_th = ca.fmin(ca.fmax((ca.trace(R_e) - 1) / 2, -1), 1)
        theta = ca.acos(cos_th - 1e-12)
        sin_th = ca.sin(theta)
        v = ca.vertcat(R_e[2, 1] - R_e[1, 2], R_e[0, 2] - R_e[2, 0], R_e[1, 0] - R_e[0, 1])
        omega = v * ca.if_else(theta < 1e-4, 0.5 + theta**2 / 12, theta / (2 * sin_th + 1e-300))
        W = ca.skew(omega)
        coef = ca.if_else(theta < 1e-4, 1.0 / 12, (1 - theta * sin_th / (2 * (1 - cos_th) + 1e-300)) / (theta**2 + 1e-300))
        rho = (ca.DM.eye(3) - 0.5 * W + coef * (W @ W)) @ t_e
        r = ca.DM(edges.sqrt_info[e]) @ ca.vertcat(omega, rho)
        f = ca.dot(r, r)
        if edges.loop[e]:
            cost += b[loop_k] ** 2 * f + config.loop_regulariser * (b[loop_k] - 1) ** 2
            loop_k += 1
        else:
            cost += f
    x = ca.vertcat(u, w, s, b) if revolute else ca.vertcat(u, s, b)
    solver = ca.nlpsol("pg", "ipopt", {"x": x, "f": cost}, {"ipopt.print_level": 0, "print_time": False, "ipopt.tol": 1e-10})
    n_joint = 4 if revolute else 2
    x0 = np.concatenate([np.zeros(n_joint), part.states[1:], np.ones(n_loop)])
    lbx = np.concatenate([np.full(n_joint + n_s, -np.inf), np.zeros(n_loop)])
    ubx = np.concatenate([np.full(n_joint + n_s, np.inf), np.ones(n_loop)])
    t0 = time.perf_counter()
    sol = np.asarray(solver(x0=x0, lbx=lbx, ubx=ubx)["x"]).ravel()
    t_solve = time.perf_counter() - t0
    a = a0 + B @ sol[:2]
    a /= np.linalg.norm(a)
    return a, np.concatenate([[0.0], sol[n_joint : n_joint + n_s]]), sol[n_joint + n_s :] ** 2, t_solve


@pytest.mark.slow
def test_optimiser_comparison_scipy_vs_casadi() -> None:
    """scipy least_squares (sparse Jacobian) and CasADi/IPOPT reach the same minimum of L."""
    scene, part = scene_and_part(4, "revolute", num_frames=80)
    config = PartMotionConfig(use_track_term=False)
    p = scene.tracks.p_world[part.frames][:, part.track_indices]
    vis = scene.tracks.visible[part.frames][:, part.track_indices]
    edges, sigma_p = _measure_edges(p, vis, config, np.random.default_rng(0))
    t0 = time.perf_counter()
    axis_s, _, states_s, conf_s, _, _ = _solve_joint(part, edges, None, sigma_p, config)
    t_scipy = time.perf_counter() - t0
    t0 = time.perf_counter()
    axis_c, states_c, conf_c, _ = _casadi_solve(part, edges, config)
    t_casadi = time.perf_counter() - t0
    print(f"scipy {t_scipy:.3f}s casadi {t_casadi:.3f}s")
    assert np.degrees(np.arccos(min(1.0, abs(axis_s @ axis_c)))) < 0.01
    np.testing.assert_allclose(states_s, states_c, atol=1e-4)
    np.testing.assert_allclose(conf_s[edges.loop], conf_c, atol=1e-3)


def test_a_part_without_shared_tracks_keeps_stage_3s_joint() -> None:
    """A part whose tracks no two frames share enough of (a plain door's few tracks, seen in turns)
    keeps the joint stage 3 fitted, unrefined, rather than raising: the ValueError reached the user
    as a traceback (plain_rev_wall_cabinet_01 at 665d2eb). Demanding more shared tracks than the
    part has makes every pair fail."""
    scene, part = scene_and_part(2, "revolute")
    config = PartMotionConfig(min_correspondences=len(part.track_indices) + 1)
    motion = refine_part_motion(scene.tracks, part, config)
    np.testing.assert_allclose(motion.axis_world, part.axis_world / np.linalg.norm(part.axis_world), atol=1e-12)
    np.testing.assert_allclose(motion.states, part.states, atol=1e-12)
    assert len(motion.edge_frames) == 0 and motion.evaluations == 0
