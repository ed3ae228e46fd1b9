"""reconstruct(): the only place that knows the order of the stages.

capture -> camera trajectory -> point tracks -> articulation -> part motion -> part masks
-> TSDF meshes -> twin folder (FORMATS.md section 2).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from funrec.articulation import ArticulationConfig, InteractionEvidence, estimate_articulation
from funrec.capture import Capture, load_capture
from funrec.export.simulation import ExportConfig, export_simulation
from funrec.export.twin import TwinWriter
from funrec.fusion import FusionConfig, fuse_tsdf
from funrec.geometry.transforms import transform_points
from funrec.gravity import GravityConfig, estimate_gravity
from funrec.part_motion import PartMotion, PartMotionConfig, refine_part_motion
from funrec.point_tracks import PointTrackConfig, track_points
from funrec.segmentation import SegmentationConfig, segment_parts
from funrec.tracking import TrackingConfig, track_camera
from funrec.twin_format import TwinArticulation, make_part

log = logging.getLogger(__name__)

StageProgress = Callable[[str, int, int], None]
"""progress(stage, done, total): called as each stage advances."""


@dataclass(frozen=True)
class ReconstructConfig:
    """Settings of the whole reconstruction; each stage has its own config."""

    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    """Camera tracking (stage 1)."""
    point_tracks: PointTrackConfig = field(default_factory=PointTrackConfig)
    """Sparse 3D point tracks (stage 2)."""
    articulation: ArticulationConfig = field(default_factory=ArticulationConfig)
    """Articulation-aware motion clustering (stage 3)."""
    part_motion: PartMotionConfig = field(default_factory=PartMotionConfig)
    """Joint optimisation of part poses and articulation (stage 5)."""
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    """Part masks (stage 4)."""
    fusion: FusionConfig = field(default_factory=FusionConfig)
    """TSDF fusion (stage 6)."""
    export: ExportConfig = field(default_factory=ExportConfig)
    """Simulation exports (twin.urdf, twin.xml, twin.usda)."""
    gravity: GravityConfig = field(default_factory=GravityConfig)
    """Gravity alignment of the twin's world frame."""
    align_gravity: bool = True
    """Express the twin in a gravity-aligned frame (z up, origin on the floor below camera 0);
    off: the world is camera 0's frame."""
    use_hand_masks: bool = True
    """Use the capture's hand masks when it has them (off: behave as if it had none)."""
    use_object_masks: bool = True
    """Use the capture's interacted-object masks when it has them."""
    max_parts: int = 1
    """Most parts kept from one capture, best interaction score first; the single-fragment
    pipeline reconstructs the interacted part, further clusters are usually the hand."""


@dataclass(frozen=True)
class PartSummary:
    """What was found for one part."""

    name: str
    joint_type: str
    """"revolute" or "prismatic"."""
    state_range: tuple[float, float]
    """Observed joint interval, rad or m."""
    frames: tuple[int, int]
    """First and last tracked frame."""


@dataclass(frozen=True)
class ReconstructionSummary:
    """Outcome of :func:`reconstruct`."""

    twin_dir: Path
    """The written twin folder."""
    frame_count: int
    """Frames in the capture."""
    parts: tuple[PartSummary, ...]
    """Parts found (empty: nothing was opened)."""
    stage_seconds: dict[str, float]
    """Wall time of each stage, seconds."""
    untracked_frames: int
    """Frames whose camera pose was interpolated rather than registered."""


def _evidence(capture: Capture, config: ReconstructConfig) -> InteractionEvidence | None:
    """Interaction evidence from the capture's masks: object masks first, then hand proximity."""
    confidence = np.ones(len(capture))
    if capture.has_object_masks and config.use_object_masks:
        return InteractionEvidence.from_masks(lambda frame: capture.mask("object", frame), confidence)
    if capture.has_hand_masks and config.use_hand_masks:
        return InteractionEvidence.from_hand_masks(lambda frame: capture.mask("hand", frame), confidence)
    return None


