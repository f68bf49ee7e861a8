"""``python -m swarmloc_studies.cli``: the command line (:func:`swarmloc_studies.cli.console`)."""

from swarmloc_studies.cli import console

console()
