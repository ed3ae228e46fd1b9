"""Shared pytest fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def tiny_capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny generated capture (24 frames, 80x60, one cabinet door opened, hand masks) with
    ground truth in its gt/ folder (FORMATS.md sections 1 and 4)."""
    from funrec.synth import generate_sequence, tiny_spec

    return generate_sequence(tiny_spec(0), tmp_path_factory.mktemp("synth"))
