"""A twin and its capture as a rerun recording (.rrd): scrub the video and watch the part, the
camera, the hand and the contact move. rerun-sdk is an optional dependency
(``pip install funrec[rerun]``), imported only here.

Entities (timelines ``frame``, the frame index, and ``time``, frame / fps):

- ``world``: view coordinates, z up.
- ``world/static``: the static mesh (static).
- ``world/parts/<part>``: the part's joint transform at every frame (``T_world_part``, states
  between tracked frames interpolated); ``.../mesh`` the canonical mesh, ``.../contact`` the
  contact point and ``.../grasp`` the grasp frame (all static, world coordinates at the canonical
  state, so the part's transform moves them).
- ``world/camera``: ``T_world_camera`` at every frame; ``world/camera/image`` its pinhole
  (with a capture), holding ``rgb`` (JPEG), ``depth`` (metres), ``parts`` (segmentation: 0
  nothing, k + 1 part k) and ``hand`` (segmentation: 1 hand) at every ``image_every``-th frame.
- ``world/camera_path``: the camera positions as one line strip (static).
- ``joints/<part>``: the joint state (rad or m) at each tracked frame.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import trimesh

from funrec.errors import ExportError
from funrec.formats.affordances import read_affordances
from funrec.formats.camera_poses import read_camera_poses
from funrec.formats.capture import Capture, read_mask
from funrec.formats.staged_folder import staged_file
from funrec.formats.twin import TwinArticulation, read_articulation
from funrec.surfaces.hands import TWIN_HAND_MASKS, part_poses

log = logging.getLogger(__name__)

INSTALL_HINT = "pip install funrec[rerun]"
"""What to run when rerun-sdk is missing."""
HAND_LABEL = 1
"""Segmentation label of hand pixels in ``world/camera/image/hand``."""


@dataclass(frozen=True)
class RerunConfig:
    """Settings of :func:`write_rerun`."""

    image_every: int = 1
    """Log the RGB-D frames and masks of every k-th frame (poses and joint states of every frame)."""
    jpeg_quality: int = 90
    """JPEG quality of the logged RGB frames (0-100)."""
    grasp_axes_length: float = 0.08
    """Length of the drawn grasp frame axes, metres."""

    def __post_init__(self) -> None:
        if self.image_every < 1 or not 0 <= self.jpeg_quality <= 100:
            raise ValueError(f"RerunConfig needs image_every >= 1 and 0 <= jpeg_quality <= 100, got {self}")


def write_rerun(
    twin_dir: str | Path,
    path: str | Path,
    capture: Capture | None = None,
    config: RerunConfig = RerunConfig(),
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Write a rerun recording of a twin (and of its capture's frames, when given).

    Args:
        twin_dir: twin folder (articulation.json, camera_poses.txt, meshes, masks, affordances.json).
        path: the .rrd file to write.
        capture: the capture the twin was made from; None logs no images.
        config: settings.
        progress: optional ``progress(done, total)`` over the frames.

    Returns:
        ``path``.

    Raises:
        ExportError: rerun-sdk is not installed, or the capture's frame count is not the twin's.
    """
    try:
        import rerun as rr
    except ImportError:
        raise ExportError(f"writing {path} needs rerun-sdk: {INSTALL_HINT}") from None
    twin_dir, path = Path(twin_dir), Path(path)
    articulation = read_articulation(twin_dir)
    if capture is not None and len(capture) != articulation.frame_count:
        raise ExportError(
            f"{capture.root}: {len(capture)} frames, but the twin {twin_dir} was made from {articulation.frame_count}"
        )
    with staged_file(path) as staged:  # Ctrl-C while logging leaves no half-written recording
        _write_recording(rr, twin_dir, staged, articulation, capture, config, progress)
    log.info("rerun recording of %s written to %s", twin_dir, path)
    return path


