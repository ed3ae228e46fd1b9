"""The twin folder appears only when complete."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from funrec.errors import FunrecError
from funrec.export import TwinWriter
from funrec.formats.twin import TwinArticulation, make_part, read_articulation


def _articulation() -> TwinArticulation:
    part = make_part("part_0", "prismatic", [1.0, 0, 0], None, [0, 1], [0.0, 0.1], masks="masks/part_0")
    return TwinArticulation(frame_count=2, parts=(part,))


def test_complete_twin_is_moved_into_place(tmp_path: Path) -> None:
    out = tmp_path / "twin"
    with TwinWriter(out) as twin:
        twin.write_mask("part_0", 1, np.ones((4, 5), bool))
        twin.write_camera_poses(np.broadcast_to(np.eye(4), (2, 4, 4)))
        twin.write_articulation(_articulation())
        assert not out.exists()
    assert read_articulation(out).parts[0].name == "part_0"
    assert (out / "masks" / "part_0" / "000001.png").is_file()
    assert [p.name for p in tmp_path.iterdir()] == ["twin"]


def test_failure_leaves_existing_output_untouched(tmp_path: Path) -> None:
    out = tmp_path / "twin"
    out.mkdir()
    (out / "keep.txt").write_text("old")
    with pytest.raises(RuntimeError), TwinWriter(out, overwrite=True) as twin:
        twin.write_articulation(_articulation())
        raise RuntimeError("stage crashed")
    assert (out / "keep.txt").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["twin"]


def test_existing_output_needs_overwrite(tmp_path: Path) -> None:
    out = tmp_path / "twin"
    out.mkdir()
    (out / "keep.txt").write_text("old")
    with pytest.raises(FunrecError, match="output exists and is not empty"), TwinWriter(out):
        pass
    with TwinWriter(out, overwrite=True) as twin:
        twin.write_articulation(_articulation())
    assert not (out / "keep.txt").exists() and (out / "articulation.json").is_file()


def test_twin_without_articulation_is_not_published(tmp_path: Path) -> None:
    with pytest.raises(FunrecError, match="twin incomplete"), TwinWriter(tmp_path / "twin"):
        pass
    assert not (tmp_path / "twin").exists()
