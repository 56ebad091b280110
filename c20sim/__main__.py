"""``python -m c20sim``: the same as the ``c20sim`` command."""

from .cli import main

raise SystemExit(main())
