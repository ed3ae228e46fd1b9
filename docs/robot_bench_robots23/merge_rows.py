"""Family tables from a full bench run (before) and the rows re-run on a branch (after).

    python merge_rows.py BEFORE.json [AFTER_SUBSET.json ...]

Prints, per family, passed / accepted (refused) before, and after: the before rows with every (case, part)
that an AFTER file holds replaced by its row there. Rows no AFTER file holds are the before run's."""

import json
import sys


def load(path):
    return {(r["case"], r["part"]): r for r in json.load(open(path))["rows"]}


def cell(rows):
    accepted = [r for r in rows if not r["refused"]]
    passed = sum(r["passed"] for r in rows)
    return f"{passed}/{len(accepted)} ({len(rows) - len(accepted)} ref.)"


before = load(sys.argv[1])
after = dict(before)
rerun = set()
for path in sys.argv[2:]:
    for key, row in load(path).items():
        if key in before:
            after[key] = row
            rerun.add(key)
families = sorted({r["family"] for r in before.values()})
print("| | " + " | ".join(families) + " | all |")
print("|---" * (len(families) + 2) + "|")
for name, rows in (("before", before), ("after", after)):
    cells = [cell([r for r in rows.values() if r["family"] == f]) for f in families]
    print(f"| {name} | " + " | ".join(cells) + f" | **{cell(list(rows.values()))}** |")
changed = [k for k in sorted(rerun) if before[k]["passed"] != after[k]["passed"] or before[k]["refused"] != after[k]["refused"]]
print(f"\nre-run rows: {len(rerun)}; changed: " + ", ".join(f"{c} {p} {'PASS' if after[(c, p)]['passed'] else 'FAIL'}" for c, p in changed))
