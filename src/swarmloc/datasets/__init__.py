"""Readers and writers of data: the UTIAS MRCLAM dataset (:mod:`~swarmloc.datasets.mrclam`), your own robots' event
files (:mod:`~swarmloc.datasets.eventfile`) and TUM trajectories (:mod:`~swarmloc.datasets.tum`).

The MRCLAM names are loaded on first use, so that reading an event file does not import pandas.
"""

from __future__ import annotations

from typing import Any

_MRCLAM = (
    "DEFAULT_BEARING_STD",
    "DEFAULT_RANGE_STD",
    "MRCLAMData",
    "MRCLAMError",
    "ROBOT_SUBJECTS",
    "load_mrclam",
    "mrclam_events",
)
__all__ = [*_MRCLAM]


def __getattr__(name: str) -> Any:
    if name in _MRCLAM:
        from swarmloc.datasets import mrclam

        return getattr(mrclam, name)
    raise AttributeError(f"module 'swarmloc.datasets' has no attribute {name!r}")
