"""funrec render writes pictures of a twin at several joint states."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from funrec.export.simulation import export_simulation
from funrec.formats.camera_poses import write_camera_poses
from funrec.geometry import make_transform
from funrec.render import RenderConfig, render_twin
from tests.helpers.twins import FAST_EXPORT, write_cabinet_twin


def test_render_shows_the_part_moving(tmp_path: Path) -> None:
    twin = tmp_path / "twin"
    articulation = write_cabinet_twin(twin)
    # A camera 1.5 m in front of the door, looking at it (OpenCV axes: z forward, y down).
    p_world_door = trimesh.load(twin / articulation.parts[0].mesh).centroid
    p_world_camera = p_world_door + [0.3, -1.5, 0.4]
    z = (p_world_door - p_world_camera) / np.linalg.norm(p_world_door - p_world_camera)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    T_world_camera = make_transform(np.stack([x, np.cross(z, x), z], axis=1), p_world_camera)
    write_camera_poses(twin / "camera_poses.txt", np.stack([T_world_camera] * articulation.frame_count))
    export_simulation(twin, FAST_EXPORT)
    paths = render_twin(twin, tmp_path / "render", RenderConfig(width=320, height=240, states=3))
    names = [p.name for p in paths]
    assert names[0] == "overview.png" and names[-1] == "twin.gif"
    assert len(paths) == 2 + 3 * len(articulation.parts)
    first, last = (np.asarray(Image.open(tmp_path / "render" / f"part_0_state{k}.png"), float) for k in (0, 2))
    assert first.shape == (240, 320, 3)
    # The door swings across its range: a few percent of the picture changes (the door covers ~15 %).
    assert np.mean(np.abs(first - last).max(axis=2) > 10) > 0.02
    # Each image is labelled along the top: a dark band with white text (the part name and state).
    band = first[:12]
    assert np.mean(band.max(axis=2) < 40) > 0.5 and (band.min(axis=2) > 200).any()


def test_render_labels_part_and_state(tmp_path: Path) -> None:
    from funrec.formats.twin import make_part
    from funrec.render import _state_label

    door = make_part("part_0", "revolute", [0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0, 1], [0.0, np.pi / 4])
    drawer = make_part("part_1", "prismatic", [1.0, 0.0, 0.0], None, [0, 1], [0.0, 0.12])
    assert _state_label(door, np.pi / 4) == "part_0 (revolute) state 0.785 rad (45.0 deg)"
    assert _state_label(drawer, 0.12) == "part_1 (prismatic) state 0.120 m"


def test_ctrl_c_while_rendering_leaves_no_pictures(tmp_path: Path, monkeypatch) -> None:
    """The pictures appear in the output folder together at the end; an interrupted render leaves none there
    (other files of the folder are kept) and no staged folder beside it."""
    import pytest

    from funrec import render

    twin = tmp_path / "twin"
    articulation = write_cabinet_twin(twin)
    write_camera_poses(twin / "camera_poses.txt", np.stack([np.eye(4)] * articulation.frame_count))
    export_simulation(twin, FAST_EXPORT)
    out = tmp_path / "render"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    shots = []
    label = render._draw_label

    def interrupt_at_the_third(image, text):  # noqa: ANN001
        shots.append(text)
        if len(shots) == 3:
            raise KeyboardInterrupt
        label(image, text)

    monkeypatch.setattr(render, "_draw_label", interrupt_at_the_third)
    with pytest.raises(KeyboardInterrupt):
        render_twin(twin, out, RenderConfig(width=160, height=120, states=3))
    assert [p.name for p in out.iterdir()] == ["notes.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["render", "twin"]
