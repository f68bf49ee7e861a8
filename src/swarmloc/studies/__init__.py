"""The research studies, apart from the library's runtime: the thesis reproduction behind ``swarmloc reproduce``
(:mod:`~swarmloc.studies.thesis_static`, :mod:`~swarmloc.studies.thesis_dynamic`), leave-one-dataset-out on MRCLAM
(:mod:`~swarmloc.studies.lodo`), the 3-D study (:mod:`~swarmloc.studies.se3`), observability and the robocentric
Monte Carlo (:mod:`~swarmloc.studies.observability`, :mod:`~swarmloc.studies.robocentric`), and ``swarmloc bench``
with the benchmarks' helpers (:mod:`~swarmloc.studies.bench`, :mod:`~swarmloc.studies.bench_report`,
:mod:`~swarmloc.studies.accelerator`).

A layer above :mod:`swarmloc.experiments` and below :mod:`swarmloc.cli` (``pyproject.toml``'s import contract): only
the command line's study commands, the benchmarks, the examples and the tests import a study; the runtime
never does.
"""
