"""Synthetic benchmark generator: suite contents, file layout, determinism, exact-geometry
self-checks (noise-free depth through the true poses), scene.xml against gt.json, noise model."""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path

import numpy as np
import pytest

from funrec.errors import FunrecError
from funrec.formats.capture import load_capture, read_mask
from funrec.formats.ground_truth import read_ground_truth
from funrec.geometry.camera import project
from funrec.geometry.joints import joint_transform
from funrec.geometry.transforms import invert_transform, transform_points
from funrec.synth import (
    Interaction,
    PartRequest,
    SequenceSpec,
    bench_suite,
    generate_sequence,
    generate_suite,
    smoke_suite,
    tiny_spec,
)
from funrec.synth.scene import JOINT_TYPE_OF_KIND
from funrec.synth.sensor import SensorNoise, noisy_depth
from funrec.synth.sequence import is_complete, plan_sequence
from funrec.synth.suite import families_suite, reseeded

SELF_CHECK_TOL_M = 0.002
"""Median reprojection tolerance of the issue's self-check; exact depth is stored in 1 mm
steps, so agreement is at the 0.5 mm level when poses, intrinsics and joints are right."""


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# --- suite contents -------------------------------------------------------------------


def test_bench_suite_meets_the_issue_counts() -> None:
    specs = bench_suite()
    names = [s.name for s in specs]
    assert len(specs) >= 24 and len(set(names)) == len(names)
    singles = [s for s in specs if len(s.interactions) == 1]
    revolute = [s for s in singles if JOINT_TYPE_OF_KIND[s.parts[0].kind] == "revolute"]
    prismatic = [s for s in singles if JOINT_TYPE_OF_KIND[s.parts[0].kind] == "prismatic"]
    multi = [s for s in specs if len(s.interactions) in (2, 3)]
    static = [s for s in specs if not s.interactions]
    assert len(revolute) >= 10 and len(prismatic) >= 8 and len(multi) >= 3 and len(static) >= 2
    assert any(len({i.part for i in s.interactions}) < len(s.interactions) for s in multi), (
        "one multi sequence reuses a part"
    )
    kinds = {(s.parts[0].kind, s.parts[0].hinge) for s in revolute}
    assert {("door", "left"), ("door", "right")} <= kinds
    assert {"double_door", "fridge_door", "microwave_door"} <= {k for k, _ in kinds}
    assert {"wall_door", "wall_double_door"} & {k for k, _ in kinds}
    assert {"oven_door", "dishwasher_door"} & {k for k, _ in kinds}
    assert {"drawer", "sliding_door"} <= {s.parts[0].kind for s in prismatic}
    assert {"top", "middle", "bottom"} <= {s.parts[0].level for s in prismatic}
    assert all(60 <= s.num_frames <= 250 and (s.width, s.height, s.fps) == (640, 480, 15.0) for s in specs)
    assert 0.35 <= np.mean([s.hand_masks for s in specs]) <= 0.65
    assert all(s.name.startswith(("rev_", "pri_", "multi_", "static_")) for s in specs)


def test_smoke_suite_covers_both_joint_types_and_a_static_walk() -> None:
    specs = smoke_suite()
    types = {JOINT_TYPE_OF_KIND[s.parts[0].kind] if s.parts else "static" for s in specs}
    assert types == {"revolute", "prismatic", "static"} and len(specs) <= 4


def test_spec_validation_names_the_problem() -> None:
    with pytest.raises(ValueError, match="unknown part kind"):
        PartRequest("trapdoor")
    with pytest.raises(ValueError, match="cannot hold a sliding_door"):
        SequenceSpec("x", 0, "kitchen", (PartRequest("sliding_door"),), (Interaction(0, (0.9,)),), 60)
    with pytest.raises(ValueError, match="never interacted"):
        SequenceSpec("x", 0, "kitchen", (PartRequest("door"), PartRequest("drawer")), (Interaction(0, (0.9,)),), 60)
    with pytest.raises(ValueError, match="fractions"):
        Interaction(0, (1.5,))
    short = SequenceSpec("short_seq", 0, "kitchen", (PartRequest("door"),), (Interaction(0, (0.9, 0.1, 0.9, 0.1)),), 10)
    with pytest.raises(ValueError, match="short_seq: 10 frames are too few"):
        plan_sequence(short, texture_px=32)


