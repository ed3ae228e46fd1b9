"""Issue 15's data and time safety in funrec: an output over its input is refused before anything is
written, replacing a file leaves nothing behind, image sizes are bounded before decoding, and `funrec check`
fails captures that no reconstruction can use."""

from __future__ import annotations

from pathlib import Path

import pytest

from funrec.cli import main
from funrec.errors import FunrecError
from funrec.formats.staged_folder import publish_folder, refuse_output_over_input, stage_folder


def test_reconstruct_refuses_an_output_equal_to_or_inside_its_capture(tmp_path: Path, capsys) -> None:
    capture = tmp_path / "cap"
    (capture / "rgb").mkdir(parents=True)
    (capture / "rgb" / "000000.jpg").write_bytes(b"keep me")
    assert main(["reconstruct", str(capture), "-o", str(capture), "--overwrite"]) == 2
    assert "the output is the input" in capsys.readouterr().err
    assert main(["reconstruct", str(capture), "-o", str(capture / "twin"), "--overwrite"]) == 2
    assert "the output is inside the input" in capsys.readouterr().err
    assert (capture / "rgb" / "000000.jpg").read_bytes() == b"keep me"
    with pytest.raises(FunrecError, match="the output contains the input"):
        refuse_output_over_input(tmp_path, capture)
    refuse_output_over_input(tmp_path / "twin", capture)  # a sibling is fine


def test_replacing_a_file_with_a_folder_leaves_no_old_copy(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.write_text("a file")
    staged = stage_folder(out, overwrite=True)
    (staged / "x.json").write_text("{}")
    publish_folder(staged, out)
    assert (out / "x.json").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
