"""``python -m thesis_repro.claims``: :func:`thesis_repro.claims.cli.main`."""

from thesis_repro.claims.cli import main

raise SystemExit(main())
