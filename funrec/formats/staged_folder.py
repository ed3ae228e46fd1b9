"""Output folders that appear only when complete: written into a temporary sibling folder and renamed into
place at the end, so a failed run never leaves a half-written twin or capture and never loses the old one.

Used by :class:`funrec.export.twin.TwinWriter` and :class:`funrec.convert.output.CaptureOutput`. A killed run
leaves only a ``.NAME.partial-*`` sibling, which ``funrec batch`` removes before redoing that capture. Single
files (videos, reports, recordings, check records) go through :func:`staged_file`: an interrupted run (Ctrl-C
included) leaves neither a half-written file nor a temporary one.
"""

from __future__ import annotations

import os
import secrets
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from funrec.errors import FunrecError


def refuse_output_over_input(out_path: str | Path, *inputs: str | Path) -> None:
    """Refuse an output that is an input, lies inside one, or contains one: replacing it would delete the input.

    Raises:
        FunrecError: naming both paths.
    """
    out = Path(out_path).resolve()
    for source in inputs:
        source = Path(source).resolve()
        if out == source or source in out.parents or out in source.parents:
            relation = "is" if out == source else ("is inside" if source in out.parents else "contains")
            raise FunrecError(f"{out_path}: the output {relation} the input {source}; writing it would destroy the input, "
                              "choose another -o")


def stage_folder(out_dir: Path, overwrite: bool) -> Path:
    """A new empty ``.NAME.partial-*`` folder beside ``out_dir`` to write into.

    Raises:
        FunrecError: ``out_dir`` exists and is not an empty folder, and ``overwrite`` is False.
    """
    if out_dir.exists() and not overwrite:
        if not out_dir.is_dir() or any(out_dir.iterdir()):
            raise FunrecError(f"{out_dir}: output exists and is not empty (use --overwrite to replace it)")
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.partial-", dir=out_dir.parent))


def publish_folder(staged: Path, out_dir: Path) -> None:
    """Move the complete ``staged`` folder to ``out_dir``; an existing ``out_dir`` is renamed aside first and
    deleted only once the new folder is in place."""
    old = None
    if out_dir.exists():
        old = out_dir.with_name(f".{out_dir.name}.old-{staged.name.rsplit('-', 1)[-1]}")
        out_dir.rename(old)
    staged.rename(out_dir)
    if old is not None:
        if old.is_dir() and not old.is_symlink():
            shutil.rmtree(old, ignore_errors=True)
        else:
            old.unlink(missing_ok=True)  # a file was replaced by the folder: no .NAME.old-* left behind


def discard_folder(staged: Path) -> None:
    """Delete a staged folder after a failure (``out_dir`` is untouched)."""
    shutil.rmtree(staged, ignore_errors=True)


@contextmanager
def staged_file(path: str | Path) -> Iterator[Path]:
    """A temporary sibling of ``path`` (``.STEM.partial-*`` with the same suffix, so writers that go by it still
    work) to write into: renamed over ``path`` when the block ends, deleted when it raises (KeyboardInterrupt
    included), so ``path`` is either the old file or the complete new one."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # named, not created: the writer creates it with the usual permissions (mkstemp's would be 0600)
    tmp = path.with_name(f".{path.stem}.partial-{os.getpid()}-{secrets.token_hex(4)}{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text_staged(path: str | Path, text: str) -> Path:
    """Write a text file through :func:`staged_file`."""
    with staged_file(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def publish_files(staged: Path, out_dir: Path) -> list[Path]:
    """Move every file of the complete ``staged`` folder into ``out_dir`` (created; other files there are kept),
    then remove ``staged``; returns the moved files' new paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    moved = []
    for item in sorted(staged.iterdir()):
        os.replace(item, out_dir / item.name)
        moved.append(out_dir / item.name)
    shutil.rmtree(staged, ignore_errors=True)
    return moved


__all__ = ["discard_folder", "publish_files", "publish_folder", "refuse_output_over_input", "stage_folder", "staged_file",
           "write_text_staged"]
