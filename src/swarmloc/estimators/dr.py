"""Dead reckoning: the thesis' prediction alone (second-order exponential-coordinate convolution), no fusion.

The baseline every cooperative estimator must beat. Every detection is counted ``rejected`` with the reason
"dead reckoning does not use detections", so that a run's accounting still adds up.

It takes an association policy (``nearest``, ``joint``) so that a comparison of every estimator runs with one, and
associates nothing: an anonymous detection is counted like a tagged one, ``rejected`` with the same reason, no
teammate is asked, and every ``association_*`` counter stays 0 (no identity was chosen, right or wrong, so the
association accuracy of a run is undefined, "-" in the reports, not 0 or 1).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from swarmloc.estimators.expfusion import ExpNode, ExpState
from swarmloc.gaussian import GroupGaussian
from swarmloc.messages import Message
from swarmloc.motion import UnicycleNoise
from swarmloc.node import Group, Outcome

UNUSED = "dead reckoning does not use detections"


class NoFusion:
    """``dr``'s update: none (every detection counted ``rejected``, :data:`UNUSED`)."""

    def fuse_group(self, node: ExpNode, s: ExpState, g: Group) -> tuple[ExpState, list[Outcome], list[Message]]:
        return s, [("rejected", UNUSED)] * len(g.detections), []


class DeadReckoning(ExpNode):
    """Exponential-coordinate prediction only (:class:`~swarmloc.estimators.expfusion.ExpNode` with
    :class:`NoFusion`; it asks no teammate: ``use_relative`` is off).

    Parameters: ``robot``, ``initial``, ``noise``, ``order`` (1 or 2), the clock's ``t0``, ``horizon``,
    ``tolerance``, ``jump_inputs``, and ``team``, ``association``, ``association_gate``, ``sensor_range``,
    ``sensor_fov`` (checked as every node checks them, then unused: module docstring); nothing else (an unknown
    keyword raises TypeError).
    """

    name = "dr"
    rule = NoFusion()

    def __init__(
        self,
        robot: int,
        initial: GroupGaussian,
        *,
        noise: UnicycleNoise,
        order: int = 2,
        t0: float | None = None,
        horizon: float | None = None,
        tolerance: float | None = None,
        jump_inputs: int | None = None,
        team: Sequence[int] = (),
        association: str = "tags",
        association_gate: float = 0.99,
        sensor_range: float | None = None,
        sensor_fov: float | None = None,
    ) -> None:
        clock = {"horizon": horizon, "tolerance": tolerance, "jump_inputs": jump_inputs}
        kw: dict[str, Any] = {k: v for k, v in clock.items() if v is not None}
        super().__init__(robot, initial, noise=noise, order=order, t0=t0, use_relative=False, use_landmarks=False,
                         team=team, association=association, association_gate=association_gate,
                         sensor_range=sensor_range, sensor_fov=sensor_fov, **kw)  # fmt: skip
