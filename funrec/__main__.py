"""``python -m funrec`` runs the command-line interface."""

from funrec.cli import main

raise SystemExit(main())
