"""Configuration of the models and the filter, read from a TOML file (standard library :mod:`tomllib`).

Five sections, every key optional (a missing key keeps its default; defaults are the MRCLAM evaluation defaults of
:mod:`swarmloc.experiments.mrclam`)::

    [motion]     # unicycle body-twist diffusion (swarmloc.motion.unicycle.UnicycleNoise), per second
    q_v0 = 0.0001    # [m^2/s]      q_fwd = q_v0 + q_v1 |v| + q_v2 v^2
    q_v1 = 0.0       # [m]
    q_v2 = 0.05      # [s]
    q_lat0 = 0.0001  # [m^2/s]      q_lat = q_lat0 + q_lat1 |v|
    q_lat1 = 0.01    # [m]
    q_w0 = 0.001     # [rad^2/s]    q_yaw = q_w0 + q_w1 |w| + q_w2 w^2 + q_wv |v|
    q_w1 = 0.0       # [rad]
    q_w2 = 0.05      # [s]
    q_wv = 0.02      # [rad^2/m]

    [sensors]    # noise std of detections that carry none, and of MRCLAM's camera
    range_std = 0.1            # [m]    a priori (camera spec order), not fitted to any ground truth
    bearing_std = 0.035        # [rad]  a priori (2 deg)
    decorrelate = "calibrate"  # MRCLAM camera errors, correlated in time (swarmloc.sensors.decorrelate):
                               # "calibrate": std and correlation estimated from the dataset's own landmark
                               #   detections and map (no ground truth), each detection weighted by its share
                               #   of the information of its (observer, target) stream;
                               # "weights": the same weighting with range_std / bearing_std as the std;
                               # "off": white noise with range_std / bearing_std (the former model used
                               #   range_std = 0.3, a white-noise inflation calibrated on dataset 6's truth)
    pose_xy_std = 0.05         # [m]    relative pose, exponential coordinates
    pose_theta_std = 0.0175    # [rad]
    absolute_xy_std = 0.01     # [m]    absolute fix
    absolute_theta_std = 0.01  # [rad]

    [filter]
    gate = 0.997       # chi-square probability in (0, 1) of the innovation gate; false (or 0) disables it
    horizon = 5.0      # [s] how far back out-of-order input is replayed
    clock_tolerance = 5.0  # [s] how far past a node's present an input may be stamped (capped at horizon)
    clock_jump_inputs = 3  # inputs in a row, at distinct stamps, that confirm a jump of a robot's clock
    order = 2          # 1 or 2: order of the SE(2) convolution
    iterations = 2     # >= 1, iterations of the iterated update
    point_iterations = 3  # >= 1, iterations of a point (landmark) update
    association = "tags"  # robot detections' identities: tags (given), nearest, joint (chosen from the beliefs,
                          # ids hidden), anonymous (PMR + particle-filter bank, ids hidden; swarmloc.association)
    association_gate = 0.99  # chi-square probability in (0, 1) of the association gate
    quarantine = 3     # a teammate's updates refused in a row (beyond the gate) that quarantine it for the run;
                       # false (or 0): never (swarmloc.node.trust)

    [record]
    rate = 4.0         # [Hz] in (0, 1000]: rate at which beliefs are recorded

    [initial]
    std_xy = 0.01      # [m] initial-belief std of x and y
    std_theta = 0.01   # [rad] initial-belief std of the heading

Units: metres, radians, seconds. Every problem raises :class:`ConfigError` (a ``ValueError``) naming the file, the
``[section] key`` and what was expected; a TOML syntax error names the file, line and column.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from swarmloc.motion.unicycle import UnicycleNoise

__all__ = [
    "DEFAULTS",
    "Config",
    "ConfigError",
    "FilterConfig",
    "InitialConfig",
    "MAX_RECORDS",
    "MAX_RECORD_RATE",
    "MotionConfig",
    "RecordConfig",
    "SensorConfig",
    "load_config",
]


class ConfigError(ValueError):
    """A problem with a configuration: unknown section or key, wrong type, value out of range, TOML syntax."""


# ----------------------------------------------------------------------------------------------------------------
# field validation (shared by every section; runs in __post_init__, so direct construction is checked too)


def _describe(value: object) -> str:
    if isinstance(value, bool):
        return f"a boolean ({str(value).lower()})"
    if isinstance(value, str):
        return f"a string ({value!r})"
    if isinstance(value, int | float):
        return repr(value)
    return f"a {type(value).__name__} ({value!r})"


def _real(section: str, key: str, value: object, lo: float | None, lo_open: bool, what: str) -> float:
    """``value`` as a finite float ``> lo`` (``lo_open``) or ``>= lo``; TOML integers are accepted."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"[{section}] {key}: expected {what}, got {_describe(value)}")
    x = float(value)
    if not math.isfinite(x) or (lo is not None and (x <= lo if lo_open else x < lo)):
        raise ConfigError(f"[{section}] {key}: expected {what}, got {_describe(value)}")
    return x


