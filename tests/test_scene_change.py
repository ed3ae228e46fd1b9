"""Scene change unexplained by the camera, on a generated capture with a panel that goes away."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from funrec.formats.capture import CaptureIntrinsics, CaptureWriter, load_capture
from funrec.parts.fragments import FragmentConfig
from funrec.parts.scene_change import scene_change

INTRINSICS = CaptureIntrinsics(160, 120, 120.0, 120.0, 79.5, 59.5)
FRAMES = 12
GONE_FROM = 6
"""The panel is there in frames 0-5 and gone (swung away) from frame 6 on."""


def _capture(root: Path, hand_over_panel: bool = False) -> tuple[Path, np.ndarray]:
    """A wall at z = 2 m and a 0.6 x 0.4 m panel at z = 1.5 m, seen by a camera sliding 3 cm per
    frame along x (depth rendered analytically); returns the folder and T_world_camera."""
    writer = CaptureWriter(root, INTRINSICS)
    u, v = np.meshgrid(np.arange(160.0), np.arange(120.0))
    dx, dy = (u - INTRINSICS.cx) / INTRINSICS.fx, (v - INTRINSICS.cy) / INTRINSICS.fy
    T_world_camera = np.tile(np.eye(4), (FRAMES, 1, 1))
    for f in range(FRAMES):
        tx = 0.03 * f
        T_world_camera[f, 0, 3] = tx
        on_panel = (np.abs(tx + 1.5 * dx) < 0.3) & (np.abs(1.5 * dy) < 0.2)
        depth = np.where(on_panel & (f < GONE_FROM), 1.5, 2.0)
        hand = on_panel if hand_over_panel else None
        writer.write_frame(f, np.full((120, 160, 3), 128, np.uint8), depth, hand_mask=hand)
    return root, T_world_camera


def test_camera_motion_alone_is_no_change_and_a_vanished_panel_is(tmp_path: Path) -> None:
    root, T_world_camera = _capture(tmp_path / "cap")
    change = scene_change(load_capture(root), T_world_camera)
    assert change.shape == (FRAMES,)
    static_pairs = [i for i in range(FRAMES - 3) if i + 3 < GONE_FROM or i >= GONE_FROM]
    across = [i for i in range(FRAMES - 3) if i < GONE_FROM <= i + 3]
    # Exact depth, exact poses: nothing is seen through while the scene stays; allow the stay
    # threshold of the fragments (0.3 %) for pixel rounding at the panel's silhouette.
    assert change[static_pairs].max() < FragmentConfig().stay_fraction
    # the panel covers 8 % of the view (48 x 32 px); across its removal the later frame sees the
    # wall through it (one of the two pooled directions: ~4 %), above the 1 % that starts a fragment
    assert change[across].min() > 3 * FragmentConfig().enter_fraction
    assert np.all(change[FRAMES - 3 :] == 0.0)


def test_hand_pixels_are_not_scene_change(tmp_path: Path) -> None:
    root, T_world_camera = _capture(tmp_path / "cap", hand_over_panel=True)
    change = scene_change(load_capture(root), T_world_camera)
    assert change.max() < FragmentConfig().stay_fraction
