"""config.json of a twin folder (funrec-twin/2, optional): the full settings the twin was made
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


def twin_config_json(config: Any) -> dict[str, Any]:
    """The content of config.json for a (ReconstructConfig) config object.

    Keys: ``format``; ``funrec_version``; ``git_commit`` (40 hex digits, ``-dirty`` appended when
    the checkout had uncommitted changes, or null); ``config``: every field of the config, nested
    stage configs as objects, exactly what ``funrec reconstruct --config`` reads back.
    """
    return {
        "format": TWIN_CONFIG_FORMAT,
        "funrec_version": funrec_version(),
        "git_commit": git_commit(),
        "config": config_to_dict(config),
    }


def write_twin_config(path: str | Path, config: Any) -> None:
    """Write config.json (see :func:`twin_config_json`)."""
    Path(path).write_text(json.dumps(twin_config_json(config), indent=2) + "\n")


__all__ = ["TWIN_CONFIG_FILE", "TWIN_CONFIG_FORMAT", "twin_config_json", "write_twin_config"]
