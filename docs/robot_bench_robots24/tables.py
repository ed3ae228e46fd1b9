"""Family tables and per-row joins of robot bench JSON files (funrec-robot bench -o), joined by (capture, part).

    python tables.py table RUN.json [AFTER.json ...]   # passed / accepted (refused) per family; AFTER rows replace RUN's
    python tables.py rows TWINS.json GT.json           # each (capture, part): the twin verdict beside the true scene's
    python tables.py summary RUN.json [AFTER.json ...] # one line: passed/accepted, refused, plan CPU, force, collisions
    python tables.py changed RUN.json AFTER.json       # the (capture, part) whose verdict differs
"""

import json
import sys


def load(path):
    return {(r["case"], r["part"]): r for r in json.load(open(path))["rows"]}


def verdict(row):
    if row is None:
        return "-"
    if row["refused"]:
        return "REFUSED"
    return "PASS" if row["passed"] else ("FAIL" if row["planned"] else "NO PLAN")


def cell(rows):
    accepted = [r for r in rows if not r["refused"]]
    return f"{sum(r['passed'] for r in rows)}/{len(accepted)} ({len(rows) - len(accepted)} ref.)"


def table(paths):
    rows = load(paths[0])
    for path in paths[1:]:
        rows.update({k: v for k, v in load(path).items() if k in rows})
    families = sorted({r["family"] for r in rows.values()})
    cells = [cell([r for r in rows.values() if r["family"] == f]) for f in families]
    print("| " + " | ".join(families) + " | all |")
    print("|---" * (len(families) + 1) + "|")
    print("| " + " | ".join(cells) + f" | **{cell(list(rows.values()))}** |")


def percentile(values, q):
    """numpy.percentile's linear interpolation of sorted ``values``, as the bench's summary computes it."""
    position = q / 100 * (len(values) - 1)
    low = int(position)
    high = min(low + 1, len(values) - 1)
    return values[low] + (position - low) * (values[high] - values[low])


def summary(paths):
    rows = load(paths[0])
    for path in paths[1:]:
        rows.update({k: v for k, v in load(path).items() if k in rows})
    rows = list(rows.values())
    accepted = [r for r in rows if not r["refused"]]
    passed = sum(r["passed"] for r in rows)
    cpu = sorted(r["plan_cpu_time"] for r in rows)
    median, p95 = percentile(cpu, 50), percentile(cpu, 95)
    forces = [r["peak_handle_force"] for r in rows if r["planned"]]
    collisions = sum(r["collisions"] > 0 for r in rows if r["planned"])
    print(f"{passed}/{len(accepted)} ({100 * passed / max(len(accepted), 1):.0f} %) | {len(rows) - len(accepted)} | "
          f"{median:.2f} / {p95:.2f} s | {max(forces):.1f} N | {collisions}")


def changed(before_path, after_path):
    before, after = load(before_path), load(after_path)
    for key in sorted(set(before) & set(after)):
        if verdict(before[key]) != verdict(after[key]):
            print(f"{key[0]} {key[1]}: {verdict(before[key])} -> {verdict(after[key])}")


def joined(twins_path, gt_path):
    twins, gt = load(twins_path), load(gt_path)
    for key in sorted(set(twins) | set(gt)):
        t, g = twins.get(key), gt.get(key)
        why = (t or {}).get("failure") or ""
        print(f"{key[0]:34s} {key[1]:7s} twin {verdict(t):8s} gt {verdict(g):8s} {why[:150]}")


if __name__ == "__main__":
    {"table": table, "summary": summary, "rows": lambda a: joined(*a), "changed": lambda a: changed(*a)}[sys.argv[1]](sys.argv[2:])
