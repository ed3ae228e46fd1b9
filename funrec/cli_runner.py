"""What every FunREC command line shares: running a parsed command with the project's exit
codes, and progress bars (which belong to the CLI layer, never to the library)."""

from __future__ import annotations

import argparse
import logging
import sys
import time
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from funrec.errors import FunrecError

EXIT_OK = 0
EXIT_BUG = 1
"""An unexpected exception: a bug, reported with its traceback."""
EXIT_BAD_INPUT = 2
"""A FunrecError: bad input or an impossible request, one line on stderr."""


_quiet = False
"""Set by run_command for ``-q``: progress bars draw nothing."""


def add_common_options(parser: argparse.ArgumentParser) -> None:
    """``--version``, and ``-v``/``-q`` accepted before or after the subcommand: on the top-level
    parser and on every subcommand's (there with a suppressed default, so a flag given before the
    subcommand is not reset by the subcommand's parser)."""
    from funrec.version import version_line

    parser.add_argument("--version", action="version", version=version_line(parser.prog))
    subparsers = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    for p, default in [(parser, False)] + [(sub, argparse.SUPPRESS) for a in subparsers for sub in a.choices.values()]:
        group = p.add_mutually_exclusive_group()
        group.add_argument("-v", "--verbose", action="store_true", default=default,
                           help="log detail and print the traceback of an error (exit codes stay the same)")
        group.add_argument("-q", "--quiet", action="store_true", default=default,
                           help="no progress bars, only errors on stderr (results still go to stdout)")


def run_command(parser: argparse.ArgumentParser, argv: list[str] | None) -> int:
    """Parse ``argv``, set up logging (``-v`` detail, ``-q`` errors only) and run ``args.handler(args)``.

    Exit codes, whatever the verbosity: 0 success, 2 on :class:`FunrecError` (one line on stderr,
    after the traceback with ``--verbose``), 1 on any other exception (the traceback), 130 on
    Ctrl-C.
    """
    global _quiet
    add_common_options(parser)
    args = parser.parse_args(argv)
    if args.verbose and args.quiet:
        parser.error("-v/--verbose and -q/--quiet are exclusive")
    _quiet = bool(args.quiet)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.ERROR if args.quiet else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        return int(args.handler(args))
    except FunrecError as exc:
        if args.verbose:
            traceback.print_exc()
        print(f"{parser.prog} {args.command}: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


@contextmanager
def stage_bars(unit: str = "frame") -> Iterator[Callable[[str, int, int], None]]:
    """Yield ``progress(stage, done, total)`` that draws one tqdm bar per stage on stderr.

    When stderr is not a terminal (a log file, CI), bars would write every redraw as a line;
    instead each stage prints one line when it ends: ``stage: done/total unit in s``. With ``-q``
    nothing is drawn.
    """
    from tqdm import tqdm

    if _quiet:
        yield lambda stage, done, total: None
        return
    interactive = sys.stderr.isatty()
    bars: dict[str, Any] = {}
    started: dict[str, float] = {}

    def close(stage: str) -> None:
        bar = bars[stage]
        if not interactive:
            seconds = time.perf_counter() - started[stage]
            # A stage without progress of its own reports 0/1 then 1/1: only its time means anything.
            count = "done" if bar.total == 1 else f"{bar.n}/{bar.total} {unit}s"
            print(f"{stage.strip():>14}: {count} in {seconds:.1f} s", file=sys.stderr)
        bar.close()

    def update(stage: str, done: int, total: int) -> None:
        bar = bars.get(stage)
        if bar is None:
            for other in list(bars):
                close(other)
                del bars[other]
            started[stage] = time.perf_counter()
            bar = bars[stage] = tqdm(total=total, desc=f"{stage:>14}", unit=unit, dynamic_ncols=True, file=sys.stderr,
                                     disable=not interactive)
        bar.total = total
        bar.n = done
        if interactive:
            bar.refresh()

    try:
        yield update
    finally:
        for stage in list(bars):
            close(stage)


@contextmanager
def progress_bar(description: str, unit: str = "frame") -> Iterator[Callable[[int, int], None]]:
    """Yield ``progress(done, total)`` that draws a single tqdm bar on stderr."""
    with stage_bars(unit) as update:
        yield lambda done, total: update(description, done, total)


__all__ = ["EXIT_BAD_INPUT", "EXIT_BUG", "EXIT_OK", "add_common_options", "progress_bar", "run_command", "stage_bars"]
