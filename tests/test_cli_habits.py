"""What users expect of any command line: --version, -q/-v anywhere with unchanged exit codes, a
short --help with the rest behind --help-all, a config dump, and the config recorded in the twin."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from funrec.config import config_from_dict, load_config_file
from funrec.formats.twin_config import TWIN_CONFIG_FORMAT, twin_config_json, write_twin_config
from funrec.version import funrec_version


def _run(module: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize(("module", "prog"), [("funrec", "funrec"), ("funrec_robot", "funrec-robot")])
def test_version(module: str, prog: str) -> None:
    result = _run(module, "--version")
    assert result.returncode == 0
    assert result.stdout.startswith(f"{prog} {funrec_version()}")


@pytest.mark.parametrize(
    "args",
    [
        ("check", "MISSING"),
        ("-v", "check", "MISSING"),
        ("check", "MISSING", "-v"),
        ("-q", "check", "MISSING"),
        ("check", "--quiet", "MISSING"),
    ],
)
def test_verbosity_anywhere_keeps_exit_code_2(args: tuple[str, ...], tmp_path: Path) -> None:
    result = _run("funrec", *(str(tmp_path / a) if a == "MISSING" else a for a in args))
    assert result.returncode == 2, result.stderr
    assert "capture folder does not exist" in result.stderr.splitlines()[-1]
    assert ("Traceback" in result.stderr) == ("-v" in args)


def test_robot_cli_takes_verbosity_after_the_command(tmp_path: Path) -> None:
    result = _run("funrec_robot", "describe", str(tmp_path / "no_robot.yaml"), "-q")
    assert result.returncode == 2, result.stderr
    assert _run("funrec_robot", "-v", "-q", "robots").returncode == 2  # exclusive: a usage error


def _main(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    """funrec's main() in this process (the stage modules are imported once, not per call)."""
    from funrec.cli import main

    try:
        code = main(list(args))
    except SystemExit as exc:  # --help, --help-all and usage errors exit from argparse
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def test_reconstruct_help_is_short_and_help_all_complete(capsys: pytest.CaptureFixture[str]) -> None:
    code, short, _ = _main(capsys, "reconstruct", "--help")
    assert code == 0
    assert len(short.splitlines()) < 120
    for flag in ("--print-config", "--help-all", "--export-snap-axis-deg", "--no-align-gravity", "-q, --quiet"):
        assert flag in short
    assert short.index("common options") < short.index("--export-snap-axis-deg")
    assert "--tracking-max-features" not in short
    code, full, _ = _main(capsys, "reconstruct", "--help-all")
    assert code == 0 and "--tracking-max-features" in full
    assert len(full.splitlines()) > 500


def test_print_config_round_trips(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from funrec.pipeline import ReconstructConfig

    code, printed, err = _main(capsys, "reconstruct", "--print-config", "--export-snap-axis-deg", "4", "--no-align-gravity")
    assert code == 0, err
    dumped = tmp_path / "config.json"
    dumped.write_text(printed)
    config = load_config_file(ReconstructConfig, dumped)
    assert config.export.snap_axis_deg == 4.0 and not config.align_gravity
    # A --config file's values survive (flags not given do not reset them to the defaults).
    code, again, _ = _main(capsys, "reconstruct", "--print-config", "--config", str(dumped))
    assert json.loads(again) == json.loads(printed)
    assert _main(capsys, "reconstruct", "--print-config", "-q")[0] == 0
    code, _, err = _main(capsys, "reconstruct", str(tmp_path))
    assert code == 2 and "-o/--output" in err


def test_twin_config_json_holds_config_version_and_commit(tmp_path: Path) -> None:
    from funrec.pipeline import ReconstructConfig

    config = ReconstructConfig(parts_per_fragment=2)
    write_twin_config(tmp_path / "config.json", config)
    data = json.loads((tmp_path / "config.json").read_text())
    assert data["format"] == TWIN_CONFIG_FORMAT and data["funrec_version"] == funrec_version()
    assert data["git_commit"] is None or len(data["git_commit"].removesuffix("-dirty")) == 40
    assert config_from_dict(ReconstructConfig, data["config"]) == config
    assert twin_config_json(config)["config"] == data["config"]


def test_a_stage_without_progress_is_named_while_it_runs(capsys: pytest.CaptureFixture[str]) -> None:
    """The pipeline reports stages without progress of their own (export) as 0/1 then 1/1; the log
    line names the stage and its time, not "1/1 frames"."""
    from funrec.cli_runner import stage_bars

    with stage_bars() as progress:
        progress("affordances", 3, 3)
        progress("export", 0, 1)
        progress("export", 1, 1)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0].strip().startswith("affordances: 3/3 frames in")
    assert lines[1].strip().startswith("export: done in")