def reconstruct(
    capture_dir: str | Path,
    out_dir: str | Path,
    config: ReconstructConfig = ReconstructConfig(),  # noqa: B008 (frozen, immutable default)
    progress: StageProgress | None = None,
    overwrite: bool = False,
) -> ReconstructionSummary:
    """Reconstruct a functional twin from a capture folder and write the twin folder.

    Args:
        capture_dir: capture folder (FORMATS.md section 1).
        out_dir: twin folder to write; written to a temporary sibling and renamed into place.
        config: stage settings.
        progress: optional ``progress(stage, done, total)``.
        overwrite: replace an existing non-empty ``out_dir``.

    Raises:
        CaptureError: the capture is malformed (names file and frame).
        ReconstructionError: the capture cannot be reconstructed (says why).
    """
    capture = load_capture(capture_dir)
    if not config.use_hand_masks or not config.use_object_masks:
        kept = {k: v for k, v in capture.mask_paths.items() if (k != "hand" or config.use_hand_masks) and (k != "object" or config.use_object_masks)}
        capture = dataclasses.replace(capture, mask_paths=kept)
    seconds: dict[str, float] = {}

    def stage_progress(name: str) -> Callable[[int, int], None] | None:
        if progress is None:
            return None
        return lambda done, total: progress(name, done, total)

    def timed(name: str, fn, *args, **kwargs):  # noqa: ANN001, ANN202 (thin timing wrapper)
        start = time.perf_counter()
        result = fn(*args, **kwargs)
        seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - start
        log.info("%s: %.1f s", name, seconds[name])
        return result

    with TwinWriter(out_dir, overwrite=overwrite) as writer:
        trajectory = timed("camera", track_camera, capture, config.tracking, progress=stage_progress("camera"))
        tracks = timed("tracks", track_points, capture, trajectory, config.point_tracks, progress=stage_progress("tracks"))
        estimate = timed("articulation", estimate_articulation, tracks, _evidence(capture, config), config.articulation)
        motions: list[PartMotion] = [
            timed("part motion", refine_part_motion, tracks, part, config.part_motion)
            for part in estimate.parts[: config.max_parts]
        ]
        all_masks = []
        for k, (part, motion) in enumerate(zip(estimate.parts, motions)):
            moving = np.zeros(tracks.num_tracks, dtype=bool)
            moving[part.track_indices] = True
            masks = timed(
                "masks",
                segment_parts,
                capture,
                trajectory,
                tracks,
                moving,
                motion.frames,
                motion.T_world_part,
                config.segmentation,
                progress=stage_progress(f"masks part_{k}"),
            )
            for frame, png in zip(masks.frames, masks.png):
                writer.path(f"masks/part_{k}/{int(frame):06d}.png").write_bytes(png)
            all_masks.append(masks)
        meshes = timed(
            "fusion",
            fuse_tsdf,
            capture,
            trajectory,
            all_masks,
            [m.T_world_part for m in motions],
            config.fusion,
            progress=stage_progress("fusion"),
        )
        T_twin_world = np.eye(4)
        if config.align_gravity:
            alignment = timed("gravity", estimate_gravity, meshes.static.vertices, trajectory.T_world_camera, config.gravity)
            T_twin_world = alignment.T_aligned_world
        meshes.static.copy().apply_transform(T_twin_world).export(writer.path("meshes/static.ply"))
        parts = []
        for k, (motion, mesh) in enumerate(zip(motions, meshes.parts)):
            mesh.copy().apply_transform(T_twin_world).export(writer.path(f"meshes/part_{k}.ply"))
            pivot_twin = None if motion.pivot_world is None else transform_points(T_twin_world, motion.pivot_world[None])[0]
            parts.append(
                make_part(
                    f"part_{k}",
                    motion.joint_type,
                    T_twin_world[:3, :3] @ motion.axis_world,
                    pivot_twin,
                    motion.frames,
                    motion.states,
                    motion.state_range,
                    mesh=f"meshes/part_{k}.ply",
                    masks=f"masks/part_{k}",
                )
            )
        writer.write_camera_poses(T_twin_world @ trajectory.T_world_camera)
        writer.write_articulation(TwinArticulation(frame_count=len(capture), parts=tuple(parts)))
        timed("export", export_simulation, writer.root, config.export)
    summaries = tuple(
        PartSummary(p.name, p.joint_type, p.state_range, (int(p.frames[0]), int(p.frames[-1]))) for p in parts
    )
    return ReconstructionSummary(
        twin_dir=Path(out_dir),
        frame_count=len(capture),
        parts=summaries,
        stage_seconds=seconds,
        untracked_frames=int((~trajectory.tracked).sum()),
    )


__all__ = ["PartSummary", "ReconstructConfig", "ReconstructionSummary", "reconstruct"]
