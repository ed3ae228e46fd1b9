"""The FunREC version and, when FunREC runs from a git checkout, the commit: what ``--version``
prints and what a twin's config.json records."""

from __future__ import annotations

import subprocess
from functools import cache
from importlib import metadata
from pathlib import Path

SOURCE_VERSION = "0.1.0"
"""The version of this source tree (pyproject.toml's); ``funrec.__version__``."""
GIT_TIMEOUT_S = 5.0
"""Longest wait for ``git rev-parse`` (a network file system can be slow)."""


def funrec_version() -> str:
    """The installed distribution's version, or the source tree's when it is not installed."""
    try:
        return metadata.version("funrec")
    except metadata.PackageNotFoundError:
        return SOURCE_VERSION


@cache
def git_commit() -> str | None:
    """The commit of the git checkout FunREC is imported from, with ``-dirty`` when it has
    uncommitted changes; None when FunREC is not in a checkout or git is missing."""
    root = Path(__file__).resolve().parent.parent
    if not (root / ".git").exists():
        return None
    try:
        commit = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                                timeout=GIT_TIMEOUT_S, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=GIT_TIMEOUT_S, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return f"{commit}-dirty" if dirty else commit


def version_line(prog: str) -> str:
    """``prog 0.1.0 (git <commit>)``, the commit only when known."""
    commit = git_commit()
    return f"{prog} {funrec_version()}" + (f" (git {commit[:12]}{'-dirty' if commit.endswith('-dirty') else ''})" if commit else "")


__all__ = ["funrec_version", "git_commit", "version_line"]
