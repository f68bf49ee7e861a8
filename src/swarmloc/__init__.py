"""swarmloc: multi-robot cooperative localization on SE(2)/SE(3) in exponential coordinates.

What a user needs is here: the groups (:class:`SE2`, :class:`SE3`), Gaussians on them (:class:`GroupGaussian`),
the fusion functions, the estimators as nodes (one per robot; :func:`make_team` builds a team) and the in-process
runner (:func:`run`). Using them loads numpy, scipy and msgspec only: figures, tables and progress bars live with
the experiments and the command line.

The names are loaded on first use (``from swarmloc import run`` or ``swarmloc.run``), not by ``import swarmloc``
itself: a program that only needs a part of the package (the command line, which parses its arguments before
anything else; a network process, which must be able to end with its launcher from its first moment) does not wait
for the whole numerical core to load. The names and the subpackage each comes from are declared once, in the
package's type stub (``__init__.pyi``), which type checkers read and ``lazy_loader`` attaches.
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach_stub(__name__, __file__)
__version__ = "0.1.0"
