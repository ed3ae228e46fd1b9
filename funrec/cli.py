"""The ``funrec`` command line: thin handlers over the library API.

Exit codes: 0 success, 2 bad input or an impossible request (one line on stderr, the
traceback with --verbose), 1 a bug (traceback).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from funrec.cli_runner import progress_bar, run_command, stage_bars

_ARGV: list[str] = []
"""The arguments being parsed (set by build_parser)."""
RECONSTRUCT_COMMON = (
    "align_gravity",
    "use_hand_masks",
    "use_object_masks",
    "parts_per_fragment",
    "intrinsics_check.enabled",
    "fusion.static_voxel_m",
    "fusion.part_voxel_m",
    "export.density_kg_m3",
    "export.snap_axis_deg",
    "export.usd_binary",
)
"""The reconstruct options ``--help`` lists: what a user changes about the result (frames, masks
used, resolution, physics). The other ~260 are the stages' tuning knobs; they are accepted always
and listed by ``--help-all`` or, as a config file, by ``--print-config``."""


def _add_config_options(
    parser: argparse.ArgumentParser, selected: bool, module: str, config: str, common: tuple[str, ...] = ()
) -> None:
    """Add a flag per field of the frozen config class ``module.config`` (help from its attribute
    docstrings), importing the module only for the command being run: stage modules are slow to import.
    With ``common``, ``--help`` lists only those flags and ``--help-all`` every one."""
    if common:
        parser.add_argument("--help-all", action="help", help="show the help of every stage option and exit")
    if selected:
        from funrec.config import add_config_arguments

        show_all = not common or "--help-all" in _ARGV
        add_config_arguments(parser, getattr(importlib.import_module(module), config), common=common, show_all=show_all)


def _print_summary(summary: Any) -> None:
    parts = ", ".join(
        f"{p.name} {p.joint_type} range [{p.state_range[0]:.3f}, {p.state_range[1]:.3f}] "
        f"{'rad' if p.joint_type == 'revolute' else 'm'} frames {p.frames[0]}-{p.frames[1]}"
        for p in summary.parts
    )
    total = sum(summary.stage_seconds.values())
    timings = ", ".join(f"{k} {v:.1f} s" for k, v in summary.stage_seconds.items())
    print(f"twin written to {summary.twin_dir}")
    print(f"  {len(summary.parts)} part(s): {parts or 'nothing was opened in this capture'}")
    fragments = ", ".join(f"{f.first}-{f.last} {f.kind}{f' ({f.part})' if f.part else ''}" for f in summary.fragments)
    print(f"  {len(summary.fragments)} fragment(s): {fragments}")
    for f in summary.fragments:
        if f.kind == "dynamic" and f.part is None:
            print(f"  scene change in frames {f.first}-{f.last} gave no part: {f.reason}")
    print(f"  {summary.frame_count} frames in {total:.1f} s ({summary.frame_count / max(total, 1e-9):.1f} frames/s): {timings}")
    if summary.untracked_frames:
        print(f"  {summary.untracked_frames} frame(s) could not be registered; their camera poses are interpolated")


def _cmd_reconstruct(args: argparse.Namespace) -> int:
    from funrec.config import config_from_args, load_config_file
    from funrec.pipeline import ReconstructConfig, reconstruct

    base = load_config_file(ReconstructConfig, args.config) if args.config else None
    config = config_from_args(ReconstructConfig, args, base)
    if args.print_config:
        import json

        from funrec.config import config_to_dict

        print(json.dumps(config_to_dict(config), indent=2))
        return 0
    if args.capture is None or args.output is None:
        args.parser.error("the following arguments are required: CAPTURE, -o/--output")
    with stage_bars() as progress:
        summary = reconstruct(args.capture, args.output, config, progress=progress, overwrite=args.overwrite)
        if args.rerun is not None:
            _write_rerun(args.output, args.rerun, args.capture, lambda done, total: progress("rerun", done, total))
    _print_summary(summary)
    if args.rerun is not None:
        print(f"  rerun recording: {args.rerun}")
    return 0


def _write_rerun(twin: Path, rrd: Path, capture_dir: Path | None, progress: Callable[[int, int], None]) -> None:
    """Write the rerun recording of a twin, with the frames of ``capture_dir`` (or of the capture
    its config.json names) when there is one."""
    from funrec.export.rerun_log import write_rerun
    from funrec.formats.capture import load_capture
    from funrec.formats.twin_config import recorded_capture

    capture_dir = capture_dir if capture_dir is not None else recorded_capture(twin)
    write_rerun(twin, rrd, None if capture_dir is None else load_capture(capture_dir), progress=progress)


def _cmd_demo(args: argparse.Namespace) -> int:
    from funrec import synth
    from funrec.bench.evaluate import evaluate_twin, format_evaluation
    from funrec.pipeline import reconstruct

    out = Path(args.output)
    with progress_bar("rendering demo capture") as progress:
        capture_dir = synth.generate_suite(out / "captures", suite="smoke", only=[args.sequence], progress=progress)[0]
    with stage_bars() as progress:
        summary = reconstruct(capture_dir, out / "twin", progress=progress, overwrite=True)
    _print_summary(summary)
    print(format_evaluation(evaluate_twin(out / "twin", capture_dir / "gt")))
    print(f"capture: {capture_dir}  (ground truth in {capture_dir / 'gt'})")
    print(f"twin:    {out / 'twin'}  (articulation.json, meshes/, masks/)")
    return 0


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
        paths = synth.generate_suite(
            args.output, suite=args.suite, only=args.only or None, progress=progress, scenes_only=args.scenes_only,
            reseed=args.reseed,
        )
    print(f"{len(paths)} sequences in {args.output} ({time.perf_counter() - start:.0f} s)")
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    from funrec.camera.intrinsics_consistency import require_consistent_intrinsics
    from funrec.formats.capture import load_capture
    from funrec.formats.capture_usable import check_capture_usable

    capture = load_capture(args.capture)
    with progress_bar(f"decoding {capture.root.name}") as progress:
        check_capture_usable(capture, progress)
    verdict = require_consistent_intrinsics(capture)
    K = capture.intrinsics
    masks = ", ".join(sorted(capture.mask_paths)) or "none"
    print(
        f"{capture.root}: {len(capture)} frames {K.width}x{K.height} at {K.fps:g} fps, "
        f"fx {K.fx:.1f} fy {K.fy:.1f}, masks: {masks}, all frames readable and usable; "
        f"intrinsics against the video: {verdict.verdict} ({verdict.reason})"
    )
    return 0


def _cmd_eval(args: argparse.Namespace) -> int:
    import json

    from funrec.bench.evaluate import evaluate_twin, evaluation_to_json, format_evaluation
    from funrec.formats.staged_folder import write_text_staged

    evaluation = evaluate_twin(args.twin, args.gt)
    print(format_evaluation(evaluation))
    if args.json:
        write_text_staged(args.json, json.dumps(evaluation_to_json(evaluation), indent=2) + "\n")
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from funrec.bench.run import BenchConfig, format_report, run_bench
    from funrec.config import config_from_args

    config = config_from_args(BenchConfig, args)
    if args.only:
        config = dataclasses.replace(config, only=tuple(args.only))
    with progress_bar("bench", unit="sequence") as progress:
        report = run_bench(args.suite_dir, args.output, config, progress=progress)
    print(format_report(report))
    print(f"report written to {args.output}/report.md and report.json")
    return 0


def _cmd_convert(args: argparse.Namespace) -> int:
    from funrec.config import config_from_args
    from funrec.convert import ConvertConfig, convert

    report = convert(args.source, args.output, config_from_args(ConvertConfig, args))
    print(report.summary())
    for dropped in report.dropped[:5]:
        print(f"  dropped source frame {dropped.source_index}: {dropped.reason}")
    if len(report.dropped) > 5:
        print(f"  ... and {len(report.dropped) - 5} more, listed in {report.capture_dir / 'conversion.json'}")
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from funrec.config import config_from_args, load_config_file
    from funrec.export.simulation import ExportConfig, export_simulation

    base = load_config_file(ExportConfig, args.config) if args.config else None
    config = config_from_args(ExportConfig, args, base)
    if args.rerun_only:
        config = dataclasses.replace(config, formats=())
    written = []
    if config.formats:
        exports = export_simulation(args.twin, config)
        written = [str(p) for p in (exports.urdf, exports.mjcf, exports.usd, exports.glb) if p is not None]
    if args.rerun is not None:
        with progress_bar("rerun") as progress:
            _write_rerun(args.twin, args.rerun, args.capture, progress)
        written.append(str(args.rerun))
    print(f"wrote {', '.join(written) or 'nothing'}")
    return 0


def _add_export(sub: Any, selected: bool) -> None:
    p = sub.add_parser(
        "export",
        usage="funrec export TWIN [--config FILE] [options]",
        help="(re)write a twin's exports: twin.urdf, twin.xml (MuJoCo), twin.usda, twin.glb; a rerun recording",
        description="Write twin.urdf (through yourdfpy), twin.xml (MuJoCo MJCF), twin.usda (UsdPhysics "
        "articulation) and twin.glb (meshes as named glTF nodes) into a twin folder: a fixed base with the static "
        "mesh, one link per part with its revolute or "
        "prismatic joint and observed limits, convex collision pieces, mass and inertia from a density. "
        "funrec reconstruct already writes them; use this to re-export with other settings.",
    )
    p.add_argument("twin", type=Path, help="twin folder (holds articulation.json and meshes/)")
    p.add_argument("--config", type=Path, help="JSON or YAML file of ExportConfig fields (unknown keys are errors)")
    p.add_argument("--rerun", type=Path, metavar="FILE.rrd",
                   help="also write a rerun recording (pip install funrec[rerun]): RGB-D frames with part and hand "
                   "masks, camera path, posed part meshes, joint states, contact point and grasp frame")
    p.add_argument("--capture", type=Path,
                   help="capture folder whose frames go into --rerun (default: the one the twin's config.json names)")
    p.add_argument("--rerun-only", action="store_true", help="write only the --rerun recording, not the simulator files")
    _add_config_options(p, selected, "funrec.export.simulation", "ExportConfig")
    p.set_defaults(handler=_cmd_export)


def _cmd_render(args: argparse.Namespace) -> int:
    from funrec.config import config_from_args
    from funrec.render import RenderConfig, render_twin

    out = args.output if args.output is not None else args.twin / "render"
    paths = render_twin(args.twin, out, config_from_args(RenderConfig, args))
    print(f"{len(paths) - 1} images and {paths[-1]} written to {out}")
    return 0


def _add_render(sub: Any, selected: bool) -> None:
    p = sub.add_parser(
        "render",
        help="write PNG pictures and a GIF of a twin at several joint states",
        description="Render the twin's MuJoCo export offscreen (EGL or OSMesa, no display needed) from the side the "
        "person looked from: an overview and each part at evenly spaced states of its observed range, plus a GIF.",
    )
    p.add_argument("twin", type=Path, help="twin folder (holds twin.xml)")
    p.add_argument("-o", "--output", type=Path, help="image folder (default: TWIN/render)")
    _add_config_options(p, selected, "funrec.render", "RenderConfig")
    p.set_defaults(handler=_cmd_render)


def _cmd_query(args: argparse.Namespace) -> int:
    from funrec.query import query_text

    print(query_text(args.twin, args.part, args.state, as_json=args.json))
    return 0


def _add_query(sub: Any, selected: bool) -> None:
    p = sub.add_parser(
        "query",
        usage="funrec query TWIN [--part NAME [--state S]] [--json]",
        help="list a twin's parts with their contact points, or give a part's grasp frame at a joint state",
        description="Without --part: every articulated part with its joint type, observed range, number of "
        "demonstrated holds and contact point (twin world frame, canonical state). With --part: the part's grasp "
        "frame T_world_grasp at --state (the canonical grasp moved by the joint; z approach, x along the handle, "
        "y across it) as a 4x4 and as position, approach and handle axis. Reads articulation.json and affordances.json.",
    )
    p.add_argument("twin", type=Path, help="twin folder (holds articulation.json and affordances.json)")
    p.add_argument("--part", metavar="NAME", help="part name, as in articulation.json (e.g. part_0)")
    p.add_argument("--state", type=float, metavar="S", help="joint state from the canonical state, rad or m, within the part's range (default 0)")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.set_defaults(handler=_cmd_query)


def _cmd_view(args: argparse.Namespace) -> int:
    from funrec.config import config_from_args
    from funrec.view import ViewConfig, serve_twin

    serve_twin(args.twin, args.host, args.port, config_from_args(ViewConfig, args),
               on_ready=lambda url: print(f"viewing {args.twin} at {url} (Ctrl+C to stop)", flush=True),
               capture_dir=args.capture)
    return 0


def _add_view(sub: Any, selected: bool) -> None:
    p = sub.add_parser(
        "view",
        help="show a twin in an interactive 3D viewer in the browser (viser): replay the capture, move the joints",
        description="Serve the twin in the browser with viser (pip install funrec[view]), aimed at the parts: the "
        "static mesh, the parts highlighted, a time slider replaying the capture (part states, camera, hand points), "
        "a slider per joint, and layers to toggle (camera path, frustums drawn as lines, contacts and grasp frames, "
        "hands). Runs until Ctrl+C.",
    )
    p.add_argument("--capture", type=Path,
                   help="capture folder of the twin, for hand points and true frustums (default: from config.json)")
    p.add_argument("twin", type=Path, help="twin folder (holds articulation.json and meshes/)")
    p.add_argument("--port", type=int, default=8080, help="port of the web viewer (default: 8080)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default: 127.0.0.1; 0.0.0.0 for other machines)")
    _add_config_options(p, selected, "funrec.view", "ViewConfig")
    p.set_defaults(handler=_cmd_view)


def _add_convert(sub: Any, selected: bool) -> None:
    p = sub.add_parser(
        "convert",
        usage="funrec convert SOURCE -o CAPTURE [--format NAME] [--rgb-topic T] [--depth-topic T] [options]",
        help="convert an RGB-D recording into a capture folder",
        description="Convert a TUM RGB-D folder, Azure Kinect .mkv, ROS 1/2 bag, RealSense .bag/.db3, Record3D .r3d or "
        "HOI4D sequence (with its annotations as gt/) into a capture folder (FORMATS.md section 1). It is written to a temporary folder and moved into place when "
        "complete; its conversion.json lists dropped frames, timestamp gaps and the decisions taken. Plain videos "
        "are refused: FunREC needs depth.",
    )
    p.add_argument("source", type=Path, help="recording file or folder")
    p.add_argument("-o", "--output", type=Path, required=True, help="capture folder to write")
    _add_config_options(p, selected, "funrec.convert", "ConvertConfig")
    p.set_defaults(handler=_cmd_convert)


def _cmd_batch(args: argparse.Namespace) -> int:
    from funrec.bench.batch import BatchConfig, run_batch
    from funrec.config import config_from_args

    with progress_bar("batch", unit="capture") as progress:
        report = run_batch(args.dataset, args.output, config_from_args(BatchConfig, args), progress=progress)
    print((report.out_dir / "summary.md").read_text())
    print(f"twins in {report.out_dir / 'twins'}, table in {report.out_dir / 'summary.csv'} and summary.md")
    return 0


def _add_batch(sub: Any, selected: bool) -> None:
    p = sub.add_parser(
        "batch",
        usage="funrec batch DATASET_DIR -o OUT [--workers N] [--ray ADDRESS] [--evaluate] [options]",
        help="reconstruct every capture of a folder (local processes or a Ray cluster), resumable",
        description="Reconstruct every capture folder in DATASET_DIR into OUT/twins/<capture>, each in its own "
        "memory-limited process, over local worker processes or, with --ray, as Ray tasks. Complete twins are "
        "skipped (rerun after an interruption to resume); a failing capture is a row of OUT/summary.csv and "
        "OUT/summary.md, never the end of the batch.",
    )
    p.add_argument("dataset", type=Path, help="folder of capture folders")
    p.add_argument("-o", "--output", type=Path, required=True, help="output folder")
    _add_config_options(p, selected, "funrec.bench.batch", "BatchConfig")
    p.set_defaults(handler=_cmd_batch)


def _add_synth(sub: Any, selected: bool) -> None:
    p = sub.add_parser(
        "synth",
        help="generate synthetic captures with exact ground truth",
        description="Render procedural rooms with articulated furniture in MuJoCo (CPU) and write capture "
        "folders (FORMATS.md section 1) with ground truth in <capture>/gt/ (section 4). Deterministic per seed.",
    )
    p.add_argument("-o", "--output", type=Path, required=True, help="output folder (one sub-folder per sequence)")
    p.add_argument(
        "--suite",
        choices=("bench", "plain", "dark", "lighting", "geometry", "person", "assets", "families", "smoke"),
        default="smoke",
        help="named suite: a bench family ('bench' = the textured family, 'plain', 'dark', 'lighting', "
        "'geometry', 'person', 'assets' = Meta-World objects), 'families' (all of them) or 'smoke' (a few short ones; default)",
    )
    p.add_argument("--only", nargs="+", metavar="NAME", help="generate only these sequences of the suite")
    p.add_argument(
        "--scenes-only",
        action="store_true",
        help="write only each sequence's gt/ scene (scene.xml, textures, camera poses, gt.json; no frames, masks or "
        "points): the true scenes `funrec-robot bench` plans in, in seconds",
    )
    p.add_argument("--reseed", type=int, default=0, metavar="K",
                   help="K > 0: fresh scenes of the suite's recipes (new layout, materials, camera and hand paths; "
                   "sequences named NAME_rK), a held-out set to check a change on scenes nobody tuned on "
                   "(default: 0, the suite as named)")
    p.add_argument("--tiny", action="store_true", help="instead of a suite, one tiny low-resolution sequence")
    p.add_argument("--seed", type=int, default=0, help="seed of the --tiny sequence (default: 0)")
    p.set_defaults(handler=_cmd_synth)


def _add_check(sub: Any, selected: bool) -> None:
    p = sub.add_parser(
        "check",
        help="validate a capture folder and decode every frame",
        description="Validate a capture folder against FORMATS.md section 1 and decode every image; "
        "the first bad file is reported with its frame index.",
    )
    p.add_argument("capture", type=Path, help="capture folder")
    p.set_defaults(handler=_cmd_check)


def _add_eval(sub: Any, selected: bool) -> None:
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


def _add_bench(sub: Any, selected: bool) -> None:
    p = sub.add_parser(
        "bench",
        usage="funrec bench [--suite-dir DIR] [-o REPORT_DIR] [--only NAME ...] [options]",
        help="run the synthetic benchmark and print the table",
        description="Generate (or reuse) the benchmark suite, reconstruct every sequence in a subprocess "
        "(timeouts and crashes become failure rows), score each twin and print one table in the layout of "
        "the paper's tables. Writes report.json and report.md.",
    )
    p.add_argument("--suite-dir", type=Path, default=Path("bench_suite"), help="suite folder (default: bench_suite)")
    p.add_argument("-o", "--output", type=Path, default=Path("bench_report"), help="report folder (default: bench_report)")
    p.add_argument("--only", nargs="+", metavar="NAME", help="run only these sequences")
    _add_config_options(p, selected, "funrec.bench.run", "BenchConfig")
    p.set_defaults(handler=_cmd_bench)


def _add_reconstruct(sub: Any, selected: bool) -> None:
    p = sub.add_parser(
        "reconstruct",
        usage="funrec reconstruct CAPTURE -o TWIN [--overwrite] [--config FILE] [options]",
        help="reconstruct a functional twin from a capture folder",
        description="Track the camera, track points, find the part the person moved and its joint, segment "
        "it in every frame, fuse meshes, and write a twin folder (FORMATS.md section 2) with the config it was "
        "made with in config.json. The twin is written to a temporary folder and moved into place only when "
        "complete.",
        epilog="Every stage setting has a flag too (about 260): --help-all lists them, --print-config prints "
        "them all as a config file to edit and pass back with --config.",
    )
    p.add_argument("capture", type=Path, nargs="?", metavar="CAPTURE", help="capture folder (FORMATS.md section 1)")
    p.add_argument("-o", "--output", type=Path, help="twin folder to write (required)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing twin folder")
    p.add_argument("--config", type=Path, help="JSON or YAML file of ReconstructConfig fields (unknown keys are errors)")
    p.add_argument("--print-config", action="store_true",
                   help="print the full config (defaults, --config file and flags applied) as JSON and exit")
    p.add_argument("--rerun", type=Path, metavar="FILE.rrd",
                   help="also write a rerun recording of the twin and the capture (pip install funrec[rerun])")
    _add_config_options(p, selected, "funrec.pipeline", "ReconstructConfig", RECONSTRUCT_COMMON)
    p.set_defaults(parser=p)
    p.set_defaults(handler=_cmd_reconstruct)


def _add_demo(sub: Any, selected: bool) -> None:
    p = sub.add_parser(
        "demo",
        help="render a synthetic capture, reconstruct it and score the twin",
        description="The main job on a built-in example: render one sequence of the smoke suite, reconstruct "
        "its twin and score it against the ground truth.",
    )
    p.add_argument("-o", "--output", type=Path, default=Path("demo_output"), help="output folder (default: demo_output)")
    p.add_argument("--sequence", default="smoke_rev_00", help="smoke-suite sequence to use (default: smoke_rev_00)")
    p.set_defaults(handler=_cmd_demo)


_COMMANDS: dict[str, Callable[[Any, bool], None]] = {
    "reconstruct": _add_reconstruct,
    "demo": _add_demo,
    "export": _add_export,
    "render": _add_render,
    "query": _add_query,
    "view": _add_view,
    "convert": _add_convert,
    "synth": _add_synth,
    "check": _add_check,
    "eval": _add_eval,
    "bench": _add_bench,
    "batch": _add_batch,
}


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The full parser; stage options (which need the stage modules) are added only for the
    command being run, so ``funrec --help`` stays instant."""
    parser = argparse.ArgumentParser(
        prog="funrec",
        description="FunREC: functional digital twins from egocentric RGB-D interaction videos.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _ARGV[:] = sys.argv[1:] if argv is None else argv
    words = [a for a in _ARGV if not a.startswith("-")]
    for name, add in _COMMANDS.items():
        add(sub, bool(words) and words[0] == name)
    return parser


def main(argv: list[str] | None = None) -> int:
    return run_command(build_parser(argv), argv)


if __name__ == "__main__":
    raise SystemExit(main())
