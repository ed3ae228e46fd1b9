"""Where tests find the robot files and the MuJoCo Menagerie models they name: the models live outside the
repository (FUNREC_ROBOT_MODELS, default ../shared/robots next to the checkout); without them these tests skip."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from funrec_robot.robot_yaml import MODELS_ENV

ROBOTS = Path(__file__).resolve().parents[2] / "robots"
"""The repository's robot files."""
MODELS = Path(os.environ.get(MODELS_ENV, Path(__file__).resolve().parents[3] / "shared" / "robots"))
"""The models folder the robot files name their models relative to."""


def needs_models(folder: str) -> pytest.MarkDecorator:
    """Skip unless the models folder holds ``folder`` (e.g. "boston_dynamics_spot")."""
    return pytest.mark.skipif(not (MODELS / folder).is_dir(), reason=f"robot models not found in {MODELS}")
