"""``python -m forecast_design``: the command line."""

from .cli import main

raise SystemExit(main())
