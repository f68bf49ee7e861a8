"""One module per ``swarmloc`` command, named as the command (``swarmloc team`` -> :mod:`.team`): its
``add_parser(sub)`` (the options and their help) and its ``run(args)`` (the exit status).

Argument groups several commands share are in :mod:`swarmloc.cli.options`, run-time helpers in
:mod:`swarmloc.cli.common` and the live view of ``node`` and ``team`` in :mod:`swarmloc.cli.liveview`."""
