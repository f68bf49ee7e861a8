"""``python -m swarmloc.cli``: the command line (:func:`swarmloc.cli.main`)."""

from swarmloc.cli import main

raise SystemExit(main())