# --- planned motion (no rendering) ----------------------------------------------------


def _check_plan(spec: SequenceSpec) -> None:
    plan = plan_sequence(spec, texture_px=32)
    motion = plan.motion
    F = spec.num_frames
    T_world_camera = motion.T_world_camera
    assert T_world_camera.shape == (F, 4, 4) and motion.states.shape == (len(spec.parts), F)
    np.testing.assert_allclose(
        T_world_camera[:, :3, :3] @ T_world_camera[:, :3, :3].transpose(0, 2, 1),
        np.broadcast_to(np.eye(3), (F, 3, 3)),
        atol=1e-9,
    )
    assert 1.45 <= T_world_camera[0, 2, 3] <= 1.75, "starts at head height"
    if spec.interactions:
        first = plan.parts[spec.interactions[0].part]
        start = np.linalg.norm((T_world_camera[0, :3, 3] - first.handle)[:2])
        assert 1.2 <= start <= 3.1, f"walks up from {start:.2f} m"
    K = np.array([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])
    for k, part in enumerate(plan.parts):
        states = motion.states[k]
        assert states[0] == 0.0 and np.all(states >= -1e-12) and np.all(states <= part.upper + 1e-12)
        T_parts = part.poses(states)
        for first_frame, last_frame in motion.intervals[k]:
            assert 0 <= first_frame < last_frame < F
            frames = np.arange(first_frame, last_frame + 1)
            handle = np.einsum("fij,j->fi", T_parts[frames, :3, :3], part.handle) + T_parts[frames, :3, 3]
            distance = np.linalg.norm(handle - T_world_camera[frames, :3, 3], axis=1)
            assert np.all((distance > 0.7) & (distance < 1.3)), (
                f"{spec.name} part_{k}: camera {distance.min():.2f}-{distance.max():.2f} m from the handle"
            )
            p_camera = np.einsum("fji,fj->fi", T_world_camera[frames, :3, :3], handle - T_world_camera[frames, :3, 3])
            uv, z = project(p_camera, K)
            assert np.all(z > 0) and np.all((uv > 0) & (uv < [640, 480])), (
                f"{spec.name} part_{k}: handle leaves the view"
            )
            # the hand is rigidly on the handle while it holds the part
            offset = np.linalg.inv(T_parts[frames]) @ motion.T_world_grasp[frames]
            np.testing.assert_allclose(offset, np.broadcast_to(offset[0], offset.shape), atol=1e-9)
            assert np.linalg.norm(offset[0][:3, 3] - part.handle) < 0.03


@pytest.mark.parametrize("name", ["rev_fridge_01", "pri_drawer_02", "multi_same_00", "static_walk_00"])
def test_planned_motion_keeps_the_part_in_view(name: str) -> None:
    _check_plan({s.name: s for s in bench_suite()}[name])


def test_reseeded_suite_is_fresh_scenes_of_the_same_recipes() -> None:
    # A held-out set: every family recipe with a seed no suite uses, and a name that says so.
    suite = families_suite()
    fresh = [reseeded(s, 2) for s in suite]
    assert reseeded(suite[0], 0) is suite[0]
    assert {s.seed for s in fresh}.isdisjoint(s.seed for s in suite)
    assert len({s.seed for s in fresh}) == len(suite)
    for old, new in zip(suite, fresh):
        assert new.name == f"{old.name}_r2"
        assert dataclasses.replace(new, name=old.name, seed=old.seed) == old
    with pytest.raises(FunrecError, match="reseed"):
        reseeded(suite[0], -1)
    # A new seed moves the furniture and the camera: the planned motion of the first copy is not the original's.
    before, after = (plan_sequence(s, texture_px=32).motion.T_world_camera for s in (suite[0], fresh[0]))
    assert not np.allclose(before, after)
    _check_plan(fresh[0])


@pytest.mark.slow
def test_planned_motion_of_the_whole_bench_suite() -> None:
    for spec in bench_suite():
        _check_plan(spec)


# --- generated files ------------------------------------------------------------------