def _write_recording(rr, twin_dir: Path, path: Path, articulation, capture, config, progress) -> None:  # noqa: ANN001
    """Log everything of :func:`write_rerun` into ``path``."""
    rec = rr.RecordingStream(application_id="funrec", recording_id=twin_dir.resolve().name)
    rec.save(str(path))
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    _log_meshes(rr, rec, twin_dir, articulation)
    _log_affordances(rr, rec, twin_dir, config)
    T_world_camera = read_camera_poses(twin_dir / "camera_poses.txt").T_world_camera
    rec.log("world/camera_path", rr.LineStrips3D([T_world_camera[:, :3, 3]]), static=True)
    if capture is not None:
        K = capture.intrinsics
        rec.log(
            "world/camera/image",
            rr.Pinhole(focal_length=[K.fx, K.fy], principal_point=[K.cx, K.cy], resolution=[K.width, K.height],
                       camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.1),
            static=True,
        )
        rec.log("world/camera/image/parts", rr.AnnotationContext(
            [(0, "nothing", (0, 0, 0, 0))] + [(k + 1, p.name) for k, p in enumerate(articulation.parts)]
        ), static=True)
        rec.log("world/camera/image/hand", rr.AnnotationContext([(0, "nothing", (0, 0, 0, 0)), (HAND_LABEL, "hand")]),
                static=True)
    poses = {p.name: part_poses(p, articulation.frame_count) for p in articulation.parts}
    tracked = {p.name: dict(zip(p.frames.tolist(), p.states.tolist())) for p in articulation.parts}
    fps = capture.intrinsics.fps if capture is not None else None
    for frame in range(articulation.frame_count):
        rec.set_time("frame", sequence=frame)
        if fps:
            rec.set_time("time", duration=frame / fps)
        rec.log("world/camera", rr.Transform3D(translation=T_world_camera[frame, :3, 3], mat3x3=T_world_camera[frame, :3, :3]))
        for name, T_world_part in poses.items():
            rec.log(f"world/parts/{name}", rr.Transform3D(translation=T_world_part[frame, :3, 3],
                                                          mat3x3=T_world_part[frame, :3, :3]))
            if frame in tracked[name]:
                rec.log(f"joints/{name}", rr.Scalars(tracked[name][frame]))
        if capture is not None and frame % config.image_every == 0:
            _log_images(rr, rec, twin_dir, articulation, capture, frame, config)
        if progress is not None:
            progress(frame + 1, articulation.frame_count)
    rec.flush()
    rec.disconnect()


def _log_meshes(rr, rec, twin_dir: Path, articulation: TwinArticulation) -> None:  # noqa: ANN001 - rerun module, stream
    meshes = [("world/static", articulation.static_mesh)]
    meshes += [(f"world/parts/{p.name}/mesh", p.mesh) for p in articulation.parts]
    for entity, relative in meshes:
        if relative is None:
            continue
        mesh = trimesh.load(twin_dir / relative, process=False)
        if isinstance(mesh, trimesh.PointCloud):  # a vertex-only PLY (the oracle twin's)
            colors = np.asarray(mesh.colors)[:, :3] if len(mesh.colors) else None
            rec.log(entity, rr.Points3D(np.asarray(mesh.vertices, dtype=np.float32), colors=colors), static=True)
            continue
        colors = np.asarray(mesh.visual.vertex_colors)[:, :3] if mesh.visual.kind == "vertex" else None
        rec.log(entity, rr.Mesh3D(vertex_positions=np.asarray(mesh.vertices, dtype=np.float32),
                                  triangle_indices=np.asarray(mesh.faces, dtype=np.uint32),
                                  vertex_colors=colors), static=True)


def _log_affordances(rr, rec, twin_dir: Path, config: RerunConfig) -> None:  # noqa: ANN001 - rerun module, stream
    if not (twin_dir / "affordances.json").is_file():
        return
    for part in read_affordances(twin_dir).parts:
        rec.log(f"world/parts/{part.name}/contact", rr.Points3D([part.contact_point], radii=0.01, colors=[(255, 40, 40)]),
                static=True)
        T = part.T_world_grasp
        rec.log(f"world/parts/{part.name}/grasp", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=True)
        rec.log(f"world/parts/{part.name}/grasp", rr.TransformAxes3D(config.grasp_axes_length), static=True)


def _log_images(
    rr, rec, twin_dir: Path, articulation: TwinArticulation, capture: Capture, frame: int, config: RerunConfig  # noqa: ANN001
) -> None:
    ok, jpeg = cv2.imencode(".jpg", cv2.cvtColor(capture.rgb(frame), cv2.COLOR_RGB2BGR),
                            [cv2.IMWRITE_JPEG_QUALITY, config.jpeg_quality])
    assert ok
    rec.log("world/camera/image/rgb", rr.EncodedImage(contents=jpeg.tobytes(), media_type="image/jpeg"))
    rec.log("world/camera/image/depth", rr.DepthImage(capture.depth_m(frame).astype(np.float32), meter=1.0))
    labels = np.zeros((capture.intrinsics.height, capture.intrinsics.width), dtype=np.uint8)
    for k, part in enumerate(articulation.parts):
        mask_path = twin_dir / (part.masks or f"masks/{part.name}") / f"{frame:06d}.png"
        if mask_path.is_file():
            labels[read_mask(mask_path)] = k + 1
    rec.log("world/camera/image/parts", rr.SegmentationImage(labels))
    hand = capture.mask("hand", frame)
    if hand is None and (twin_dir / TWIN_HAND_MASKS / f"{frame:06d}.png").is_file():
        hand = read_mask(twin_dir / TWIN_HAND_MASKS / f"{frame:06d}.png")
    if hand is not None:
        rec.log("world/camera/image/hand", rr.SegmentationImage(hand.astype(np.uint8) * HAND_LABEL))


__all__ = ["RerunConfig", "write_rerun"]
