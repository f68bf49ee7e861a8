"""Readers for public multi-robot datasets."""

from swarmloc.datasets.mrclam import (
    DEFAULT_BEARING_STD,
    DEFAULT_RANGE_STD,
    ROBOT_SUBJECTS,
    MRCLAMData,
    MRCLAMError,
    load_mrclam,
    mrclam_events,
)

__all__ = [
    "DEFAULT_BEARING_STD",
    "DEFAULT_RANGE_STD",
    "MRCLAMData",
    "MRCLAMError",
    "ROBOT_SUBJECTS",
    "load_mrclam",
    "mrclam_events",
]