def _nonneg(section: str, key: str, value: object) -> float:
    return _real(section, key, value, 0.0, False, "a finite number >= 0")


def _positive(section: str, key: str, value: object) -> float:
    return _real(section, key, value, 0.0, True, "a finite number > 0")


def _integer(section: str, key: str, value: object, allowed: tuple[int, ...] | None, lo: int, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ConfigError(f"[{section}] {key}: expected {what}, got {_describe(value)}")
    n = int(value)
    if (allowed is not None and n not in allowed) or n < lo:
        raise ConfigError(f"[{section}] {key}: expected {what}, got {n}")
    return n


def _set(obj: object, name: str, value: object) -> None:
    object.__setattr__(obj, name, value)


def _fmt(x: float | int) -> str:
    """Exact TOML literal: integers as integers, floats as Python's shortest round-trip repr."""
    return str(int(x)) if isinstance(x, int) else repr(float(x))


# ----------------------------------------------------------------------------------------------------------------
# sections


@dataclass(frozen=True)
class MotionConfig:
    """Coefficients of the unicycle body-twist diffusion (see :mod:`swarmloc.motion.unicycle`), all ``>= 0``."""

    SECTION: ClassVar[str] = "motion"
    UNITS: ClassVar[dict[str, str]] = {
        "q_v0": "[m^2/s] forward diffusion floor: q_fwd = q_v0 + q_v1 |v| + q_v2 v^2",
        "q_v1": "[m] forward diffusion per metre travelled",
        "q_v2": "[s] forward diffusion per speed squared (relative speed error)",
        "q_lat0": "[m^2/s] lateral diffusion floor: q_lat = q_lat0 + q_lat1 |v|",
        "q_lat1": "[m] lateral diffusion per metre travelled",
        "q_w0": "[rad^2/s] yaw diffusion floor: q_yaw = q_w0 + q_w1 |w| + q_w2 w^2 + q_wv |v|",
        "q_w1": "[rad] yaw diffusion per radian turned",
        "q_w2": "[s] yaw diffusion per yaw rate squared",
        "q_wv": "[rad^2/m] yaw diffusion per metre travelled",
    }

    q_v0: float = 1e-4
    q_v1: float = 0.0
    q_v2: float = 0.05
    q_lat0: float = 1e-4
    q_lat1: float = 0.01
    q_w0: float = 1e-3
    q_w1: float = 0.0
    q_w2: float = 0.05
    q_wv: float = 0.02

    def __post_init__(self) -> None:
        for f in fields(self):
            _set(self, f.name, _nonneg(self.SECTION, f.name, getattr(self, f.name)))

    def noise(self) -> UnicycleNoise:
        """The :class:`~swarmloc.motion.unicycle.UnicycleNoise` with these coefficients."""
        return UnicycleNoise(**{f.name: getattr(self, f.name) for f in fields(self)})

    @classmethod
    def from_noise(cls, noise: UnicycleNoise) -> MotionConfig:
        """The section holding the coefficients of ``noise``."""
        return cls(**{name: getattr(noise, name) for name in UnicycleNoise.__slots__})


@dataclass(frozen=True)
class SensorConfig:
    """Noise standard deviations used when a detection carries none (and for MRCLAM's camera), all ``> 0``.

    ``pose_*`` are the std of the exponential coordinates of a relative-pose measurement's noise; ``absolute_*``
    those of an absolute fix of the observer's own pose. ``decorrelate`` (one of :attr:`DECORRELATE`) says how
    MRCLAM's time-correlated camera errors are modelled (:mod:`swarmloc.sensors.decorrelate`; module docstring).
    """

    SECTION: ClassVar[str] = "sensors"
    UNITS: ClassVar[dict[str, str]] = {
        "range_std": "[m] range std",
        "bearing_std": "[rad] bearing std",
        "pose_xy_std": "[m] relative pose: x and y std (exponential coordinates)",
        "pose_theta_std": "[rad] relative pose: heading std",
        "absolute_xy_std": "[m] absolute fix: x and y std",
        "absolute_theta_std": "[rad] absolute fix: heading std",
        "decorrelate": "MRCLAM camera: calibrate (estimated std and correlation), weights (given std), or off",
    }
    DECORRELATE: ClassVar[tuple[str, ...]] = ("calibrate", "weights", "off")

    range_std: float = 0.1
    bearing_std: float = 0.035
    pose_xy_std: float = 0.05
    pose_theta_std: float = 0.0175
    absolute_xy_std: float = 0.01
    absolute_theta_std: float = 0.01
    decorrelate: str = "calibrate"

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name != "decorrelate":
                _set(self, f.name, _positive(self.SECTION, f.name, getattr(self, f.name)))
        if self.decorrelate not in self.DECORRELATE:
            choices = ", ".join(f'"{c}"' for c in self.DECORRELATE)
            got = _describe(self.decorrelate)
            raise ConfigError(f"[{self.SECTION}] decorrelate: expected one of {choices}, got {got}")

    def detection_defaults(self) -> dict[str, np.ndarray]:
        """Per measurement kind, the default noise std vector (for ``load_events(defaults=...)``)."""
        return {
            "pose": np.array([self.pose_xy_std, self.pose_xy_std, self.pose_theta_std]),
            "range_bearing": np.array([self.range_std, self.bearing_std]),
            "range": np.array([self.range_std]),
            "bearing": np.array([self.bearing_std]),
            "absolute": np.array([self.absolute_xy_std, self.absolute_xy_std, self.absolute_theta_std]),
        }


@dataclass(frozen=True)
class FilterConfig:
    """Filter settings: innovation gate, out-of-order horizon, convolution order, iteration counts.

    ``gate``: probability in ``(0, 1)`` of the chi-square gate on the normalized innovation squared, or None for
    no gate (TOML: ``gate = false`` or ``gate = 0``). ``horizon`` [s] ``> 0``: how far back out-of-order input is
    replayed. ``clock_tolerance`` [s] ``> 0`` (the nodes take at most ``horizon``) and ``clock_jump_inputs`` (an
    integer in [1, 100]): the node's clock contract (:mod:`swarmloc.node.clock`). ``order``: 1 or 2.
    ``iterations``, ``point_iterations``: integers ``>= 1``. ``association`` (one of :attr:`ASSOCIATIONS`) and
    ``association_gate`` (a probability in ``(0, 1)``): how robot detections get their identity
    (:mod:`swarmloc.experiments.association`). ``smoother_lag`` [s] ``> 0``: the window of the fixed-lag smoothers
    ``fls`` and ``flsd``; ``delayed_output`` (a boolean): they also give their smoothed estimate of each pose as it
    leaves the window (``smoother_lag`` s late), scored beside the causal belief as ``"<name>_delayed"`` and
    published by network nodes (:mod:`swarmloc.evaluation.delayed`). ``diekf_cluster`` (an integer ``>= 0``): robots
    per ``diekf`` cluster, 0 for the exact filter over the whole team (:mod:`swarmloc.estimators.diekf`).
    ``quarantine``: a teammate's updates refused in a row (each beyond the gate) that quarantine it for the run, an
    integer ``>= 1``, or None: never (TOML: ``quarantine = false`` or ``0``; :mod:`swarmloc.node.trust`).
    """

    SECTION: ClassVar[str] = "filter"
    UNITS: ClassVar[dict[str, str]] = {
        "gate": "chi-square probability in (0, 1) of the innovation gate; false disables it",
        "horizon": "[s] how far back out-of-order input is replayed",
        "clock_tolerance": "[s] how far past a node's present an input may be stamped (capped at horizon)",
        "clock_jump_inputs": "inputs in a row, at distinct stamps, that confirm a jump of a robot's clock",
        "order": "1 or 2: order of the SE(2) convolution",
        "iterations": "iterations of the iterated update (>= 1)",
        "point_iterations": "iterations of a point (landmark) update (>= 1)",
        "association": "tags, nearest, joint or anonymous: how robot detections get their identity",
        "association_gate": "chi-square probability in (0, 1) of the association gate",
        "smoother_lag": "[s] window of the fixed-lag smoothers fls and flsd",
        "delayed_output": "true or false: fls and flsd also output each pose as it leaves the window",
        "diekf_cluster": "robots per diekf cluster (0: the exact filter over the whole team)",
        "quarantine": "a teammate's updates refused in a row that quarantine it for the run; false: never",
    }
    ASSOCIATIONS: ClassVar[tuple[str, ...]] = ("tags", "nearest", "joint", "anonymous")

    gate: float | None = 0.997
    horizon: float = 5.0
    clock_tolerance: float = 5.0
    clock_jump_inputs: int = 3
    order: int = 2
    iterations: int = 2
    point_iterations: int = 3
    association: str = "tags"
    association_gate: float = 0.99
    smoother_lag: float = 2.0
    delayed_output: bool = False
    diekf_cluster: int = 0
    quarantine: int | None = 3

    def __post_init__(self) -> None:
        s = self.SECTION
        q = self.quarantine
        if q is not None and q is not False and not (isinstance(q, int | np.integer) and q == 0):  # (True is 1)
            q = _integer(s, "quarantine", q, None, 1, "an integer >= 1, or false (or 0): never")
        _set(self, "quarantine", q or None)
        _set(self, "diekf_cluster", _integer(s, "diekf_cluster", self.diekf_cluster, None, 0, "an integer >= 0"))
        _set(self, "smoother_lag", _positive(s, "smoother_lag", self.smoother_lag))
        if not isinstance(self.delayed_output, bool):
            raise ConfigError(f"[{s}] delayed_output: expected true or false, got {_describe(self.delayed_output)}")
        if self.association not in self.ASSOCIATIONS:
            choices = ", ".join(f'"{c}"' for c in self.ASSOCIATIONS)
            raise ConfigError(f"[{s}] association: expected one of {choices}, got {_describe(self.association)}")
        a = _real(s, "association_gate", self.association_gate, 0.0, True, "a probability in (0, 1)")
        if not a < 1.0:
            raise ConfigError(f"[{s}] association_gate: expected a probability in (0, 1), got {a!r}")
        _set(self, "association_gate", a)
        g = self.gate
        if g is False or (not isinstance(g, bool) and isinstance(g, int | float) and g == 0):
            g = None
        if g is not None:
            g = _real(s, "gate", g, None, False, "a probability in (0, 1), or false (or 0) to disable the gate")
            if not 0.0 < g < 1.0:
                raise ConfigError(
                    f"[{s}] gate: expected a probability in (0, 1), or false (or 0) to disable the gate, got {g!r}"
                )
        _set(self, "gate", g)
        _set(self, "horizon", _positive(s, "horizon", self.horizon))
        _set(self, "clock_tolerance", _positive(s, "clock_tolerance", self.clock_tolerance))
        jumps = _integer(s, "clock_jump_inputs", self.clock_jump_inputs, None, 1, "an integer in [1, 100]")
        if jumps > 100:
            raise ConfigError(f"[{s}] clock_jump_inputs: expected an integer in [1, 100], got {jumps!r}")
        _set(self, "clock_jump_inputs", jumps)
        _set(self, "order", _integer(s, "order", self.order, (1, 2), 1, "1 or 2 (an integer)"))
        _set(self, "iterations", _integer(s, "iterations", self.iterations, None, 1, "an integer >= 1"))
        _set(
            self,
            "point_iterations",
            _integer(s, "point_iterations", self.point_iterations, None, 1, "an integer >= 1"),
        )


MAX_RECORD_RATE = 1000.0
"""[Hz] Highest ``[record] rate``: beliefs are recorded to be scored, and no input here comes faster than about
100 Hz (MRCLAM's odometry: 67 Hz), so a faster grid interpolates between the same inputs; 1 kHz leaves a margin."""

MAX_RECORDS = 2_000_000
"""Most beliefs one run records (record times x robots): each costs about 0.75 kB while a run is recorded (measured
with tracemalloc), so at most about 1.5 GB. At 4 Hz that is 5 robots for 28 hours of data."""


@dataclass(frozen=True)
class RecordConfig:
    """``rate`` [Hz] in ``(0, MAX_RECORD_RATE]``: how often beliefs are recorded."""

    SECTION: ClassVar[str] = "record"
    UNITS: ClassVar[dict[str, str]] = {"rate": "[Hz] rate at which beliefs are recorded"}

    rate: float = 4.0

    def __post_init__(self) -> None:
        what = f"a number in (0, {MAX_RECORD_RATE:g}] Hz"
        rate = _real(self.SECTION, "rate", self.rate, 0.0, True, what)
        if rate > MAX_RECORD_RATE:
            raise ConfigError(f"[{self.SECTION}] rate: expected {what} (beliefs are recorded to be scored; no input "
                              f"comes faster than about 100 Hz), got {_describe(self.rate)}")  # fmt: skip
        _set(self, "rate", rate)

    def count(self, t_start: float, t_end: float, robots: int = 1, origin: str = "") -> int:
        """How many record times :meth:`times` gives over ``[t_start, t_end)`` [s], checked before anything is
        allocated: ValueError when the span is not finite, when ``robots`` times that many exceeds
        :data:`MAX_RECORDS`, or when there is nothing to score (no record time after ``t_start``, where the belief
        is the initial one). ``origin`` says where the span comes from, for the message."""
        span = f"[{t_start!r}, {t_end!r}] s{origin}"
        where = f"recording beliefs at [record] rate = {self.rate:g} Hz over {span}"
        if not (math.isfinite(t_start) and math.isfinite(t_end)):
            raise ValueError(f"{where}: the span is not finite")
        step = 1.0 / self.rate
        n = math.ceil((t_end - t_start) / step) if t_end > t_start and math.isfinite(step) else 0
        if n * max(1, robots) > MAX_RECORDS:
            raise ValueError(
                f"{where}: {n:.4g} record times x {robots} robot(s) is more than {MAX_RECORDS} records (the bound on "
                f"a run's memory): lower [record] rate or shorten the span"
            )
        if n < 2:
            fix = "the span is empty"
            if t_end > t_start:
                fix = f"raise [record] rate above {1.0 / (t_end - t_start):.3g} Hz or use a longer span"
            raise ValueError(
                f"{where}: {n} record time(s), none after the start (where the belief is the initial one): nothing to "
                f"score ({fix})"
            )
        return n

    def times(self, t_start: float, t_end: float, robots: int = 1, origin: str = "") -> np.ndarray:
        """Record times [s]: every ``1 / rate`` s over ``[t_start, t_end)``, after :meth:`count` checked them."""
        self.count(t_start, t_end, robots, origin)
        return np.arange(t_start, t_end, 1.0 / self.rate)


@dataclass(frozen=True)
class InitialConfig:
    """Initial-belief std (exponential coordinates, right perturbation), all ``> 0``."""

    SECTION: ClassVar[str] = "initial"
    UNITS: ClassVar[dict[str, str]] = {
        "std_xy": "[m] initial-belief std of x and y",
        "std_theta": "[rad] initial-belief std of the heading",
    }

    std_xy: float = 0.01
    std_theta: float = 0.01

    def __post_init__(self) -> None:
        for f in fields(self):
            _set(self, f.name, _positive(self.SECTION, f.name, getattr(self, f.name)))

    def cov(self) -> np.ndarray:
        """Initial covariance ``diag(std_xy^2, std_xy^2, std_theta^2)``."""
        return np.diag(np.square([self.std_xy, self.std_xy, self.std_theta]))


_SECTIONS: dict[str, type] = {
    "motion": MotionConfig,
    "sensors": SensorConfig,
    "filter": FilterConfig,
    "record": RecordConfig,
    "initial": InitialConfig,
}


def _suggest(name: str, known: list[str]) -> str:
    close = difflib.get_close_matches(name, known, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


@dataclass(frozen=True)
class Config:
    """All settings, one attribute per TOML section. ``Config()`` holds the defaults (:data:`DEFAULTS`)."""

    motion: MotionConfig = field(default_factory=MotionConfig)
    sensors: SensorConfig = field(default_factory=SensorConfig)
    filter: FilterConfig = field(default_factory=FilterConfig)
    record: RecordConfig = field(default_factory=RecordConfig)
    initial: InitialConfig = field(default_factory=InitialConfig)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "<dict>") -> Config:
        """Build from a mapping ``{section: {key: value}}`` (as :func:`tomllib.load` returns); missing sections
        and keys keep their defaults. Raises :class:`ConfigError` prefixed with ``source``."""
        if not isinstance(d, Mapping):
            raise ConfigError(f"{source}: expected a mapping of sections, got {type(d).__name__}")
        known = list(_SECTIONS)
        parts: dict[str, object] = {}
        for name, body in d.items():
            if name not in _SECTIONS:
                if isinstance(body, Mapping):
                    what = f"unknown section [{name}]"
                else:
                    what = f"unknown top-level key {name!r} (every key belongs in a section)"
                raise ConfigError(f"{source}: {what}{_suggest(name, known)}; known sections: {', '.join(known)}")
            if not isinstance(body, Mapping):
                raise ConfigError(f"{source}: {name!r} must be a section [{name}], got {_describe(body)}")
            sec = _SECTIONS[name]
            keys = [f.name for f in fields(sec)]
            for key in body:
                if key not in keys:
                    raise ConfigError(
                        f"{source}: [{name}] unknown key {key!r}{_suggest(key, keys)}; known keys: {', '.join(keys)}"
                    )
            try:
                parts[name] = sec(**body)
            except ConfigError as exc:
                raise ConfigError(f"{source}: {exc}") from None
        return cls(**parts)

    def to_dict(self) -> dict[str, dict[str, object]]:
        """``{section: {key: value}}`` with every key (``gate`` and ``quarantine`` None become False, as in TOML)."""
        out: dict[str, dict[str, object]] = {}
        for name in _SECTIONS:
            sec = getattr(self, name)
            out[name] = {f.name: getattr(sec, f.name) for f in fields(sec)}
        out["filter"]["gate"] = False if self.filter.gate is None else self.filter.gate
        out["filter"]["quarantine"] = False if self.filter.quarantine is None else self.filter.quarantine
        return out

    def to_toml(self) -> str:
        """The configuration as TOML text: every section and key with its value and a unit comment.

        ``tomllib.loads(c.to_toml())`` given to :meth:`from_dict` gives back an equal ``Config``.
        """
        lines = ["# swarmloc configuration (units: metres, radians, seconds)"]
        for name, body in self.to_dict().items():
            units = _SECTIONS[name].UNITS
            lines.append("")
            lines.append(f"[{name}]")
            for key, value in body.items():
                literal = "false" if value is False else f'"{value}"' if isinstance(value, str) else _fmt(value)
                lines.append(f"{key} = {literal}  # {units[key]}")
        return "\n".join(lines) + "\n"

    def replace(self, **sections: object) -> Config:
        """A copy with whole sections replaced, e.g. ``c.replace(filter=FilterConfig(gate=None))``."""
        unknown = sorted(set(sections) - set(_SECTIONS))
        if unknown:
            raise ConfigError(f"Config.replace: unknown section(s) {unknown}; known sections: {', '.join(_SECTIONS)}")
        for name, sec in sections.items():
            if not isinstance(sec, _SECTIONS[name]):
                raise ConfigError(f"Config.replace: section {name!r} must be a {_SECTIONS[name].__name__}")
        return dataclasses.replace(self, **sections)

    def event_defaults(self) -> dict[str, np.ndarray]:
        """Default noise std per record kind for :func:`swarmloc.datasets.eventfile.load_events`: the detection
        kinds from ``[sensors]`` and ``"initial"`` from ``[initial]``."""
        out = self.sensors.detection_defaults()
        out["initial"] = np.array([self.initial.std_xy, self.initial.std_xy, self.initial.std_theta])
        return out


DEFAULTS = Config()
"""The default configuration (the MRCLAM evaluation defaults)."""

_TOML_POS = re.compile(r"\(at line (\d+), column (\d+)\)\s*$")


def load_config(path: str | os.PathLike[str]) -> Config:
    """Read a TOML configuration file; keys it does not set keep their defaults. Raises :class:`ConfigError`."""
    p = Path(path).expanduser()
    label = str(path)
    if not p.is_file():
        raise ConfigError(f"config file not found: {p}" if not p.exists() else f"config path {p} is not a file")
    try:
        with open(p, "rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        m = _TOML_POS.search(msg)
        if m:
            raise ConfigError(
                f"{label} line {m.group(1)}, column {m.group(2)}: TOML syntax error: {msg[: m.start()].rstrip()}"
            ) from None
        raise ConfigError(f"{label}: TOML syntax error: {msg}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{label}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise ConfigError(f"{label}: cannot read file ({exc.strerror or exc})") from None
    return Config.from_dict(data, source=label)
