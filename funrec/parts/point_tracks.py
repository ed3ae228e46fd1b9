"""Sparse 3D point tracks in the world frame with per-frame visibility.

KLT tracks with a forward-backward check, re-seeded on a uniform grid (plus corners)
wherever no live track is near, so that surfaces revealed during the interaction (the
inside of a cabinet) get tracks too. Where a point has too little texture for KLT (a plain
painted door), it is carried by dense DIS optical flow instead (:mod:`funrec.camera.flow`),
checked forward and backward the same way. Classical stand-in for the paper's TAPIP3D.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from funrec.camera.features import depth_edges, detect_corners, lift, mask_at, sample_depth, track_klt
from funrec.camera.flow import FlowConfig, dense_flow, track_flow
from funrec.camera.tracking import CameraTrajectory
from funrec.formats.capture import Capture
from funrec.geometry.transforms import transform_points
from funrec.typed import BoolArray, FloatArray, UInt8Array

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class PointTracks:
    """N point tracks over F frames (a track exists from the frame it was seeded in)."""

    p_world: FloatArray
    """(F, N, 3) track positions in the world frame, metres; NaN where not visible."""
    uv: FloatArray
    """(F, N, 2) pixel positions (u column, v row); NaN where not visible."""
    visible: BoolArray
    """(F, N) True where the track was observed with valid depth."""

    def __post_init__(self) -> None:
        F, N = np.shape(self.visible)
        if np.shape(self.p_world) != (F, N, 3) or np.shape(self.uv) != (F, N, 2):
            raise ValueError(
                f"p_world must be (F, N, 3) and uv (F, N, 2) with visible (F, N) = {(F, N)}, "
                f"got {np.shape(self.p_world)}, {np.shape(self.uv)}"
            )

    @property
    def num_frames(self) -> int:
        return int(self.visible.shape[0])

    @property
    def num_tracks(self) -> int:
        return int(self.visible.shape[1])


@dataclass(frozen=True)
class PointTrackConfig:
    """Settings of :func:`track_points`.

    Memory: the result holds F x N x (3 + 2) float64 plus F x N bools, i.e. 41 bytes per
    frame and track (F = 1,000 frames, N = 2,000 tracks: 82 MB). While streaming, each
    frame's live observations are kept in float32 (24 bytes per observation).
    """

    grid_columns: int = 32
    """Columns of the seed grid of square cells (rows follow the aspect ratio): 20 px at 640
    wide. Each free cell seeds its best-textured pixel."""
    seed_radius: float = 0.75
    """No new track is seeded closer than this many grid steps to a live track."""
    reseed: bool = True
    """Seed new tracks during the capture; off follows only frame 0's seeds, so surfaces
    revealed later get no track (ablation)."""
    reseed_every: int = 3
    """Frames between two seeding passes (frame 0 is always seeded)."""
    corners_per_seed: int = 200
    """Shi-Tomasi corners tried per seeding pass before the grid points."""
    min_texture: float = 1e-4
    """Minimal eigenvalue of the structure tensor (cv2.cornerMinEigenVal, intensities in
    [0, 1]) at a grid seed (the best pixel of its cell); below it LK has no gradient to lock
    on to."""
    max_alive: int = 1000
    """Live tracks at most (bounds the per-frame cost, ~3 ms per 1,000 tracks at 640x480).
    500 was measured to saturate on rendered kitchens before the interaction, so no seed
    reached a door that only filled 5 % of the view (its live tracks: 35 -> 55)."""
    max_tracks: int = 5000
    """Tracks in the result at most (bounds its memory, see above: 250 frames x 5,000 tracks
    is 51 MB); seeding stops when the live tracks plus the finished ones long enough to keep
    reach it."""
    min_track_length: int = 3
    """Tracks visible in fewer frames are dropped from the result (too short to show motion)."""
    klt_window_px: int = 21
    """Lucas-Kanade window side, pixels."""
    klt_pyramid_levels: int = 3
    """Coarser pyramid levels; 3 follows ~60 px per frame at 640x480."""
    klt_max_forward_backward_px: float = 1.0
    """Round-trip error above which a track dies (occlusion, slipping along an edge), pixels."""
    depth_window_px: int = 5
    """Window for the robust depth of an observation, pixels (odd)."""
    subpixel_depth: bool = True
    """Read depth from the plane fitted to the depth window at the sub-pixel track position
    rather than the window median at the rounded pixel (see :func:`funrec.camera.features.sample_depth`)."""
    depth_max_spread: float = 0.05
    """A depth window spread beyond this fraction of its median is a depth edge: no 3D there."""
    min_depth_m: float = 0.2
    """Readings closer than this are ignored, metres (sensor minimum range)."""
    max_depth_m: float = 5.0
    """Readings farther than this are ignored, metres."""
    max_step_m: float = 0.05
    """A track whose world position jumps more than this between consecutive visible
    frames dies: it slipped onto an occluder (a hand) or across a depth edge. Opening a
    door moves its edge ~1-3 cm per frame at 15 fps."""
    depth_edge_step: float = 0.03
    """Two neighbouring pixels whose depths differ by more than this fraction of the nearer
    one are an occlusion edge: 3 cm at 1 m. A plane seen at 80 degrees incidence steps ~2 %
    per pixel at 320 px focal length, so slanted floors and walls stay trackable."""
    edge_margin_px: int = 8
    """Tracks within this distance of a depth discontinuity die and none are seeded there:
    the LK window (21 px) would straddle two surfaces, and the feature would slide along
    the occlusion boundary (a door edge against the cabinet interior) instead of following
    either surface."""
    hand_dilation_px: int = 9
    """Hand masks are grown by this many pixels; tracks there die and none are seeded."""
    dense_flow: bool = False
    """Carry points that KLT loses (no texture to lock on to) along dense DIS optical flow, and
    seed grid points regardless of texture (``min_texture`` then only orders the seeds of a
    cell). Off by default, measured: on the plain bench family's plain_rev_cabinet_left_00 it
    turned "no part" into a wrong part, because on a flat painted panel DIS drags the static
    neighbour door along with the moving one and its forward-backward check agrees (tests/test_flow.py).
    Plain fronts get their part from depth instead (:mod:`funrec.parts.depth_proposal`)."""
    flow: FlowConfig = FlowConfig()
    """Dense flow settings (used with ``dense_flow``)."""
    flow_max_forward_backward_px: float = 1.0
    """Round-trip error above which a flow-carried track dies, pixels (as for KLT)."""


@dataclass
class _Tracks:
    """Mutable streaming state: the live tracks (parallel arrays) and their counters."""

    ids: np.ndarray
    """(L,) track id."""
    uv: FloatArray
    """(L, 2) pixel in the current frame."""
    last_p_world: FloatArray
    """(L, 3) last lifted position (for the step test)."""
    visible_count: np.ndarray
    """(L,) frames with a valid observation so far."""
    next_id: int = 0
    finished_long: int = 0

    @classmethod
    def empty(cls) -> _Tracks:
        return cls(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0, np.int64))

    def keep(self, alive: BoolArray) -> None:
        for name in ("ids", "uv", "last_p_world", "visible_count"):
            setattr(self, name, getattr(self, name)[alive])

    def add(self, uv: FloatArray, p_world: FloatArray) -> np.ndarray:
        """Start tracks at pixels uv (M, 2) lifted to p_world (M, 3); returns their ids."""
        ids = np.arange(self.next_id, self.next_id + len(uv))
        self.next_id += len(uv)
        self.ids = np.concatenate([self.ids, ids])
        self.uv = np.concatenate([self.uv, uv])
        self.last_p_world = np.concatenate([self.last_p_world, p_world])
        self.visible_count = np.concatenate([self.visible_count, np.ones(len(uv), np.int64)])
        return ids


def _hand_free(capture: Capture, frame: int, config: PointTrackConfig) -> BoolArray | None:
    hand = capture.mask("hand", frame)
    if hand is None or not hand.any():
        return None
    size = 2 * config.hand_dilation_px + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    return cv2.dilate(hand.astype(np.uint8), kernel) == 0


def _best_in_cells(gray: UInt8Array, free: BoolArray, step: float, min_texture: float) -> FloatArray:
    """(M, 2) pixel of largest texture (minimal structure-tensor eigenvalue) in each cell of a
    grid with the given step, among free pixels above ``min_texture``; best cells first.

    The best pixel of a cell, rather than the cell centre, is what puts seeds on weakly
    textured surfaces (a painted door): there most pixels are flat and a fixed grid point
    usually lands on one, while almost every cell holds some grain LK can lock on to.
    """
    H, W = gray.shape
    side = max(2, int(round(step)))
    rows, cols = H // side, W // side
    texture = cv2.cornerMinEigenVal(gray.astype(np.float32) / 255.0, blockSize=7, ksize=3)
    score = np.where(free, texture, -np.inf)[: rows * side, : cols * side]  # a taken pixel never seeds
    cells = score.reshape(rows, side, cols, side).transpose(0, 2, 1, 3).reshape(rows, cols, side * side)
    best = cells.argmax(-1)
    good = np.take_along_axis(cells, best[..., None], -1)[..., 0] > min_texture
    r, c = np.nonzero(good)
    order = np.argsort(-cells[r, c, best[r, c]], kind="stable")
    r, c = r[order], c[order]
    dv, du = np.divmod(best[r, c], side)
    return np.stack([c * side + du, r * side + dv], axis=1).astype(np.float64)


def _seed(gray: UInt8Array, depth_m: FloatArray, allowed: BoolArray, live_uv: FloatArray, budget: int,
          config: PointTrackConfig) -> FloatArray:
    """(M, 2) new seed pixels: corners, then the best-textured pixel of each grid cell, away
    from live tracks."""
    H, W = gray.shape
    step = W / config.grid_columns
    radius = max(1, int(round(config.seed_radius * step)))
    free = allowed & (depth_m > 0)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))

    def block(uv: FloatArray) -> None:
        taken = np.zeros((H, W), np.uint8)
        taken[np.clip(np.rint(uv[:, 1]).astype(int), 0, H - 1), np.clip(np.rint(uv[:, 0]).astype(int), 0, W - 1)] = 1
        free[cv2.dilate(taken, kernel) > 0] = False

    if len(live_uv):
        block(live_uv)
    corners = detect_corners(gray, free, min(budget, config.corners_per_seed), 0.01, radius)
    if len(corners):
        block(corners)
    grid = _best_in_cells(gray, free, step, -1.0 if config.dense_flow else config.min_texture)
    return np.concatenate([corners, grid])[:budget]


def track_points(
    capture: Capture,
    trajectory: CameraTrajectory,
    config: PointTrackConfig = PointTrackConfig(),
    progress: Callable[[int, int], None] | None = None,
) -> PointTracks:
    """Track sparse surface points through the capture and lift them to the world frame.

    Tracks follow whatever surface they lie on, static or moving (a door), which is what
    articulation estimation needs. Frames are streamed one at a time.

    Args:
        capture: the RGB-D capture; when it has hand masks, no track is seeded on or
            followed onto the hand.
        trajectory: (F, 4, 4) camera-to-world poses from :func:`funrec.camera.tracking.track_camera`.
        config: tracking settings.
        progress: optional callback ``progress(done, total)`` after each frame.

    Returns:
        Tracks ordered by the frame they were seeded in; a track is visible where it was
        followed and had valid depth, and NaN elsewhere.
    """
    F = len(capture)
    if len(trajectory.T_world_camera) != F:
        raise ValueError(f"trajectory has {len(trajectory.T_world_camera)} poses, capture has {F} frames")
    K = capture.intrinsics.K
    state = _Tracks.empty()
    log: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    previous_gray: UInt8Array | None = None
    for frame in range(F):
        gray = capture.gray(frame)
        depth_m = capture.depth_m(frame)
        depth_m = np.where((depth_m >= config.min_depth_m) & (depth_m <= config.max_depth_m), depth_m, 0.0)
        hand_free = _hand_free(capture, frame, config)
        allowed = ~depth_edges(depth_m, config.edge_margin_px, config.depth_edge_step)
        if hand_free is not None:
            allowed &= hand_free
        T_world_camera = trajectory.T_world_camera[frame]
        alive = np.zeros(len(state.ids), dtype=bool)
        p_world = np.full((len(state.ids), 3), np.nan)
        if previous_gray is not None and len(state.ids):
            uv_klt, alive = track_klt(previous_gray, gray, state.uv, config.klt_window_px,
                                      config.klt_pyramid_levels, config.klt_max_forward_backward_px)
            if config.dense_flow and not alive.all():
                uv_flow, ok_flow = track_flow(dense_flow(previous_gray, gray, config.flow),
                                              dense_flow(gray, previous_gray, config.flow), state.uv,
                                              config.flow_max_forward_backward_px)
                uv_klt = np.where(alive[:, None], uv_klt, uv_flow)
                alive |= ok_flow
            state.uv = uv_klt
            alive &= mask_at(allowed, state.uv)
            z = sample_depth(depth_m, state.uv, config.depth_window_px, config.depth_max_spread, config.subpixel_depth)
            p_world = transform_points(T_world_camera, lift(state.uv, z, K))
            step = np.linalg.norm(p_world - state.last_p_world, axis=1)
            alive &= ~(step > config.max_step_m)  # NaN steps (no depth now or before) pass
        visible = alive & np.isfinite(p_world[:, 2])
        state.last_p_world = np.where(visible[:, None], p_world, state.last_p_world)
        state.visible_count += visible
        state.finished_long += int(np.sum(~alive & (state.visible_count >= config.min_track_length)))
        state.keep(alive)
        observed_ids, observed_uv, observed_p = [state.ids[visible[alive]]], [state.uv[visible[alive]]], [p_world[visible]]
        if frame % config.reseed_every == 0 and (config.reseed or frame == 0):
            budget = min(config.max_alive - len(state.ids), config.max_tracks - len(state.ids) - state.finished_long)
            if budget > 0:
                uv_new = _seed(gray, depth_m, allowed, state.uv, budget, config)
                z_new = sample_depth(depth_m, uv_new, config.depth_window_px, config.depth_max_spread, config.subpixel_depth)
                uv_new, z_new = uv_new[np.isfinite(z_new)], z_new[np.isfinite(z_new)]
                p_new = transform_points(T_world_camera, lift(uv_new, z_new, K))
                observed_ids.append(state.add(uv_new, p_new))
                observed_uv.append(uv_new)
                observed_p.append(p_new)
        log.append((np.concatenate(observed_ids).astype(np.int32), np.concatenate(observed_uv).astype(np.float32),
                    np.concatenate(observed_p).astype(np.float32)))
        previous_gray = gray
        if progress is not None:
            progress(frame + 1, F)
    return _assemble(log, state.next_id, F, config)


def _assemble(log: list[tuple[np.ndarray, np.ndarray, np.ndarray]], total: int, F: int,
              config: PointTrackConfig) -> PointTracks:
    """Dense (F, N, ...) arrays from the per-frame observation log (consumed: emptied as the
    arrays fill), keeping tracks seen in at least ``min_track_length`` frames (the longest
    ``max_tracks`` if more)."""
    counts = np.zeros(total, np.int64)
    for ids, _, _ in log:
        counts[ids] += 1
    keep = np.flatnonzero(counts >= config.min_track_length)
    if len(keep) > config.max_tracks:
        keep = np.sort(keep[np.argsort(-counts[keep], kind="stable")[: config.max_tracks]])
    column = np.full(total, -1, np.int64)
    column[keep] = np.arange(len(keep))
    N = len(keep)
    p_world = np.full((F, N, 3), np.nan)
    uv = np.full((F, N, 2), np.nan)
    visible = np.zeros((F, N), dtype=bool)
    log.reverse()  # pop() now yields frame 0 first; each frame's log is freed once copied
    for frame in range(F):
        ids, frame_uv, frame_p = log.pop()
        columns = column[ids]
        kept = columns >= 0
        p_world[frame, columns[kept]] = frame_p[kept]
        uv[frame, columns[kept]] = frame_uv[kept]
        visible[frame, columns[kept]] = True
    logger.info("%d point tracks kept of %d seeded over %d frames", N, total, F)
    return PointTracks(p_world=p_world, uv=uv, visible=visible)


__all__ = ["PointTrackConfig", "PointTracks", "track_points"]
