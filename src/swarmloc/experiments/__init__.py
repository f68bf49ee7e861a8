"""Reproductions of the thesis' experiments (ch. 5) that write tables, JSON and figures to a folder.

``run_demo`` and ``run_tables`` (thesis sec. 5.1) live in :mod:`swarmloc.experiments.thesis_static`; they are
imported lazily, so that importing this package (e.g. for :mod:`swarmloc.experiments.mrclam`) does not load the
thesis experiments.
"""

from __future__ import annotations

from typing import Any

__all__ = ["run_demo", "run_tables"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from swarmloc.experiments import thesis_static

        return getattr(thesis_static, name)
    raise AttributeError(f"module 'swarmloc.experiments' has no attribute {name!r}")
