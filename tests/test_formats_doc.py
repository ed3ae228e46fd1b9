"""docs/formats.md is the project's data contract; its sections 1-5 must be the outside scorers' copy word for word."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("FUNREC_SHARED_FORMATS", ROOT.parent / "shared" / "FORMATS.md"))


def test_project_contract_contains_the_scorers_copy() -> None:
    if not SHARED.is_file():
        pytest.skip(f"no scorers' copy at {SHARED} (set FUNREC_SHARED_FORMATS)")
    ours = (ROOT / "docs" / "formats.md").read_text()
    theirs = SHARED.read_text().strip()
    assert theirs in ours, "docs/formats.md sections 1-5 differ from the scorers' FORMATS.md: a format change bumps both"


def test_every_format_tag_in_the_code_is_documented() -> None:
    doc = (ROOT / "docs" / "formats.md").read_text()
    from funrec.formats.affordances import AFFORDANCES_FORMAT
    from funrec.formats.fragments import FRAGMENTS_FORMAT
    from funrec.formats.twin import TWIN_FORMAT

    for tag in (TWIN_FORMAT, AFFORDANCES_FORMAT, FRAGMENTS_FORMAT):
        assert f'"format": "{tag}"' in doc, f"{tag} is written by the code but not specified in docs/formats.md"
