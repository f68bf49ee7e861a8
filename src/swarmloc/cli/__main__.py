"""``python -m swarmloc.cli``: the command line (:func:`swarmloc.cli.console`)."""

from swarmloc.cli import console

console()
