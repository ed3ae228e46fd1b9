"""Run every script in demos/ as a newcomer would (``python demos/NAME.py ...``), so they do not silently break."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

DEMOS = Path(__file__).resolve().parents[1] / "demos"


def _run(script: str, *args: str, timeout: float = 1200) -> str:
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    result = subprocess.run([sys.executable, str(DEMOS / script), *args], capture_output=True, text=True, env=env,
                            timeout=timeout, cwd=DEMOS.parent)
    assert result.returncode == 0, f"{script} failed:\n{result.stdout[-2000:]}\n{result.stderr[-3000:]}"
    return result.stdout


def _moved(output: str, engine: str) -> dict[str, float]:
    return {m[0]: float(m[1]) for m in re.findall(rf"(\w+): {engine} \w+ at lower limit .* moved ([0-9.]+) m", output)}


def _check_joints_move_alike(output: str) -> None:
    in_mujoco, in_urdf = _moved(output, "MuJoCo"), _moved(output, "URDF")
    assert in_mujoco and in_mujoco.keys() == in_urdf.keys()
    for name, distance in in_mujoco.items():
        # Both exports carry the same link frames and centres of mass; printed to 0.1 mm.
        assert distance == pytest.approx(in_urdf[name], abs=2e-4) and distance > 0.005, name


def test_export_and_move_joints_on_a_written_twin(tmp_path):
    from tests.helpers.twins import export  # the hand-built cabinet twin (a door and a drawer), exported fast

    exports = export(tmp_path)
    output = _run("export_and_move_joints.py", "--twin", str(exports.mjcf.parent), timeout=300)
    assert "2 joint(s) in twin.xml, 2 in twin.urdf" in output
    _check_joints_move_alike(output)


@pytest.fixture(scope="module")
def demo_output(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("demo")
    return out, _run("reconstruct_and_view.py", "-o", str(out))


@pytest.mark.slow  # renders a smoke capture and reconstructs it: a minute or more
def test_reconstruct_and_view(demo_output):
    out, output = demo_output
    assert "part_0: revolute" in output and (out / "twin" / "articulation.json").is_file()
    assert len(list((out / "render").glob("*.png"))) >= 2


@pytest.mark.slow
def test_export_and_query_on_the_reconstructed_twin(demo_output):
    out, _ = demo_output
    _check_joints_move_alike(_run("export_and_move_joints.py", "--twin", str(out / "twin")))
    output = _run("query_affordance.py", "--twin", str(out / "twin"))
    assert re.search(r"part_0 at state [-0-9.]+: grasp at \[", output)


@pytest.mark.slow  # plans with the robot and simulates it in MuJoCo: tens of seconds
def test_replay_on_robot(demo_output):
    out, _ = demo_output
    output = _run("replay_on_robot.py", "--twin", str(out / "twin"), "--capture", str(out / "captures" / "smoke_rev_00"),
                  "-o", str(out / "robot"))
    assert "planned part_0 (revolute)" in output and output.splitlines()[-1].startswith("PASS")
