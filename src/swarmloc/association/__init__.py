"""Data association: which robot an anonymous detection saw, and anonymous mutual localization.

* ``policies``: gated nearest neighbour (lecture slide 38, eq. 8) and joint assignment of a scan's detections
  (slide 39, eq. 9) on squared Mahalanobis distances of the innovations, with clutter, ambiguous and missed outcomes;
* ``registration``, ``pmr``: binary and multiple registration of anonymous scans, rotational symmetry (Stegagno's
  slides 41-63; Franchi, Oriolo, Stegagno 2010); ``pfbank``: a bank of particle filters over the solutions;
  ``tracker``: anonymous mutual localization of a team from them.
"""

from swarmloc.association.pfbank import BankEstimate, BankSettings, ParticleFilterBank
from swarmloc.association.pmr import (
    PMRResult,
    Solution,
    multiple_registration,
    rotational_symmetry_order,
    solution_count_theory,
    symmetry_metric,
)
from swarmloc.association.policies import (
    AMBIGUOUS,
    CLUTTER,
    Association,
    gate_threshold,
    innovation_terms,
    joint,
    likely_rivals,
    nearest,
)
from swarmloc.association.registration import Registration, binary_register, points_from_range_bearing
from swarmloc.association.tracker import AnonymousTrack, anonymous_scans, track_anonymous

__all__ = [
    "AMBIGUOUS",
    "CLUTTER",
    "AnonymousTrack",
    "Association",
    "BankEstimate",
    "BankSettings",
    "PMRResult",
    "ParticleFilterBank",
    "Registration",
    "Solution",
    "anonymous_scans",
    "binary_register",
    "gate_threshold",
    "innovation_terms",
    "joint",
    "likely_rivals",
    "multiple_registration",
    "nearest",
    "points_from_range_bearing",
    "rotational_symmetry_order",
    "solution_count_theory",
    "symmetry_metric",
    "track_anonymous",
]
