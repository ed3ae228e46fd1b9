"""Reconstruct a functional twin from a generated capture, render it to PNG, and (with --view) open it in the
browser viewer.

    python demos/reconstruct_and_view.py -o demo_output [--view]
"""

from __future__ import annotations

import argparse
from pathlib import Path


def make_twin(out: Path, sequence: str = "smoke_rev_00") -> tuple[Path, Path]:
    """Render a smoke-suite capture (a person opening a cabinet door) and reconstruct its twin.

    Returns:
        The capture folder (with ground truth in gt/) and the twin folder.
    """
    from funrec import synth
    from funrec.pipeline import reconstruct

    capture = synth.generate_suite(out / "captures", suite="smoke", only=[sequence])[0]
    summary = reconstruct(capture, out / "twin", overwrite=True)
    return Path(capture), summary.twin_dir


def twin_parser(description: str) -> argparse.ArgumentParser:
    """Command line of the demos that work on a twin: --twin DIR, or -o DIR to make one first."""
    parser = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--twin", type=Path, help="twin folder from funrec reconstruct (default: make one)")
    parser.add_argument("-o", "--output", type=Path, default=Path("demo_output"), help="output folder")
    return parser


def twin_from(args: argparse.Namespace) -> Path:
    """The --twin folder, or a twin reconstructed from a generated capture in --output."""
    return args.twin if args.twin is not None else make_twin(args.output)[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-o", "--output", type=Path, default=Path("demo_output"), help="output folder")
    parser.add_argument("--sequence", default="smoke_rev_00", help="smoke-suite sequence (smoke_rev_00, smoke_pri_00)")
    parser.add_argument("--view", action="store_true", help="serve the twin in the browser (needs viser)")
    args = parser.parse_args()

    from funrec import read_articulation
    from funrec.bench.evaluate import evaluate_twin, format_evaluation
    from funrec.render import render_twin

    capture, twin = make_twin(args.output, args.sequence)
    for part in read_articulation(twin / "articulation.json").parts:
        print(f"{part.name}: {part.joint_type} axis {part.axis_world.round(3)} range {part.state_range}")
    print(format_evaluation(evaluate_twin(twin, capture / "gt")))
    images = render_twin(twin, args.output / "render")
    print(f"{len(images)} pictures in {args.output / 'render'}")
    if args.view:
        from funrec.view import serve_twin

        serve_twin(twin, on_ready=lambda url: print(f"viewing {twin} at {url} (Ctrl+C to stop)", flush=True))


if __name__ == "__main__":
    main()
