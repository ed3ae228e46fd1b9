"""``python -m funrec_robot``: the funrec-robot command line."""

from funrec_robot.cli import main

raise SystemExit(main())
