#!/bin/bash
cd "$(dirname "$0")"
O=rows
echo "### Fetch, reseed 3 (before: docs/robot_bench_robots21s/gt_fetch_r3_7725af3, 64/70 as at 9a28e49; after: the 6 failing cases re-run at 7d4c601)"
python3 merge_rows.py ../robot_bench_robots21s/gt_fetch_r3_7725af3.json $O/7d4c601sub_fetch_r3.json
echo; echo "### TIAGo, reseed 3 (before: docs/robot_bench_robots21s/gt_tiago_r3_7725af3, 67/73; after: the 6 failing cases, 10 passing or refused high-handle cases and 12 passing low or mid-height cases re-run at 7d4c601)"
python3 merge_rows.py ../robot_bench_robots21s/gt_tiago_r3_7725af3.json $O/7d4c601sub_tiago_r3.json $O/7d4c601pass_tiago_r3.json $O/7d4c601pass2_tiago_r3.json
echo; echo "### Fetch, reseed 7, the 28 captures of docs/robot_bench_reseed7 (before: 0d1d6f8 there; after: its 7 failing rows re-run at 7d4c601)"
python3 merge_rows.py ../robot_bench_reseed7/gt_fetch_r7.json $O/7d4c601sub_fetch_r7.json
echo; echo "### TIAGo, reseed 7, the same 28 captures (after: its 4 failing rows re-run at 7d4c601)"
python3 merge_rows.py ../robot_bench_reseed7/gt_tiago_r7.json $O/7d4c601sub_tiago_r7.json
for r in fetch tiago; do echo; echo "### $r, reseed 9 (10 fresh scenes; before 9a28e49, after 7d4c601, every row measured both times)"; python3 merge_rows.py $O/basesub_${r}_r9.json $O/7d4c601sub_${r}_r9.json; done
