"""config.json of a twin folder (funrec-config/1, optional; docs/formats.md section 10): the full settings the twin was made
with, the FunREC version and the git commit when FunREC ran from a checkout, so a twin can be
remade or its settings compared with another's."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from funrec.config import config_to_dict
from funrec.version import funrec_version, git_commit

TWIN_CONFIG_FILE = "config.json"
"""Name of the file inside the twin folder."""
TWIN_CONFIG_FORMAT = "funrec-config/1"
"""Format tag written into config.json."""


def twin_config_json(config: Any, capture_dir: str | Path | None = None) -> dict[str, Any]:
    """The content of config.json for a (ReconstructConfig) config object.

    Keys: ``format``; ``funrec_version``; ``git_commit`` (40 hex digits, ``-dirty`` appended when
    the checkout had uncommitted changes, or null); ``capture``: the absolute path of the capture
    folder the twin was made from (or null); ``config``: every field of the config, nested stage
    configs as objects, exactly what ``funrec reconstruct --config`` reads back.
    """
    return {
        "format": TWIN_CONFIG_FORMAT,
        "funrec_version": funrec_version(),
        "git_commit": git_commit(),
        "capture": None if capture_dir is None else str(Path(capture_dir).resolve()),
        "config": config_to_dict(config),
    }


def write_twin_config(path: str | Path, config: Any, capture_dir: str | Path | None = None) -> None:
    """Write config.json (see :func:`twin_config_json`)."""
    Path(path).write_text(json.dumps(twin_config_json(config, capture_dir), indent=2) + "\n")


def recorded_capture(twin_dir: str | Path) -> Path | None:
    """The capture folder a twin's config.json names, if it has one and it still exists."""
    path = Path(twin_dir) / TWIN_CONFIG_FILE
    if not path.is_file():
        return None
    capture = json.loads(path.read_text()).get("capture")
    return Path(capture) if capture and Path(capture).is_dir() else None


__all__ = ["TWIN_CONFIG_FILE", "TWIN_CONFIG_FORMAT", "recorded_capture", "twin_config_json", "write_twin_config"]
