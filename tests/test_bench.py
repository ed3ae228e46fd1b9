"""Tests of funrec.bench.run on a two-sequence suite written by tests/helpers/tiny_sequence.py (no funrec.synth)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pytest

from funrec.bench import report as bench_report
from funrec.bench import run as bench
from funrec.bench.evaluate import PartEvaluation, TwinEvaluation
from funrec.bench.run import BenchConfig, format_report, run_bench, summarize
from funrec.config import add_config_arguments, config_from_args
from funrec.errors import FunrecError
from funrec.pipeline import ReconstructConfig
from tests.helpers.tiny_sequence import write_tiny_sequence

SEQUENCES = ("seq_a", "seq_b")


@pytest.fixture(scope="module")
def suite(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("suite")
    write_tiny_sequence(root, "seq_a")
    write_tiny_sequence(root, "seq_b", offset=(1.0, 2.0, 0.0))
    (root / "not_a_sequence").mkdir()  # ignored: no gt/gt.json
    return root


def _config(**changes) -> BenchConfig:
    return BenchConfig(**{"generate_missing": False, "jobs": 2, "timeout_s": 120.0, "speed_baseline": "none", **changes})


def _load_strict_json(path: Path) -> dict:
    def reject(constant):
        raise ValueError(f"non-standard JSON constant {constant}")

    return json.loads(path.read_text(), parse_constant=reject)


def test_oracle_bench_is_perfect_and_writes_reports(suite, tmp_path):
    calls = []
    report = run_bench(suite, tmp_path / "out", _config(method="oracle"), progress=lambda done, total: calls.append((done, total)), command_line="funrec bench --method oracle")
    assert calls[-1] == (2, 2)
    assert [r.name for r in report.main.sequences] == list(SEQUENCES)
    s = report.main.summary
    assert (s.sequences, s.failed_sequences, s.parts, s.failed_parts, s.fail_pct) == (2, 0, 4, 0, 0.0)
    # Exact up to file round-off, as in test_evaluate (10 um bounds).
    assert s.axis_revolute_deg < 1e-3 and s.axis_prismatic_deg < 1e-3 and s.pivot_m < 1e-5
    assert s.adds_auc > 99.999 and s.add_auc > 99.999 and s.miou == pytest.approx(100.0)
    assert s.chamfer_cm < 1e-3 and s.camera_ate_cm < 1e-3
    assert s.frames_per_s > 0 and s.peak_rss_mb > 10  # a Python child with numpy uses tens of MB
    # CPU throughput is at least wall throughput for a single-threaded child (CPU time <= wall
    # time), and a child importing numpy uses some CPU time.
    assert s.frames_per_cpu_s >= s.frames_per_s and all(r.cpu_s > 0 for r in report.main.sequences)
    markdown = (tmp_path / "out" / "report.md").read_text()
    for needle in ("git commit:", "machine:", "date:", "method: oracle", "`funrec bench --method oracle`", "| Method |", "| seq_a |", "Fail (%)"):
        assert needle in markdown
    data = _load_strict_json(tmp_path / "out" / "report.json")
    assert data["methods"][0]["summary"]["fail_pct"] == 0.0
    assert data["methods"][0]["sequences"][1]["evaluation"]["parts"][0]["true_name"] == "door"
    assert "| oracle |" in format_report(report)
    assert (tmp_path / "out" / "twins" / "oracle" / "seq_a" / "articulation.json").is_file()


def test_trivial_bench_scores_badly(suite, tmp_path):
    report = run_bench(suite, tmp_path / "out", _config(method="trivial", only=("seq_b",)))
    s = report.main.summary
    assert s.sequences == 1 and s.failed_sequences == 0  # it ran and wrote a readable twin
    assert s.fail_pct == 100.0 and s.invented_parts == 1  # its plane is metres from both parts
    assert s.camera_ate_cm > 1.0 and s.chamfer_cm > 10.0
    assert "| trivial |" in format_report(report)


def test_failing_reconstruction_and_ablations_are_failure_rows(suite, tmp_path):
    # An unknown flag makes `funrec reconstruct` exit non-zero whether or not it exists yet.
    config = _config(method="funrec", reconstruct_args=("--definitely-not-a-flag",), ablations=(("variant", ("--x",)),), only=("seq_a",))
    report = run_bench(suite, tmp_path / "out", config)
    assert [m.label for m in report.methods] == ["funrec", "variant"]
    for method in report.methods:
        assert method.summary.fail_pct == 100.0 and method.summary.failed_sequences == 1
        for row in method.sequences:
            assert row.status == "failed" and row.reason.startswith("exit code")
            assert [p.failure for p in row.evaluation.parts] == [row.reason, row.reason]
            assert row.log_path.is_file()
    assert report.ablations[0].command[-2:] == ("--definitely-not-a-flag", "--x")
    markdown = (tmp_path / "out" / "report.md").read_text()
    assert "## Ablations" in markdown and "| variant |" in markdown and "seq_a: failed: exit code" in markdown
    _load_strict_json(tmp_path / "out" / "report.json")


def test_standard_ablations_run_on_a_subset_and_compare_on_it(suite, tmp_path, monkeypatch):
    # Every run writes the oracle twin, so rows are scored without reconstructing; the calls
    # show which extra arguments each (label, sequence) run received.
    calls = []
    oracle_command = bench._method_command

    def fake(method, extra, capture, twin):
        calls.append((method, tuple(extra), Path(capture).name))
        return oracle_command("oracle", extra, capture, twin)

    monkeypatch.setattr(bench, "_method_command", fake)
    config = _config(method="funrec", ablation_set="standard", ablation_sequences="seq_b")
    report = run_bench(suite, tmp_path / "out", config)
    labels = [label for label, _ in bench.STANDARD_ABLATIONS]
    assert [m.label for m in report.methods] == ["funrec", *labels]
    assert [r.name for r in report.main.sequences] == list(SEQUENCES)
    for method, (_, flags) in zip(report.ablations, bench.STANDARD_ABLATIONS):
        assert [r.name for r in method.sequences] == ["seq_b"] and method.summary.failed_sequences == 0
        assert ("funrec", flags, "seq_b") in calls and ("funrec", flags, "seq_a") not in calls
    heading, rows = bench_report.ablation_rows(report)
    assert heading == "1 of 2 sequences: seq_b"
    assert [label for label, _ in rows] == ["funrec (full)", *labels]
    assert rows[0][1].sequences == 1  # the full method is summarised over the ablation sequences only
    markdown = (tmp_path / "out" / "report.md").read_text()
    assert "## Ablations (1 of 2 sequences: seq_b)" in markdown and "| no re-seeding |" in markdown
    assert "Ablations (1 of 2 sequences: seq_b):" in format_report(report)


def test_standard_ablation_flags_each_switch_off_one_stage():
    parser = argparse.ArgumentParser()
    add_config_arguments(parser, ReconstructConfig)
    defaults = ReconstructConfig()
    switched = {}
    for label, flags in bench.STANDARD_ABLATIONS:
        config = config_from_args(ReconstructConfig, parser.parse_args(list(flags)))
        assert config != defaults, label
        switched[label] = config
    assert not switched["no pose graph"].tracking.use_pose_graph
    assert not switched["no joint constraint"].part_motion.use_joint_constraint
    assert not switched["no re-seeding"].point_tracks.reseed
    assert not switched["no hand masks"].use_hand_masks


def test_timeout_is_a_failure_row(suite, tmp_path, monkeypatch):
    monkeypatch.setattr(bench, "_method_command", lambda *args: [sys.executable, "-c", "import time; time.sleep(60)"])
    report = run_bench(suite, tmp_path / "out", _config(method="funrec", timeout_s=0.5, only=("seq_a",)))
    row = report.main.sequences[0]
    assert row.status == "timeout" and row.reason == "timeout after 0.5 s"
    assert row.wall_s < 10.0 and row.peak_rss_mb is None  # killed, not waited for
    assert report.main.summary.fail_pct == 100.0


def test_bad_requests_raise(suite, tmp_path):
    with pytest.raises(FunrecError, match="expected one of"):
        run_bench(suite, tmp_path, _config(method="magic"))
    with pytest.raises(FunrecError, match="no capture with gt/ for \\['seq_z'\\]"):
        run_bench(suite, tmp_path, _config(method="oracle", only=("seq_z",)))
    with pytest.raises(FunrecError, match="unique"):
        run_bench(suite, tmp_path, _config(method="oracle", ablations=(("oracle", ()),)))
    with pytest.raises(FunrecError, match="unknown ablation set"):
        run_bench(suite, tmp_path, _config(ablation_set="everything"))
    with pytest.raises(FunrecError, match="ablates funrec"):
        run_bench(suite, tmp_path, _config(method="oracle", ablation_set="standard"))
    with pytest.raises(FunrecError, match="not among the sequences run"):
        run_bench(suite, tmp_path, _config(method="oracle", ablations=(("x", ()),), only=("seq_a",), ablation_sequences="seq_b"))
    with pytest.raises(FunrecError, match="no sequences"):
        run_bench(tmp_path / "empty", tmp_path / "out", _config(method="oracle"))


def _row(parts, status="ok", chamfer=None, frames=10, wall=2.0, cpu=1.0):
    evaluation = TwinEvaluation(Path("t"), Path("g"), tuple(parts), None if status == "ok" else "x", (), chamfer, 1.0)
    return bench.SequenceResult("s", "m", status, None, frames, wall, 50.0, evaluation, Path("t"), None, cpu)


def test_summary_averages_over_non_failed_parts_and_fails_over_all():
    door = PartEvaluation("d", "revolute", "p", None, 0.0, 5, 2.0, 0.1, 4.0, 80.0, 60.0, 50.0)
    drawer = PartEvaluation("w", "prismatic", "q", None, 0.0, 5, 6.0, None, 0.02, 40.0, 20.0, None)
    door_2 = PartEvaluation("d", "revolute", "p", None, 0.0, 5, 4.0, 0.3, 8.0, 60.0, 40.0, 70.0)
    failed = PartEvaluation("e", "revolute", failure="no part found")
    s = summarize([_row([door, drawer], chamfer=2.0), _row([door_2, failed], chamfer=4.0), _row([failed], status="timeout", wall=100.0)])
    assert (s.parts, s.failed_parts, s.fail_pct) == (5, 2, 40.0)
    assert s.axis_revolute_deg == pytest.approx(3.0) and s.axis_prismatic_deg == pytest.approx(6.0)
    assert s.pivot_m == pytest.approx(0.2) and s.state_revolute_deg == pytest.approx(6.0) and s.state_prismatic_m == pytest.approx(0.02)
    assert s.adds_auc == pytest.approx(60.0) and s.add_auc == pytest.approx(40.0)
    assert s.miou == pytest.approx(60.0)  # parts without an mIoU (no true mask) are left out
    assert s.chamfer_cm == pytest.approx(3.0)
    assert s.frames_per_s == pytest.approx(20 / 4.0)  # the timed-out run's time is not throughput
    assert s.frames_per_cpu_s == pytest.approx(20 / 2.0)
    assert s.failed_sequences == 1 and s.peak_rss_mb == 50.0


def test_summary_scores_contacts_over_all_scored_parts_and_fragments_per_sequence():
    from dataclasses import replace

    from funrec.bench.fragment_metrics import score_fragments

    door = PartEvaluation("d", "revolute", "p", None, 0.0, 5, 2.0, 0.1, 4.0, 80.0, 60.0, 50.0, contact_error_m=0.01)
    far = replace(door, contact_error_m=0.05)
    no_contact = replace(door, contact_error_m=None)
    # 15 FPS: a fragment 6 frames late (0.4 s) passes, one 9 frames late (0.6 s) fails.
    good = score_fragments([(16, 40)], [(10, 40)], fps=15.0)
    late = score_fragments([(19, 40), (60, 70)], [(10, 40)], fps=15.0)
    rows = [replace(_row([door, far]), fragments=good), replace(_row([no_contact]), fragments=late)]
    s = summarize(rows)
    assert s.contact_within_3cm_pct == pytest.approx(100.0 / 3)  # a scored part without a contact is a miss
    assert s.contact_median_cm == pytest.approx(3.0)  # median of 1 and 5 cm
    assert s.fragment_pass_pct == pytest.approx(50.0)
    assert s.fragment_boundary_max_s == pytest.approx(0.6)
    assert (s.interactions_missed, s.interactions_invented) == (0, 1)


@pytest.mark.slow  # starting a local Ray instance takes 15-30 s
def test_bench_through_ray_scores_like_local_processes(suite, tmp_path):
    pytest.importorskip("ray")
    # funrec bench --ray runs the same job function through funrec batch's scheduler as Ray tasks. The trivial
    # baseline is deterministic, so every score must be identical to the local run's.
    local = run_bench(suite, tmp_path / "local", _config(method="trivial"))
    on_ray = run_bench(suite, tmp_path / "ray", _config(method="trivial", ray="local"))
    for a, b in zip(local.main.sequences, on_ray.main.sequences, strict=True):
        assert (a.name, a.status) == (b.name, b.status)
        assert [p.axis_error_deg for p in a.evaluation.parts] == [p.axis_error_deg for p in b.evaluation.parts]
    assert local.main.summary.adds_auc == on_ray.main.summary.adds_auc
    assert (tmp_path / "ray" / "twins" / "trivial" / "seq_b" / "articulation.json").is_file()


def test_report_headline_is_the_worst_family_and_every_family_has_a_row():
    from dataclasses import replace

    good = PartEvaluation("d", "revolute", "p", None, 0.0, 5, 1.0, 0.01, 1.0, 95.0, 90.0, 90.0)
    failed = PartEvaluation("e", "revolute", failure="no part found")
    rows = (
        replace(_row([good]), name="a", family="textured"),
        replace(_row([good]), name="b", family="plain"),
        replace(_row([failed]), name="c", family="plain"),
    )
    assert [f for f, _ in bench_report.family_rows(rows)] == ["textured", "plain"]
    family, summary = bench_report.worst_family(rows)
    assert family == "plain" and summary.fail_pct == pytest.approx(50.0)
    crashed = (*rows, replace(_row([failed], status="failed"), name="d", family="dark"))
    assert bench_report.worst_family(crashed)[0] == "dark"  # a failed run ranks below a failed part
    method = bench_report.MethodReport("funrec", ("funrec",), rows, summarize(rows))
    slow = tuple(replace(r, method="open3d", wall_s=8.0) for r in rows[:2])
    baseline = bench_report.MethodReport("open3d", ("o3d",), slow, summarize(slow))
    report = bench_report.BenchReport(Path("s"), Path("o"), (method,), "abc", "m", "d", "c", _config(), (baseline,))
    text = format_report(report)
    assert "worst family (plain)" in text and "funrec: textured" in text and "open3d (2 sequences)" in text
    (speed,) = bench_report.speed_comparisons(report)
    assert speed.sequences == ("a", "b") and speed.ratio == pytest.approx(4.0)  # 2 s against 8 s per 10 frames
    assert "ratio 4.00x" in text
    assert bench_report.report_to_json(report)["worst_family"] == "plain"


def test_sequence_family_reads_the_generator_spec(tmp_path):
    (tmp_path / "gt").mkdir()
    assert bench.sequence_family(tmp_path) == "textured"  # no gt.json: the old textured bench
    (tmp_path / "gt" / "gt.json").write_text(json.dumps({"generator": {"spec": {"family": "plain"}}}))
    assert bench.sequence_family(tmp_path) == "plain"


@pytest.mark.slow  # renders a tiny sequence and runs Open3D in a subprocess: ~30 s on a busy machine
def test_open3d_baseline_runs_beside_funrec_on_the_chosen_sequences(tmp_path):
    synth = pytest.importorskip("funrec.synth")
    synth.generate_sequence(synth.tiny_spec(3), tmp_path / "suite")  # the fixture suite has no depth
    config = _config(method="funrec", reconstruct_args=("--definitely-not-a-flag",), speed_baseline="open3d", jobs=1)
    report = run_bench(tmp_path / "suite", tmp_path / "out", config)
    assert [m.label for m in report.methods] == ["funrec"]
    assert [b.label for b in report.baselines] == ["open3d"]
    (row,) = report.baselines[0].sequences
    assert row.status == "ok", row.reason
    assert row.evaluation.camera_ate_cm is not None
    assert row.family == "textured" and row.evaluation.camera_ate_cm < 5.0
    assert (tmp_path / "out" / "twins" / "open3d" / "tiny_03" / "meshes" / "static.ply").is_file()
