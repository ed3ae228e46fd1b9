"""Replay the demonstrated interaction with a mobile manipulator: plan on the reconstructed twin
(funrec_robot.plan), then execute the plan in MuJoCo against the true scene of the generated capture
(funrec_robot.check) and say whether the robot opened the part.

    python demos/replay_on_robot.py --twin TWIN --capture CAPTURE   # CAPTURE holds gt/ (a generated capture)
    python demos/replay_on_robot.py -o demo_output                  # generate a capture and reconstruct it first
"""

from __future__ import annotations

import argparse
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--twin", type=Path, help="twin folder from funrec reconstruct")
    parser.add_argument("--capture", type=Path, help="the capture the twin came from, with gt/ (for the true scene)")
    parser.add_argument("-o", "--output", type=Path, default=Path("demo_output"), help="output folder")
    parser.add_argument("--robot", default=None, help="robot name or YAML file (default: the default robot)")
    args = parser.parse_args()
    twin, capture = args.twin, args.capture
    if twin is None or capture is None:
        from reconstruct_and_view import make_twin  # the sibling demo (python puts demos/ on the path)

        capture, twin = make_twin(args.output)

    from funrec_robot import default_robot_path, resolve_robot
    from funrec_robot.check import check_plan_file
    from funrec_robot.plan import plan_scene
    from funrec_robot.plan_file import write_plan

    robot = resolve_robot(args.robot) if args.robot else default_robot_path()
    plan = plan_scene(robot, twin, target="open")
    args.output.mkdir(parents=True, exist_ok=True)
    plan_path = args.output / "plan.json"
    write_plan(plan_path, plan)
    print(f"planned {plan.part} ({plan.joint_type}) {plan.start_state:.3f} -> {plan.target_state:.3f} in {plan.duration:.1f} s "
          f"with {len(plan.base_poses)} base stop(s): {plan_path}")
    report = check_plan_file(plan_path, gt_dir=capture / "gt")
    verdict = "PASS" if report.passed else "FAIL: " + ", ".join(f"{f.criterion} at {f.time:.2f} s" for f in report.failures)
    print(f"{verdict}: in the true scene {report.joint} ended at {report.final_state:.3f} (target {report.target_state:.3f}), "
          f"peak handle force {report.peak_handle_force:.1f} N")


if __name__ == "__main__":
    main()
