"""The ``funrec`` command line: thin handlers over the library API.

Exit codes: 0 success, 2 bad input or an impossible request (one line on stderr, the
traceback with --verbose), 1 a bug (traceback).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
import time
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from funrec.errors import FunrecError

log = logging.getLogger("funrec")


@contextmanager
def progress_bar(description: str, unit: str = "frame"):
    """Yield a ``progress(done, total)`` callback that draws a tqdm bar on stderr."""
    from tqdm import tqdm

    bar: Any = None

    def update(done: int, total: int) -> None:
        nonlocal bar
        if bar is None:
            bar = tqdm(total=total, desc=description, unit=unit, leave=True, dynamic_ncols=True, file=sys.stderr)
        bar.total = total
        bar.n = done
        bar.refresh()

    try:
        yield update
    finally:
        if bar is not None:
            bar.close()


def _cmd_synth(args: argparse.Namespace) -> int:
    from funrec import synth

    start = time.perf_counter()
    if args.tiny:
        spec = synth.tiny_spec(args.seed)
        with progress_bar(f"synth {spec.name}") as progress:
            path = synth.generate_sequence(spec, args.output, progress=progress)
        print(f"capture written to {path} (ground truth in {path / 'gt'}; {time.perf_counter() - start:.0f} s)")
        return 0
    with progress_bar(f"suite {args.suite}") as progress:
        paths = synth.generate_suite(args.output, suite=args.suite, only=args.only or None, progress=progress)
    print(f"{len(paths)} sequences in {args.output} ({time.perf_counter() - start:.0f} s)")
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    from funrec.capture import load_capture

    capture = load_capture(args.capture)
    with progress_bar(f"decoding {capture.root.name}") as progress:
        for frame in range(len(capture)):
            capture.rgb(frame)
            capture.depth_m(frame)
            for kind in capture.mask_paths:
                capture.mask(kind, frame)
            progress(frame + 1, len(capture))
    K = capture.intrinsics
    masks = ", ".join(sorted(capture.mask_paths)) or "none"
    print(
        f"{capture.root}: {len(capture)} frames {K.width}x{K.height} at {K.fps:g} fps, "
        f"fx {K.fx:.1f} fy {K.fy:.1f}, masks: {masks}, all frames readable"
    )
    return 0


def _cmd_eval(args: argparse.Namespace) -> int:
    import json

    from funrec.evaluate import evaluate_twin, evaluation_to_json, format_evaluation

    evaluation = evaluate_twin(args.twin, args.gt)
    print(format_evaluation(evaluation))
    if args.json:
        Path(args.json).write_text(json.dumps(evaluation_to_json(evaluation), indent=2) + "\n")
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from funrec.bench import BenchConfig, format_report, run_bench
    from funrec.config import config_from_args

    config = config_from_args(BenchConfig, args)
    if args.only:
        config = dataclasses.replace(config, only=tuple(args.only))
    with progress_bar("bench", unit="sequence") as progress:
        report = run_bench(args.suite_dir, args.output, config, progress=progress)
    print(format_report(report))
    print(f"report written to {args.output}/report.md and report.json")
    return 0


def _add_synth(sub: Any) -> None:
    p = sub.add_parser(
        "synth",
        help="generate synthetic captures with exact ground truth",
        description="Render procedural rooms with articulated furniture in MuJoCo (CPU) and write capture "
        "folders (FORMATS.md section 1) with ground truth in <capture>/gt/ (section 4). Deterministic per seed.",
    )
    p.add_argument("-o", "--output", type=Path, required=True, help="output folder (one sub-folder per sequence)")
    p.add_argument(
        "--suite",
        choices=("bench", "smoke"),
        default="smoke",
        help="named suite: 'bench' (the benchmark, 24+ sequences) or 'smoke' (a few short ones; default)",
    )
    p.add_argument("--only", nargs="+", metavar="NAME", help="generate only these sequences of the suite")
    p.add_argument("--tiny", action="store_true", help="instead of a suite, one tiny low-resolution sequence")
    p.add_argument("--seed", type=int, default=0, help="seed of the --tiny sequence (default: 0)")
    p.set_defaults(handler=_cmd_synth)


def _add_check(sub: Any) -> None:
    p = sub.add_parser(
        "check",
        help="validate a capture folder and decode every frame",
        description="Validate a capture folder against FORMATS.md section 1 and decode every image; "
        "the first bad file is reported with its frame index.",
    )
    p.add_argument("capture", type=Path, help="capture folder")
    p.set_defaults(handler=_cmd_check)


def _add_eval(sub: Any) -> None:
    p = sub.add_parser(
        "eval",
        help="score a twin against ground truth (FORMATS.md section 5)",
        description="Score a twin folder against a ground-truth folder with the metrics of FORMATS.md "
        "section 5 and print per-part results.",
    )
    p.add_argument("twin", type=Path, help="twin folder (holds articulation.json)")
    p.add_argument("gt", type=Path, help="ground-truth folder (gt/ or the capture folder holding it)")
    p.add_argument("--json", type=Path, help="also write the evaluation as JSON to this file")
    p.set_defaults(handler=_cmd_eval)


def _add_bench(sub: Any) -> None:
    from funrec.bench import BenchConfig
    from funrec.config import add_config_arguments

    p = sub.add_parser(
        "bench",
        help="run the synthetic benchmark and print the table",
        description="Generate (or reuse) the benchmark suite, reconstruct every sequence in a subprocess "
        "(timeouts and crashes become failure rows), score each twin and print one table in the layout of "
        "the paper's tables. Writes report.json and report.md.",
    )
    p.add_argument("--suite-dir", type=Path, default=Path("bench_suite"), help="suite folder (default: bench_suite)")
    p.add_argument("-o", "--output", type=Path, default=Path("bench_report"), help="report folder (default: bench_report)")
    p.add_argument("--only", nargs="+", metavar="NAME", help="run only these sequences")
    add_config_arguments(p, BenchConfig)
    p.set_defaults(handler=_cmd_bench)


_COMMANDS: tuple[Callable[[Any], None], ...] = (_add_synth, _add_check, _add_eval, _add_bench)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="funrec",
        description="FunREC: functional digital twins from egocentric RGB-D interaction videos.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log detail and show tracebacks of errors")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in _COMMANDS:
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        return int(args.handler(args))
    except FunrecError as exc:
        if args.verbose:
            raise
        print(f"funrec {args.command}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
