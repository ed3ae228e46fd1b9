"""Ask a twin where to grasp: list its parts with their contact points, then the grasp frame of each part at a
few joint states across its observed range (funrec.query).

    python demos/query_affordance.py --twin TWIN
    python demos/query_affordance.py -o demo_output   # generate a capture and reconstruct it first
"""

from __future__ import annotations

import numpy as np
from reconstruct_and_view import twin_from, twin_parser  # the sibling demo (python puts demos/ on the path)


def main() -> None:
    twin = twin_from(twin_parser(__doc__).parse_args())
    from funrec.query import format_parts, grasp_frame, list_parts

    rows = list_parts(twin)
    print(format_parts(rows))
    for row in rows:
        if row.contact_point is None:
            print(f"{row.name}: no grasp ({row.note})")
            continue
        for state in np.linspace(row.state_range[0], row.state_range[1], 3):
            T_world_grasp = grasp_frame(twin, row.name, float(state))
            approach = T_world_grasp[:3, 2]
            print(f"{row.name} at state {state:.3f}: grasp at {T_world_grasp[:3, 3].round(3)} m, approach {approach.round(3)}")


if __name__ == "__main__":
    main()
