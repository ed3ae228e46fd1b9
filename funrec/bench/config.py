"""Settings of the bench (:func:`funrec.bench.run.run_bench`) and the names they choose from: methods,
speed baselines, ablation sets. Its own module so that the report can name them without the runner."""

from __future__ import annotations

from dataclasses import dataclass

from funrec.bench.evaluate import EvalConfig

METHODS = ("funrec", "oracle", "trivial", "open3d")
"""Methods :func:`run_bench` can run: the reconstruction, and the reference baselines of
:mod:`funrec.bench.baselines` (ground-truth oracle, trivial twin, Open3D odometry + TSDF)."""
SPEED_BASELINES = ("open3d", "none")
"""Values of :attr:`BenchConfig.speed_baseline`."""

STANDARD_ABLATIONS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("no pose graph", ("--no-tracking-use-pose-graph",)),
    ("no joint constraint", ("--no-part-motion-use-joint-constraint",)),
    ("no re-seeding", ("--no-point-tracks-reseed",)),
    ("no hand masks", ("--no-use-hand-masks",)),
)
"""The ablation set "standard": each row switches off one stage with one reconstruct flag, so
its worth is the difference to the full method: the camera pose graph (loop closures), the
articulation-constrained part-motion refinement, point-track re-seeding and the hand masks."""
CUES_ABLATIONS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("no depth in camera tracking", ("--no-tracking-depth-odometry-enabled",)),
    ("no depth proposals", ("--no-depth-proposal-enabled",)),
    ("no depth challenge to track parts", ("--no-depth-proposal-challenge",)),
    ("no joint type in depth", ("--no-joint-type-enabled",)),
    ("no hands first", ("--no-hands-first",)),
    ("dense flow on", ("--point-tracks-dense-flow",)),
    ("no hand masks, no hands first", ("--no-use-hand-masks", "--no-hands-first")),
    ("no change left out of depth registration", ("--tracking-depth-odometry-changed-min-fraction", "0")),
    ("no arrived surfaces in the state search", ("--depth-proposal-arrival-points", "0")),
    ("no depth loop closures", ("--no-tracking-depth-loop-closures",)),
    ("no veto of the tracks against depth's part", ("--no-depth-proposal-track-veto",)),
)
"""The ablation set "cues": what each texture-independent cue buys (issue 12): depth registration
where camera tracking has too few corners, parts proposed from depth where tracks give none (and
challenging the tracks' part where they give one), the joint type decided in depth, hands detected before the parts,
the dense-flow track cue (off by default, on here), the changed regions (a turning door) left out of a second
depth registration, the surfaces that arrived in front of a span's first frame scored in its state search, and
the keyframes' depth closing the camera's loops where ORB cannot, and the tracks' veto of a depth part that
misplaces tracks which saw the whole motion."""
ABLATION_SETS: dict[str, tuple[tuple[str, tuple[str, ...]], ...]] = {
    "none": (), "standard": STANDARD_ABLATIONS, "cues": CUES_ABLATIONS, "all": STANDARD_ABLATIONS + CUES_ABLATIONS}
"""Named ablation sets selectable with BenchConfig.ablation_set."""

@dataclass(frozen=True)
class BenchConfig:
    """Settings of :func:`run_bench`."""

    method: str = "funrec"
    """Method to run: "funrec" (reconstruct in a subprocess), "oracle" or "trivial" (funrec.bench.baselines)."""
    suite: str = "bench"
    """Named suite of funrec.synth used to generate missing sequences (a family such as "bench" or
    "plain", "families" for all of them, or "smoke"; see funrec.synth.suite.SUITES)."""
    timeout_s: float = 1800.0
    """Wall-time limit per sequence, seconds; a run that exceeds it is killed and is a failure row."""
    only: tuple[str, ...] | None = None
    """Run only these sequence names (None: every sequence of the suite folder)."""
    reconstruct_args: tuple[str, ...] = ()
    """Extra arguments appended to ``funrec reconstruct CAPTURE -o TWIN`` (method "funrec" and ablations)."""
    ablations: tuple[tuple[str, tuple[str, ...]], ...] = ()
    """(label, extra reconstruct args) pairs; each runs "funrec reconstruct" with reconstruct_args
    plus its extra args as an additional method and gets a row in the ablation table."""
    ablation_set: str = "none"
    """Named ablations run in the same bench, after ``ablations``: "none", "standard" (no
    camera pose graph, no joint-constrained part motion, no track re-seeding, no hand masks),
    "cues" (no depth in camera tracking, no depth proposals, no depth challenge, no joint type in
    depth, no hands first, dense flow on, neither hand masks nor hands first, no change left out of
    depth registration, no arrived surfaces in the state search, no depth loop closures) or "all" (both)."""
    ablation_sequences: str | None = None
    """Comma-separated sequence names the ablations run on (None: every sequence); the ablation
    table then compares them with the full method on the same sequences."""
    generate_missing: bool = True
    """Generate missing sequences with funrec.synth.generate_suite before running."""
    jobs: int = 1
    """Sequences run in parallel (each in its own subprocess), or the CPUs of the Ray instance of --ray local."""
    ray: str | None = None
    """Run the sequences as Ray tasks through funrec batch's scheduler: 'local' starts a Ray instance on this
    machine, otherwise a cluster address ('auto', 'ray://host:10001') whose nodes see the suite and report
    folders; None runs local processes."""
    memory_limit_mb: int = 0
    """Address-space limit (RLIMIT_AS) of each run, MiB, as in funrec batch; 0 = none."""
    task_memory_mb: int = 2000
    """Resident memory Ray reserves for each run with --ray, MiB, as in funrec batch (0: none)."""
    evaluation: EvalConfig = EvalConfig()
    """Evaluation settings."""
    speed_baseline: str = "open3d"
    """Reference method timed in the same run on the same captures, one at a time like the main
    method: "open3d" (Open3D RGB-D odometry + TSDF integration, funrec.bench.baselines) or "none".
    The report gives the main method's throughput over the baseline's on the sequences both ran.
    Runs only when the method is "funrec"."""
    speed_baseline_sequences: str | None = None
    """Comma-separated sequence names the speed baseline runs on (None: every sequence). Open3D
    runs ~1.7 frames/s at 640x480 on 2 cores, so a subset keeps the bench short."""


__all__ = ["ABLATION_SETS", "CUES_ABLATIONS", "METHODS", "SPEED_BASELINES", "STANDARD_ABLATIONS", "BenchConfig"]
