"""Data association for anonymous robot detections: binary registration, PMR multiple registration, rotational
symmetry, and a bank of particle filters (Stegagno's lecture slides 41-63; Franchi, Oriolo, Stegagno 2010)."""

from swarmloc.association.pfbank import BankEstimate, ParticleFilterBank
from swarmloc.association.pmr import (
    PMRResult,
    Solution,
    multiple_registration,
    rotational_symmetry_order,
    solution_count_theory,
    symmetry_metric,
)
from swarmloc.association.registration import Registration, binary_register, points_from_range_bearing
from swarmloc.association.tracker import AnonymousTrack, anonymous_scans, track_anonymous

__all__ = [
    "AnonymousTrack",
    "BankEstimate",
    "PMRResult",
    "ParticleFilterBank",
    "Registration",
    "Solution",
    "anonymous_scans",
    "binary_register",
    "multiple_registration",
    "points_from_range_bearing",
    "rotational_symmetry_order",
    "solution_count_theory",
    "symmetry_metric",
    "track_anonymous",
]