def test_tiny_capture_follows_the_formats(tiny_capture: Path) -> None:
    capture = load_capture(tiny_capture)
    gt = read_ground_truth(tiny_capture / "gt")
    F = len(capture)
    assert F == tiny_spec().num_frames == gt.frame_count and capture.has_hand_masks
    assert capture.T_world_camera_known is None and not (tiny_capture / "camera_poses.txt").exists()
    assert (capture.intrinsics.cx, capture.intrinsics.cy) == (
        39.5,
        29.5,
    ) and capture.intrinsics.fx == capture.intrinsics.fy
    depth = capture.depth_m(F // 2)
    assert depth.max() < 6.0 and np.allclose(depth * 1000, np.round(depth * 1000), atol=1e-6)
    np.testing.assert_array_equal(gt.T_scene_world, np.eye(4))
    (part,) = gt.parts
    assert part.part.name == "part_0" and part.part.joint_type == "revolute"
    np.testing.assert_array_equal(part.part.frames, np.arange(F))
    assert (
        part.part.states[0] == 0.0
        and part.part.state_range[0] == 0.0
        and part.part.states.max() <= part.part.state_range[1]
    )
    ((first, last),) = part.intervals
    assert 0 <= first < last < F and np.ptp(part.part.states[first : last + 1]) > 0.5
    assert np.all(np.diff(part.part.states[:first]) == 0) and np.all(np.diff(part.part.states[last:]) == 0)
    assert gt.extra["part_info"][0]["kind"] == "door" and gt.extra["generator"]["spec"]["seed"] == 0
    hand_files = sorted((gt.root / "masks" / "hand").iterdir())
    assert len(hand_files) == F and any(read_mask(p).any() for p in hand_files)
    part_files = sorted((gt.root / "masks" / "part_0").iterdir())
    assert part_files and all(read_mask(p).any() for p in part_files)
    assert any(read_mask(p).any() for p in capture.mask_paths["hand"] if p is not None)
    import trimesh

    for name in ("static", "part_0"):
        points = np.asarray(trimesh.load(gt.points_path(name)).vertices)
        assert len(points) > 100 and np.all(np.abs(points) < 5.0)
    part_points = np.asarray(trimesh.load(gt.points_path("part_0")).vertices)
    assert np.linalg.norm(part_points - part.handle_world, axis=1).max() < 1.0, "part points sit at the canonical door"


def test_scene_xml_reproduces_the_true_part_pose(tiny_capture: Path) -> None:
    import mujoco

    gt = read_ground_truth(tiny_capture / "gt")
    model = mujoco.MjModel.from_xml_path(str(gt.scene_xml))
    data = mujoco.MjData(model)
    (part,) = gt.parts
    joint = model.joint(part.part.name)
    body = int(model.jnt_bodyid[joint.id])
    p_body = model.geom_pos[model.geom_bodyid == body] + [0.01, -0.02, 0.03]
    mujoco.mj_forward(model, data)
    p_world_canonical = data.xpos[body] + p_body @ data.xmat[body].reshape(3, 3).T
    for frame in (len(part.part.states) // 2, len(part.part.states) - 1):
        state = part.part.states[frame]
        data.qpos[joint.qposadr[0]] = state
        mujoco.mj_forward(model, data)
        p_world = data.xpos[body] + p_body @ data.xmat[body].reshape(3, 3).T
        T = joint_transform(part.part.joint_type, part.part.axis_world, part.part.pivot_world, state)
        np.testing.assert_allclose(p_world, transform_points(T, p_world_canonical), atol=1e-6)
    handle = model.site(f"{gt.extra['part_info'][0]['body']}_handle")
    data.qpos[:] = 0.0
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(data.site_xpos[handle.id], part.handle_world, atol=1e-9)


def test_same_seed_same_files_different_seed_different(tiny_capture: Path, tmp_path: Path) -> None:
    again = generate_sequence(tiny_spec(0), tmp_path / "again")
    other = generate_sequence(tiny_spec(1), tmp_path / "other")
    for stem in ("000005.png", "000018.png"):
        for folder in ("rgb", "depth"):
            assert _digest(tiny_capture / folder / stem) == _digest(again / folder / stem)
        assert _digest(tiny_capture / "rgb" / stem) != _digest(other / "rgb" / stem)
    for name in ("gt.json", "camera_poses.txt", "scene.xml"):
        assert _digest(tiny_capture / "gt" / name) == _digest(again / "gt" / name)


def test_scenes_only_writes_the_same_true_scene_without_frames(tiny_capture: Path, tmp_path: Path) -> None:
    scene = generate_sequence(tiny_spec(0), tmp_path, scenes_only=True)
    for name in ("gt.json", "camera_poses.txt", "scene.xml"):
        assert _digest(tiny_capture / "gt" / name) == _digest(scene / "gt" / name)
    assert not (scene / "rgb").exists() and not (scene / "gt" / "masks").exists()
    assert is_complete(scene, scenes_only=True) and not is_complete(scene)


def test_interrupted_generation_leaves_nothing_that_looks_complete(tmp_path: Path) -> None:
    def stop(done: int, total: int) -> None:
        if done == 5:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        generate_sequence(tiny_spec(2), tmp_path, progress=stop)
    assert list(tmp_path.iterdir()) == []


def test_generate_suite_skips_complete_sequences(
    tiny_capture: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import funrec.synth.suite as suite

    calls: list[str] = []
    monkeypatch.setitem(suite.SUITES, "unit", lambda: (tiny_spec(0), tiny_spec(4)))
    monkeypatch.setattr(suite, "generate_sequence", lambda spec, out, progress=None, scenes_only=False: calls.append(spec.name))
    paths = generate_suite(tiny_capture.parent, "unit")
    assert calls == ["tiny_04"] and paths == [tiny_capture, tiny_capture.parent / "tiny_04"]
    (tmp_path / "tiny_00").mkdir()
    (tmp_path / "tiny_00" / "intrinsics.json").write_text("{}")  # no gt/gt.json: unfinished
    generate_suite(tmp_path, "unit", only=["tiny_00"])
    assert calls[-1] == "tiny_00"
    with pytest.raises(FunrecError, match="has no sequences"):
        generate_suite(tmp_path, "unit", only=["nope"])
    with pytest.raises(FunrecError, match="unknown suite"):
        generate_suite(tmp_path, "nope")


# --- exact-geometry self-check ----------------------------------------------------------


def _exact_spec() -> SequenceSpec:
    return dataclasses.replace(tiny_spec(3), name="exact_03", width=160, height=120, noise=False)


@pytest.fixture(scope="module")
def exact_capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Noise-free 160x120 sequence for the exact-geometry self-checks."""
    return generate_sequence(_exact_spec(), tmp_path_factory.mktemp("exact"))


def _labels(gt_root: Path, parts: int, frame: int, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) 0 static, k + 1 part k, -1 hand."""
    labels = np.zeros(shape, np.int64)
    for k in range(parts):
        path = gt_root / "masks" / f"part_{k}" / f"{frame:06d}.png"
        if path.is_file():
            labels[read_mask(path)] = k + 1
    labels[read_mask(gt_root / "masks" / "hand" / f"{frame:06d}.png")] = -1
    return labels


def _reprojection_errors(depth_i: np.ndarray, ok_i: np.ndarray, p_camera_i: np.ndarray, K: np.ndarray) -> np.ndarray:
    """|z - depth_i(uv)| for camera-i points whose bilinear neighbourhood lies on one smooth
    valid surface of the selected pixels, leaving out points hidden behind it (a door's inner
    face seen from the room side); asserts that most points are not hidden."""
    uv, z = project(p_camera_i, K)
    H, W = depth_i.shape
    inside = (
        (z > 0)
        & np.all(np.isfinite(uv), axis=1)
        & (uv[:, 0] >= 0)
        & (uv[:, 0] < W - 1)
        & (uv[:, 1] >= 0)
        & (uv[:, 1] < H - 1)
    )
    uv, z = uv[inside], z[inside]
    u0, v0 = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    a, b = uv[:, 0] - u0, uv[:, 1] - v0
    corners = np.stack([depth_i[v0, u0], depth_i[v0, u0 + 1], depth_i[v0 + 1, u0], depth_i[v0 + 1, u0 + 1]], axis=1)
    usable = np.stack([ok_i[v0, u0], ok_i[v0, u0 + 1], ok_i[v0 + 1, u0], ok_i[v0 + 1, u0 + 1]], axis=1).all(axis=1)
    usable &= np.ptp(corners, axis=1) < 0.02
    sampled = (
        corners[:, 0] * (1 - a) * (1 - b)
        + corners[:, 1] * a * (1 - b)
        + corners[:, 2] * (1 - a) * b
        + corners[:, 3] * a * b
    )
    signed = (z - sampled)[usable]
    hidden = signed > 0.005
    assert hidden.mean() < 0.5, f"{hidden.mean():.0%} of the points land behind the surface"
    return np.abs(signed[~hidden])


def _points(depth: np.ndarray, mask: np.ndarray, K: np.ndarray) -> np.ndarray:
    v, u = np.nonzero(mask & (depth > 0))
    z = depth[v, u]
    return np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)


def test_self_check_static_points_coincide_across_frames(exact_capture: Path) -> None:
    capture = load_capture(exact_capture)
    gt = read_ground_truth(exact_capture / "gt")
    K = capture.intrinsics.K
    F = len(capture)
    for i, j in ((0, F - 1), (F // 3, 2 * F // 3), (2, F // 2)):
        depth_i, depth_j = capture.depth_m(i), capture.depth_m(j)
        labels_i = _labels(gt.root, len(gt.parts), i, depth_i.shape)
        labels_j = _labels(gt.root, len(gt.parts), j, depth_j.shape)
        p_world = transform_points(gt.T_world_camera[j], _points(depth_j, labels_j == 0, K))
        p_camera_i = transform_points(invert_transform(gt.T_world_camera[i]), p_world)
        errors = _reprojection_errors(depth_i, (labels_i == 0) & (depth_i > 0), p_camera_i, K)
        assert len(errors) > 500, f"frames {i}, {j} overlap too little"
        assert np.median(errors) < SELF_CHECK_TOL_M, f"frames {i}->{j}: median {np.median(errors) * 1000:.2f} mm"


def test_self_check_part_points_coincide_in_the_canonical_pose(exact_capture: Path) -> None:
    capture = load_capture(exact_capture)
    gt = read_ground_truth(exact_capture / "gt")
    (part,) = gt.parts
    K = capture.intrinsics.K
    T_parts = part.part.T_world_part()
    # The plan (same seed) knows the door's outer normal: compare frames that see the same face.
    plan = plan_sequence(_exact_spec(), texture_px=32)
    np.testing.assert_allclose(plan.motion.states[0], part.part.states, atol=1e-12)
    normal = np.einsum("fij,j->fi", T_parts[:, :3, :3], plan.parts[0].normal)
    handle = np.einsum("fij,j->fi", T_parts[:, :3, :3], part.handle_world) + T_parts[:, :3, 3]
    outer = np.einsum("fi,fi->f", normal, gt.T_world_camera[:, :3, 3] - handle) > 0
    visible = np.array([(gt.root / "masks" / "part_0" / f"{f:06d}.png").is_file() for f in range(len(capture))])
    pairs = []
    for side in (True, False):
        frames = np.flatnonzero(visible & (outer == side))
        if len(frames) >= 2:
            lo, hi = frames[np.argmin(part.part.states[frames])], frames[np.argmax(part.part.states[frames])]
            pairs += [(lo, hi), (hi, lo)] if lo != hi else [(frames[0], frames[-1])]
    assert any(abs(part.part.states[i] - part.part.states[j]) > 0.3 for i, j in pairs), (
        "no pair of views at different states"
    )
    for i, j in pairs:
        depth_i, depth_j = capture.depth_m(i), capture.depth_m(j)
        labels_i = _labels(gt.root, 1, i, depth_i.shape)
        labels_j = _labels(gt.root, 1, j, depth_j.shape)
        p_world_j = transform_points(gt.T_world_camera[j], _points(depth_j, labels_j == 1, K))
        p_canonical = transform_points(invert_transform(T_parts[j]), p_world_j)
        p_camera_i = transform_points(invert_transform(gt.T_world_camera[i]) @ T_parts[i], p_canonical)
        errors = _reprojection_errors(depth_i, (labels_i == 1) & (depth_i > 0), p_camera_i, K)
        assert len(errors) > 50, f"frames {j}->{i}: part overlaps too little ({len(errors)} points)"
        assert np.median(errors) < SELF_CHECK_TOL_M, f"frames {j}->{i}: median {np.median(errors) * 1000:.2f} mm"


def test_intrinsics_match_mujoco_projection() -> None:
    """Depth of a tilted plane rendered by MuJoCo equals the analytic depth through the
    pixel centres of :func:`intrinsics_from_fovy` (cx = W/2 - 0.5)."""
    import mujoco

    from funrec.synth.render import R_MUJOCO_OPENCV, OffscreenRenderer, fovy_for_focal, intrinsics_from_fovy

    W, H = 64, 48
    fovy = fovy_for_focal(H, 52.5)
    xml = f"""<mujoco><compiler angle="radian"/><visual><global offwidth="{W}" offheight="{H}"/></visual><worldbody>
      <geom type="plane" size="20 20 0.1" rgba="0.5 0.5 0.5 1"/>
      <body pos="0.3 -2 1.4" euler="1.1 0.15 0.3"><camera name="c" fovy="{fovy!r}"/></body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    with OffscreenRenderer(model, W, H, "c") as renderer:
        view = renderer.render(data)
    K = intrinsics_from_fovy(W, H, fovy).K
    R_world_camera = data.cam_xmat[0].reshape(3, 3) @ R_MUJOCO_OPENCV
    v, u = np.mgrid[0:H, 0:W]
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((H, W))], axis=-1) @ R_world_camera.T
    analytic = -data.cam_xpos[0][2] / rays[..., 2]  # depth along the optical axis where the ray meets z = 0
    hit = (view.geom_id == 0) & (analytic < 6.0)
    assert hit.sum() > 0.5 * H * W
    # float32 depth read-back: relative error ~1e-4 at 6 m; half a pixel of principal point
    # offset would give errors of several per cent on this tilted plane.
    np.testing.assert_allclose(view.depth_m[hit], analytic[hit], rtol=2e-4)
    shifted = -data.cam_xpos[0][2] / (rays + 0.5 / K[0, 0] * R_world_camera[:, 0])[..., 2]
    assert np.median(np.abs(view.depth_m[hit] / shifted[hit] - 1.0)) > 10 * 2e-4


# --- sensor noise ---------------------------------------------------------------------


def test_depth_noise_grows_with_depth_and_is_quantised() -> None:
    noise = SensorNoise()
    rng = np.random.default_rng(0)
    stds = []
    for z in (1.0, 2.5, 4.0):
        wall = np.full((120, 160), z)
        reading = noisy_depth(wall, rng, noise)
        valid = reading > 0
        assert valid.mean() > 0.99, "a flat wall has almost no holes"
        np.testing.assert_allclose(reading[valid] * 1000, np.round(reading[valid] * 1000), atol=1e-9)
        std = reading[valid].std()
        assert abs(std - np.hypot(noise.sigma_m(z), 0.001 / np.sqrt(12))) < 0.2 * noise.sigma_m(z) + 3e-4
        stds.append(std)
    assert stds[0] < stds[1] < stds[2]
    exact = noisy_depth(np.full((4, 4), 1.2344), rng, noise, exact=True)
    np.testing.assert_array_equal(exact, 1.234)


def test_depth_holes_at_edges_and_out_of_range() -> None:
    rng = np.random.default_rng(1)
    depth = np.full((100, 100), 1.5)
    depth[:, 50:] = 2.5  # a depth step between columns 49 and 50
    depth[:10, :10] = 0.2  # too near
    depth[90:, 90:] = 7.0  # too far
    reading = noisy_depth(depth, rng)
    assert np.all(reading[:10, :10] == 0) and np.all(reading[90:, 90:] == 0)
    edge_holes = (reading[20:80, 49:51] == 0).mean()
    elsewhere = (reading[20:80, 10:40] == 0).mean()
    assert edge_holes > 0.5 and elsewhere < 0.02


def test_part_depth_self_test_passes_and_catches_depth_that_is_not_the_part(exact_capture: Path, tmp_path: Path) -> None:
    import shutil

    import cv2

    from funrec.synth.selftest import PART_DEPTH_TOLERANCE_M, check_part_depth, part_depth_consistency

    (result,) = check_part_depth(exact_capture)
    # Nearest-pixel lookup on a 160x120 image: a few mm on slanted surfaces even with exact depth.
    assert result.frame_pairs > 3 and result.median_m is not None and result.median_m < PART_DEPTH_TOLERANCE_M / 2
    # Depth seen through a pane: every other frame reads 5 cm behind the part under its mask.
    broken = shutil.copytree(exact_capture, tmp_path / "broken")
    for frame in range(1, len(load_capture(broken)), 2):
        mask_path = broken / "gt" / "masks" / "part_0" / f"{frame:06d}.png"
        if not mask_path.is_file():
            continue
        depth_path = broken / "depth" / f"{frame:06d}.png"
        depth = cv2.imread(str(depth_path), cv2.IMREAD_UNCHANGED)
        depth[read_mask(mask_path) & (depth > 0)] += 50
        cv2.imwrite(str(depth_path), depth)
    (bad,) = part_depth_consistency(broken)
    assert bad.median_m is not None and bad.median_m > PART_DEPTH_TOLERANCE_M
    with pytest.raises(FunrecError, match="part_0: median"):
        check_part_depth(broken)


def test_bench_families_plain_has_12_and_half_without_hand_masks() -> None:
    from funrec.synth.suite import FAMILY_SUITES, families_suite, plain_suite

    plain = plain_suite()
    assert len(plain) >= 12 and sum(not s.hand_masks for s in plain) * 2 >= len(plain)
    assert all(s.appearance == "plain" and s.family == "plain" for s in plain)
    names = [s.name for s in families_suite()]
    assert len(set(names)) == len(names)
    for suite, make in FAMILY_SUITES.items():
        families = {s.family for s in make()}
        assert families == {"textured" if suite == "bench" else suite}
    person = {(s.arm, s.joint_speed) for s in FAMILY_SUITES["person"]()}
    assert {"sleeve", "elbow"} <= {arm for arm, _ in person} and min(v for _, v in person) < 1 < max(v for _, v in person)
    assert {"dim", "harsh", "window", "changing"} <= {s.lighting for s in FAMILY_SUITES["lighting"]()}
    assert {"angled", "island"} <= {s.layout for s in FAMILY_SUITES["geometry"]()}
    with pytest.raises(ValueError, match="unknown lighting"):
        dataclasses.replace(tiny_spec(), lighting="disco")


def test_clear_glass_is_in_the_colour_but_not_in_depth_or_labels() -> None:
    import mujoco

    from funrec.synth.render import OffscreenRenderer
    from funrec.synth.scene import SEE_THROUGH_GROUP

    xml = f"""<mujoco><visual><global offwidth="64" offheight="48"/></visual><worldbody>
      <light pos="0 0 3" dir="0 0 -1"/>
      <camera name="cam" pos="0 0 0" xyaxes="1 0 0 0 1 0" fovy="60"/>
      <geom name="wall" type="box" size="2 2 0.01" pos="0 0 -2" rgba="0.8 0.2 0.2 1"/>
      <geom name="pane" type="box" size="0.5 0.5 0.005" pos="0 0 -1" rgba="0.8 0.9 0.9 0.2"
            group="{SEE_THROUGH_GROUP}"/>
    </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    with OffscreenRenderer(model, 64, 48, "cam") as renderer:
        view = renderer.render(data)
    wall = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "wall")
    assert view.geom_id[24, 32] == wall
    assert view.depth_m[24, 32] == pytest.approx(1.99, abs=0.01)  # the wall's front face, not the pane


def test_metaworld_assets_become_human_scale_fronts_with_credit() -> None:
    from funrec.synth.assets import ASSET_MODELS, METAWORLD_CREDIT, metaworld_root
    from funrec.synth.suite import assets_suite

    try:
        metaworld_root()
    except FunrecError as exc:
        pytest.skip(f"metaworld not installed: {exc}")
    kinds = {s.parts[0].kind for s in assets_suite()}
    assert kinds == set(ASSET_MODELS)
    for spec in assets_suite()[::2]:
        plan = plan_sequence(dataclasses.replace(spec, width=160, height=120), texture_px=32)
        (part,) = plan.parts
        assert part.joint_type == JOINT_TYPE_OF_KIND[spec.parts[0].kind]
        assert 0.3 < part.handle[2] < 1.8 and 0.3 < part.width < 1.5, (spec.name, part.handle, part.width)
        assert plan.scene.description["third_party_assets"] == METAWORLD_CREDIT
        assert any(path.endswith(".stl") for path in plan.assets)


def test_metaworld_moving_parts_are_free_in_their_carcass_and_open_under_a_modest_pull() -> None:
    """Meta-World's meshes collide as convex hulls: the drawer case's hull held the drawer 0.41 m deep,
    so no robot could pull it (350-460 N). Each asset's part touches nothing at rest and, pulled at its
    handle with 20 N beyond its weight, opens at least half its range within 1 s; its mass stays that of
    a piece of furniture (under 30 kg; the drawer was 80 kg as a solid hull)."""
    import mujoco

    from funrec.synth.assets import metaworld_root
    from funrec.synth.suite import assets_suite

    try:
        metaworld_root()
    except FunrecError as exc:
        pytest.skip(f"metaworld not installed: {exc}")
    kinds: dict[str, SequenceSpec] = {}
    for spec in assets_suite():
        kinds.setdefault(spec.parts[0].kind, spec)
    for kind, spec in kinds.items():
        plan = plan_sequence(dataclasses.replace(spec, width=160, height=120), texture_px=32)
        model = mujoco.MjModel.from_xml_string(plan.scene_xml, plan.assets)
        data = mujoco.MjData(model)
        joint = model.joint("part_0")
        body, dof, qadr = int(joint.bodyid[0]), int(joint.dofadr[0]), int(joint.qposadr[0])
        site = next(i for i in range(model.nsite) if model.site_bodyid[i] == body)
        mujoco.mj_forward(model, data)
        touching = [c for c in data.contact[: data.ncon] if body in model.geom_bodyid[[c.geom1, c.geom2]]]
        assert not touching, (kind, [(model.geom(c.geom1).name, model.geom(c.geom2).name, c.dist) for c in touching])
        assert model.body_subtreemass[body] < 30.0, (kind, model.body_subtreemass[body])
        jac = np.zeros((3, model.nv))
        for _ in range(500):  # 1 s at MuJoCo's 2 ms step
            mujoco.mj_jacSite(model, data, jac, None, site)
            data.qfrc_applied[dof] = data.qfrc_bias[dof] + 20.0 * np.linalg.norm(jac[:, dof])
            mujoco.mj_step(model, data)
        assert data.qpos[qadr] >= 0.5 * model.jnt_range[joint.id, 1], (kind, data.qpos[qadr], model.jnt_range[joint.id])


def test_changing_light_switches_one_light_and_other_set_ups_keep_theirs() -> None:
    from funrec.synth.room import light_schedule

    rng = np.random.default_rng(4)
    assert np.array_equal(light_schedule("dim", 3, 50, rng), np.ones((50, 3)))
    scale = light_schedule("changing", 3, 100, np.random.default_rng(5))
    jumps = np.abs(np.diff(scale, axis=0)).max(axis=0)
    assert sorted(jumps > 0.2) == [False, False, True]  # one light switched within 3 frames
    switched = int(np.argmax(jumps))
    assert {round(scale[0, switched], 2), round(scale[-1, switched], 2)} == {0.12, 1.0}


@pytest.mark.parametrize("arrangement", ["angled", "island"])
def test_turned_and_free_rows_keep_the_walk_area_in_front_of_every_front(arrangement: str) -> None:
    for seed in range(3):
        spec = SequenceSpec(
            f"geo_{seed}", 900 + seed, "kitchen", (PartRequest("door"),), (Interaction(0, (0.9,)),), 120,
            layout=arrangement, appearance="plain",
        )
        plan = plan_sequence(spec, texture_px=32)
        y_max = plan.scene.walk_area[3]
        assert plan.scene.description["layout"] == arrangement
        # Every handle (on the fronts) lies beyond the walk area's far edge, and the camera stays in it.
        handles = np.array([p.handle for p in plan.parts])
        assert np.all(handles[:, 1] > y_max)
        assert np.all(plan.motion.T_world_camera[:, 1, 3] <= y_max + 0.05)
        if arrangement == "angled":
            assert 8.0 <= abs(plan.scene.description["row_yaw_deg"]) <= 25.0
            assert abs(plan.parts[0].normal[0]) > np.sin(np.radians(7.0))  # not axis-aligned
