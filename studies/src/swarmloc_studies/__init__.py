"""swarmloc's research studies, a package of their own beside the library (installed with
``pip install -e ./studies``): the thesis reproduction behind ``swarmloc-studies reproduce``
(:mod:`~swarmloc_studies.thesis_static`, :mod:`~swarmloc_studies.thesis_dynamic`), leave-one-dataset-out on MRCLAM
(:mod:`~swarmloc_studies.lodo`), the 3-D study (:mod:`~swarmloc_studies.se3`), observability and the robocentric
Monte Carlo (:mod:`~swarmloc_studies.observability`, :mod:`~swarmloc_studies.robocentric`), and
``swarmloc-studies bench`` with the benchmarks' helpers (:mod:`~swarmloc_studies.bench`,
:mod:`~swarmloc_studies.bench_report`, :mod:`~swarmloc_studies.accelerator`); the command line is
:mod:`swarmloc_studies.cli`.

The studies import swarmloc; swarmloc never imports them (``pyproject.toml``'s import contract): only this
package's command line, the benchmarks, the examples and the tests import a study.
"""
