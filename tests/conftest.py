"""Shared pytest fixtures."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from tests.helpers.stage_inputs import EstimatedRun


@pytest.fixture(autouse=True, scope="session")
def _private_config_home(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Keys, tokens and certificates of funrec-robot go to a throwaway $XDG_CONFIG_HOME, never the user's."""
    import os

    os.environ["XDG_CONFIG_HOME"] = str(tmp_path_factory.mktemp("xdg_config"))


@pytest.fixture(scope="session")
def tiny_capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny generated capture (24 frames, 80x60, one cabinet door opened, hand masks) with
    ground truth in its gt/ folder (FORMATS.md sections 1 and 4)."""
    from funrec.synth import generate_sequence, tiny_spec

    return generate_sequence(tiny_spec(0), tmp_path_factory.mktemp("synth"))


@pytest.fixture(scope="session")
def smoke_captures(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The rendered 320x240 smoke sequences (funrec.synth.smoke_suite): a cabinet door and a
    drawer opened (75 frames each, hand masks) and a camera-only walk (45 frames, no masks),
    Kinect-like depth noise, ground truth in gt/; ~1-2 min to generate, so only slow tests
    use them."""
    from funrec.synth import generate_sequence, smoke_suite

    out = tmp_path_factory.mktemp("smoke")
    specs = {spec.name: spec for spec in smoke_suite()}
    return {name: generate_sequence(specs[name], out) for name in ("smoke_rev_00", "smoke_pri_00", "smoke_static_00")}


@pytest.fixture(scope="session")
def small_sequence(request: pytest.FixtureRequest) -> Path:
    """A 40-frame 320x240 noisy kitchen with one revolute door (~25 s to generate, then cached
    across test runs in pytest's cache folder)."""
    from tests.helpers.stage_inputs import synth_sequence

    return synth_sequence(request.config.cache.mkdir("funrec_synth"), "seg_rev_320", 7, "door", 40, 320, 240)


@pytest.fixture(scope="session", params=["smoke_rev_00", "smoke_pri_00"])
def estimated_run(request: pytest.FixtureRequest) -> EstimatedRun:
    """Stages 1-5 on funrec.synth's smoke door and drawer: ~1 min per capture (plus ~45 s to
    generate it the first time); slow tests only."""
    from tests.helpers.stage_inputs import estimate_run, smoke_sequence

    return estimate_run(request.param, smoke_sequence(request.config.cache.mkdir("funrec_synth"), request.param))


@pytest.fixture(scope="module")
def robot():
    """The default robot (funrec_robot.default_robot_path); modules that test another define their own."""
    from funrec_robot import default_robot_path, load_robot

    return load_robot(default_robot_path())


@pytest.fixture()
def endpoint(robot):
    """serve-sim for ``robot`` on a free localhost port, in a thread: (server, "host:port")."""
    import threading

    from funrec_robot.sim_server import SimServerConfig, make_sim_server

    server = make_sim_server(robot, None, SimServerConfig(port=0, heartbeat_timeout=0.5))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    host, port = server.server_address[:2]
    yield server, f"{host}:{port}"
    server.shutdown()
    thread.join(5.0)
    server.server_close()
