"""Stage inputs on generated captures: the true ones read from a capture's gt/ folder (the library
never reads gt/; tests do), and the estimated ones of stages 1-5 run as funrec.pipeline runs them.

``synth_sequence`` and ``smoke_sequence`` generate captures once and cache them across test runs
(pytest's cache folder), so the rendered sequences are shared by every test file that uses them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
import trimesh

from funrec.camera.tracking import CameraTrajectory
from funrec.formats.capture import Capture, load_capture, read_mask
from funrec.formats.ground_truth import GroundTruth, read_ground_truth
from funrec.formats.twin import ArticulatedPart, make_part
from funrec.geometry.joints import joint_transform, joint_transforms
from funrec.geometry.transforms import invert_transform, transform_points
from funrec.parts.part_motion import PartMotion
from funrec.surfaces.segmentation import PartMasks, segment_parts


def synth_sequence(cache_root: Path, name: str, seed: int, part: str, frames: int, width: int, height: int) -> Path:
    """Generate (once, cached across test runs and files) a synthetic capture with ground truth."""
    synth = pytest.importorskip("funrec.synth")
    spec = synth.SequenceSpec(
        name, seed, "kitchen", (synth.PartRequest(part, "left") if part == "door" else synth.PartRequest(part, level="top"),),
        (synth.Interaction(0, (0.9,)),), frames, width, height, hand_masks=True,
    )
    if not synth.is_complete(cache_root / name):
        synth.generate_sequence(spec, cache_root / name)
    return next(p.parent for p in (cache_root / name).rglob("intrinsics.json"))



def smoke_sequence(cache_root: Path, name: str) -> Path:
    """Generate (once, cached across test runs) one sequence of funrec.synth's smoke suite."""
    synth = pytest.importorskip("funrec.synth")
    spec = next(s for s in synth.smoke_suite() if s.name == name)
    if not synth.is_complete(cache_root / name):
        synth.generate_sequence(spec, cache_root)
    return next(p.parent for p in (cache_root / name).rglob("intrinsics.json"))


def true_inputs(root: Path) -> tuple[Capture, GroundTruth, CameraTrajectory, np.ndarray, np.ndarray]:
    """Capture, ground truth, true trajectory, the part's frames and T_world_part at every frame."""
    capture, gt = load_capture(root), read_ground_truth(root / "gt")
    F = len(capture)
    part = gt.parts[0].part
    T_world_part = np.tile(np.eye(4), (F, 1, 1))
    T_world_part[np.asarray(part.frames)] = joint_transforms(part.joint_type, part.axis_world, part.pivot_world, part.states)
    trajectory = CameraTrajectory(gt.T_world_camera, np.arange(F), np.ones(F, dtype=bool))
    return capture, gt, trajectory, np.asarray(part.frames), T_world_part


def true_mask(gt: GroundTruth, capture: Capture, frame: int) -> np.ndarray:
    path = gt.mask_path("part_0", frame)
    shape = (capture.intrinsics.height, capture.intrinsics.width)
    return read_mask(path) if path.is_file() else np.zeros(shape, dtype=bool)




def ground_truth_inputs(
    capture_root: Path, T_twin_camera0: npt.ArrayLike, rebase: bool = False
) -> tuple[CameraTrajectory, list[ArticulatedPart], list[PartMasks], list[np.ndarray]]:
    """Trajectory, parts, part masks and canonical part points from a capture's gt/ folder.

    Args:
        capture_root: a generated capture with gt/.
        T_twin_camera0: (4, 4) pose of camera 0 in the twin world frame to build.
        rebase: mimic the pipeline's convention: a part is tracked only around its motion and its
            canonical state is its first tracked state (the true one is the closed state).
    """
    gt = read_ground_truth(capture_root / "gt")
    T_twin_world = np.asarray(T_twin_camera0, dtype=np.float64) @ invert_transform(gt.T_world_camera[0])
    trajectory = CameraTrajectory(T_twin_world @ gt.T_world_camera, np.zeros(0, np.int64), np.ones(gt.frame_count, bool))
    parts, masks, surfaces = [], [], []
    for gt_part in gt.parts:
        part = gt_part.part
        frames, states = part.frames, part.states
        points = np.asarray(trimesh.load(str(gt.points_path(part.name)), process=False).vertices, dtype=np.float64)
        if rebase:
            moving = np.flatnonzero(np.abs(np.diff(states)) > 1e-4)
            keep = slice(max(0, moving[0] - 3), min(len(frames), moving[-1] + 8))
            frames, states = frames[keep], states[keep]
            points = transform_points(joint_transform(part.joint_type, part.axis_world, part.pivot_world, states[0]), points)
            states = states - states[0]
        pivot = None if part.pivot_world is None else transform_points(T_twin_world, part.pivot_world[None])[0]
        parts.append(make_part(part.name, part.joint_type, T_twin_world[:3, :3] @ part.axis_world, pivot, frames, states))
        files = [f for f in sorted((gt.root / "masks" / part.name).glob("*.png")) if frames[0] <= int(f.stem) <= frames[-1]]
        masks.append(PartMasks(np.array([int(f.stem) for f in files], dtype=np.int64), tuple(f.read_bytes() for f in files),
                               int(read_mask(files[0]).shape[0]), int(read_mask(files[0]).shape[1]), np.zeros(0, np.int64)))
        surfaces.append(transform_points(T_twin_world, points))
    return trajectory, parts, masks, surfaces




@dataclass(frozen=True)
class EstimatedRun:
    """Stages 1-5 on a rendered capture, as funrec.pipeline runs them."""

    name: str
    capture: Capture
    gt: GroundTruth
    trajectory: CameraTrajectory
    motion: PartMotion
    masks: PartMasks


def estimate_run(name: str, root: Path) -> EstimatedRun:
    """Stages 1-5 on the capture ``name`` at ``root``: ~1 min for a 320x240 smoke capture."""
    from funrec.camera.tracking import track_camera
    from funrec.parts.articulation import InteractionEvidence, estimate_articulation
    from funrec.parts.part_motion import refine_part_motion
    from funrec.parts.point_tracks import track_points

    capture = load_capture(root)
    trajectory = track_camera(capture)
    tracks = track_points(capture, trajectory)
    evidence = InteractionEvidence.from_hand_masks(lambda frame: capture.mask("hand", frame), np.ones(len(capture)))
    estimate = estimate_articulation(tracks, evidence)
    assert estimate.parts, "no part found"
    motion = refine_part_motion(tracks, estimate.parts[0])
    moving = np.zeros(tracks.num_tracks, dtype=bool)
    moving[estimate.parts[0].track_indices] = True
    masks = segment_parts(capture, trajectory, tracks, moving, motion.frames, motion.T_world_part)
    return EstimatedRun(name, capture, read_ground_truth(capture.root / "gt"), trajectory, motion, masks)

