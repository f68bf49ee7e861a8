"""Configuration of the models and the filter, read from a TOML file (standard library :mod:`tomllib`).

Five sections, one class each: ``[motion]`` (:class:`MotionConfig`), ``[sensors]`` (:class:`SensorConfig`),
``[filter]`` (:class:`FilterConfig`), ``[record]`` (:class:`RecordConfig`) and ``[initial]`` (:class:`InitialConfig`).
Every key is optional: a key that a file does not set keeps its default (the MRCLAM evaluation defaults of
:mod:`swarmloc.experiments.mrclam`); every key with its default, unit, range and meaning is listed by
``swarmloc config --defaults`` and in the documentation's page :doc:`/configuration`. For example::

    [filter]
    gate = 0.99     # probability of the innovation gate (false: no gate)
    horizon = 3.0   # [s]

    [record]
    rate = 10       # [Hz]

Each key is declared once, as a field of its section's class: its type and range (``Annotated`` with
:class:`msgspec.Meta`), its default, and below it a docstring with its unit in brackets and its meaning. From that
declaration come the check (:func:`load_config`, :meth:`Config.from_dict` and every direct construction, e.g.
``FilterConfig(gate=2.0)`` raises), the listing of every key with its default, unit and meaning that
``swarmloc config --defaults`` prints (:meth:`Config.to_toml`), and the documentation's table of the keys
(:func:`config_markdown`).

Rules that hold for every key: a number must be finite, and a TOML integer is taken where a real number is declared;
a key whose type admits None (``gate``, ``quarantine``) is turned off with ``false`` or ``0`` (TOML has no null).
Units: metres, radians, seconds. Every problem raises :class:`ConfigError` (a ``ValueError``) naming the file, the
``[section] key`` and what was expected; a TOML syntax error names the file, line and column.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import os
import re
import tomllib
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

import msgspec
import numpy as np

from swarmloc.declared import attribute_docs, markdown_table
from swarmloc.kernels.group import FUSE_ITERATIONS, POINT_ITERATIONS
from swarmloc.motion.unicycle import UnicycleNoise
from swarmloc.sensors.decorrelate import PRIOR_BEARING_STD, PRIOR_RANGE_STD

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
    "Section",
    "SensorConfig",
    "config_markdown",
    "load_config",
]


class ConfigError(ValueError):
    """A problem with a configuration: unknown section or key, wrong type, value out of range, TOML syntax."""


# ----------------------------------------------------------------------------------------------------------------
# the types of the keys, and their check (run in __post_init__, so direct construction is checked too)

Nonneg = Annotated[float, msgspec.Meta(ge=0)]
"""A finite real number ``>= 0``."""
Positive = Annotated[float, msgspec.Meta(gt=0)]
"""A finite real number ``> 0``."""
Probability = Annotated[float, msgspec.Meta(gt=0, lt=1, title="probability")]
"""A probability in ``(0, 1)``."""
Count = Annotated[int, msgspec.Meta(ge=1)]
"""An integer ``>= 1``."""

MAX_RECORD_RATE = 1000.0
"""[Hz] Highest ``[record] rate``: beliefs are recorded to be scored, and no input here comes faster than about
100 Hz (MRCLAM's odometry: 67 Hz), so a faster grid interpolates between the same inputs; 1 kHz leaves a margin."""

MAX_RECORDS = 2_000_000
"""Most beliefs one run records (record times x robots): each costs about 0.75 kB while a run is recorded (measured
with tracemalloc), so at most about 1.5 GB. At 4 Hz that is 5 robots for 28 hours of data."""


def _describe(value: object) -> str:
    if isinstance(value, bool):
        return f"a boolean ({str(value).lower()})"
    if isinstance(value, str):
        return f"a string ({value!r})"
    if isinstance(value, int | float):
        return repr(value)
    return f"a {type(value).__name__} ({value!r})"


def _optional(tp: Any) -> tuple[Any, bool]:
    """``(X, True)`` for a declared ``X | None``, else ``(tp, False)``."""
    args = typing.get_args(tp)
    if typing.get_origin(tp) in (typing.Union, types.UnionType) and type(None) in args:
        return next(a for a in args if a is not type(None)), True
    return tp, False


def _words(tp: Any, unit: str) -> str:
    """What a value of a declared type is, in words: ``a finite number > 0``, ``an integer in [1, 100]``,
    ``a number in (0, 1000] Hz``, ``1 or 2 (an integer)``, ``one of "a", "b"``, ``true or false``; a union's in turn."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return " or ".join(_words(a, unit) for a in typing.get_args(tp))
    if typing.get_origin(tp) is Literal:
        args = typing.get_args(tp)
        if all(isinstance(a, str) for a in args):
            return "one of " + ", ".join(f'"{a}"' for a in args)
        return " or ".join(map(str, args)) + " (an integer)"
    if tp is bool:
        return "true or false"
    kind, meta = typing.get_args(tp)[:2] if typing.get_origin(tp) is Annotated else (tp, msgspec.Meta())
    noun = "an integer" if kind is int else f"a {meta.title or 'number'}"
    lo, hi = (meta.gt, meta.ge), (meta.lt, meta.le)
    if any(v is not None for v in lo) and any(v is not None for v in hi):
        left = f"({meta.gt:g}" if meta.gt is not None else f"[{meta.ge:g}"
        right = f"{meta.lt:g})" if meta.lt is not None else f"{meta.le:g}]"
        return f"{noun} in {left}, {right}" + (f" {unit}" if unit else "")
    noun = noun if kind is int else f"a finite {meta.title or 'number'}"
    marks = [f"{op} {v:g}" for op, v in zip((">", ">=", "<", "<="), (*lo, *hi), strict=True) if v is not None]
    return " ".join([noun, *marks])


def _expected(tp: Any, unit: str = "") -> str:
    """What a key of declared type ``tp`` takes, in words (the error messages' and the table's)."""
    base, optional = _optional(tp)
    return _words(base, unit) + (", or false (or 0) to turn it off" if optional else "")


def _unit(doc: str) -> tuple[str, str]:
    """``(unit, meaning)`` of a key's docstring ``"[unit] meaning"`` (unit ``""`` where it has none)."""
    m = re.match(r"\[([^\]]*)\]\s*", doc)
    return (m.group(1), doc[m.end() :]) if m else ("", doc)


def _off(value: object, tp: Any) -> bool:
    """Whether ``value`` turns an optional key off: None, false, or a zero of the key's type."""
    if value is None or value is False:
        return True
    kind = typing.get_args(tp)[0] if typing.get_origin(tp) is Annotated else tp
    try:
        return bool(msgspec.convert(value, kind) == 0)
    except msgspec.ValidationError:
        return False


def _checked(cls: type[Section], key: str, tp: Any, value: object) -> Any:
    """``value`` as the declared type ``tp`` (a numpy scalar as Python's, a TOML integer as a float where a float is
    declared, an optional key's off value as None), or ConfigError naming ``[section] key``."""
    base, optional = _optional(tp)
    plain = value.item() if isinstance(value, np.generic) else value
    if optional and _off(plain, base):
        return None
    try:
        out = msgspec.convert(plain, base)
        if not isinstance(out, float) or math.isfinite(out):
            return out
    except msgspec.ValidationError:
        pass
    unit, meaning = _unit(attribute_docs(cls).get(key, ""))
    what = f"[{cls.SECTION}] {key}: expected {_expected(tp, unit)}, got {_describe(plain)}"
    raise ConfigError(f"{what} ({meaning})" if meaning else what)


_TYPES: dict[type, dict[str, Any]] = {}


def _types(cls: type) -> dict[str, Any]:
    """``{key: declared type}`` of a section, in declaration order (resolved once per class)."""
    if cls not in _TYPES:
        hints = typing.get_type_hints(cls, include_extras=True)
        _TYPES[cls] = {f.name: hints[f.name] for f in fields(cls)}
    return _TYPES[cls]


Scalar = bool | int | float | str
"""A key's value (an optional key that is off, None, is False in TOML and in :meth:`Config.to_dict`)."""

Association = Literal["tags", "nearest", "joint", "anonymous"]
"""How robot detections get their identities (``[filter] association``)."""

NODE_ASSOCIATION: dict[str, str] = {"tags": "tags", "nearest": "nearest", "joint": "joint", "anonymous": "joint"}
"""The association a node runs under each policy: ``anonymous`` hands the nodes tagged relative poses and the
detections PMR could not register (no mutual counterpart), which they assign with ``joint`` against their beliefs."""


def _literal(value: Scalar) -> str:
    """Exact TOML literal: booleans, quoted strings, integers as integers, floats as Python's shortest repr."""
    if isinstance(value, bool | str):
        return json.dumps(value)
    return str(value) if isinstance(value, int) else repr(float(value))


class Section:
    """Base of the sections: each key is a dataclass field of the subclass, checked against its declared type on
    construction (:meth:`__post_init__`), so a file, :meth:`Config.from_dict`, a direct construction and
    :func:`dataclasses.replace` are checked alike. ``SECTION`` is the section's TOML name."""

    SECTION: ClassVar[str]

    def __post_init__(self) -> None:
        for key, tp in _types(type(self)).items():
            object.__setattr__(self, key, _checked(type(self), key, tp, getattr(self, key)))


# ----------------------------------------------------------------------------------------------------------------
# sections: one field per key (type, range, default), its docstring "[unit] meaning" below it


@dataclass(frozen=True)
class MotionConfig(Section):
    """Coefficients of the unicycle body-twist diffusion, per second (see :mod:`swarmloc.motion.unicycle`)."""

    SECTION: ClassVar[str] = "motion"

    q_v0: Nonneg = 1e-4
    """[m^2/s] forward diffusion floor: q_fwd = q_v0 + q_v1 abs(v) + q_v2 v^2"""
    q_v1: Nonneg = 0.0
    """[m] forward diffusion per metre travelled"""
    q_v2: Nonneg = 0.05
    """[s] forward diffusion per speed squared (relative speed error)"""
    q_lat0: Nonneg = 1e-4
    """[m^2/s] lateral diffusion floor: q_lat = q_lat0 + q_lat1 abs(v)"""
    q_lat1: Nonneg = 0.01
    """[m] lateral diffusion per metre travelled"""
    q_w0: Nonneg = 1e-3
    """[rad^2/s] yaw diffusion floor: q_yaw = q_w0 + q_w1 abs(w) + q_w2 w^2 + q_wv abs(v)"""
    q_w1: Nonneg = 0.0
    """[rad] yaw diffusion per radian turned"""
    q_w2: Nonneg = 0.05
    """[s] yaw diffusion per yaw rate squared"""
    q_wv: Nonneg = 0.02
    """[rad^2/m] yaw diffusion per metre travelled"""

    def noise(self) -> UnicycleNoise:
        """The :class:`~swarmloc.motion.unicycle.UnicycleNoise` with these coefficients."""
        return UnicycleNoise(**{f.name: getattr(self, f.name) for f in fields(self)})

    @classmethod
    def from_noise(cls, noise: UnicycleNoise) -> MotionConfig:
        """The section holding the coefficients of ``noise``."""
        return cls(**{name: getattr(noise, name) for name in UnicycleNoise.__slots__})


@dataclass(frozen=True)
class SensorConfig(Section):
    """Noise standard deviations used when a detection carries none, and the model of MRCLAM's camera.

    ``pose_*`` are the std of the exponential coordinates of a relative-pose measurement's noise; ``absolute_*``
    those of an absolute fix of the observer's own pose. ``decorrelate`` says how MRCLAM's time-correlated camera
    errors are modelled (:mod:`swarmloc.sensors.decorrelate`): ``"calibrate"``, std and correlation estimated from
    the dataset's own landmark detections and map (no ground truth), each detection weighted by its share of the
    information of its (observer, target) stream; ``"weights"``, the same weighting with ``range_std`` and
    ``bearing_std`` as the std; ``"off"``, white noise with them (the former model used ``range_std = 0.3``, a
    white-noise inflation calibrated on dataset 6's truth). ``range_std`` and ``bearing_std`` are a priori (the
    camera's spec, 2 degrees of bearing), not fitted to any ground truth.
    """

    SECTION: ClassVar[str] = "sensors"

    range_std: Positive = PRIOR_RANGE_STD
    """[m] range std"""
    bearing_std: Positive = PRIOR_BEARING_STD
    """[rad] bearing std"""
    pose_xy_std: Positive = 0.05
    """[m] relative pose: x and y std (exponential coordinates)"""
    pose_theta_std: Positive = 0.0175
    """[rad] relative pose: heading std"""
    absolute_xy_std: Positive = 0.01
    """[m] absolute fix: x and y std"""
    absolute_theta_std: Positive = 0.01
    """[rad] absolute fix: heading std"""
    decorrelate: Literal["calibrate", "weights", "off"] = "calibrate"
    """MRCLAM camera: calibrate (estimated std and correlation), weights (given std), or off (white noise)"""

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
class FilterConfig(Section):
    """Filter settings: innovation gate, out-of-order horizon, the node's clock contract
    (:mod:`swarmloc.node.clock`), convolution order, iteration counts, association of robot detections
    (:mod:`swarmloc.experiments.association`), the fixed-lag smoothers' window and delayed output
    (:mod:`swarmloc.evaluation.delayed`), ``diekf``'s clusters (:mod:`swarmloc.estimators.diekf`) and the quarantine of
    a teammate whose updates are refused (:mod:`swarmloc.node.trust`). ``gate`` and ``quarantine`` are None when off.
    """

    SECTION: ClassVar[str] = "filter"

    gate: Probability | None = 0.997
    """chi-square probability of the innovation gate on the normalized innovation squared"""
    horizon: Positive = 5.0
    """[s] how far back out-of-order input is replayed"""
    clock_tolerance: Positive = 5.0
    """[s] how far past a node's present an input may be stamped (capped at horizon)"""
    clock_jump_inputs: Annotated[int, msgspec.Meta(ge=1, le=100)] = 3
    """inputs in a row, at distinct stamps, that confirm a jump of a robot's clock"""
    order: Literal[1, 2] = 2
    """order of the SE(2) convolution"""
    iterations: Count = FUSE_ITERATIONS
    """iterations of the iterated update"""
    point_iterations: Count = POINT_ITERATIONS
    """iterations of a point (landmark) update"""
    association: Association = "tags"
    """robot detections' identities: tags (given), nearest or joint (chosen from the beliefs, ids hidden), anonymous
    (PMR and a particle-filter bank, ids hidden)"""
    association_gate: Probability = 0.99
    """chi-square probability of the association gate"""
    smoother_lag: Positive = 2.0
    """[s] window of the fixed-lag smoothers fls and flsd"""
    delayed_output: bool = False
    """fls and flsd also output each pose as it leaves the window (smoother_lag s late), scored as <name>_delayed"""
    diekf_cluster: Annotated[int, msgspec.Meta(ge=0)] = 0
    """robots per diekf cluster (0: the exact filter over the whole team)"""
    diekf_reform: Annotated[float, msgspec.Meta(ge=0)] = 0.0
    """[s] period at which diekf's clusters re-form from whom the robots saw (0: fixed clusters; needs diekf_cluster
    and a recording)"""
    diekf_adaptive: bool | Literal["median"] = "median"
    """diekf and flsd scale their process noise online from their own innovations (swarmloc.estimators.adaptive_noise):
    "median" (median matching after dead reckoning, down to 0.003, only while they fuse landmarks), true (covariance
    matching, only up) or false (the noise as configured)"""
    diekf_odocal: bool = False
    """diekf calibrates each robot's odometry scale and yaw-rate bias online, truth-free (swarmloc.motion.odocal)"""
    diekf_fault: bool = False
    """diekf detects a robot's odometry fault from its mutual detections and inflates its covariance, truth-free
    (swarmloc.estimators.odometry_fault)"""
    quarantine: Count | None = 3
    """a teammate's updates refused in a row (each beyond the gate) that quarantine it for the run"""


@dataclass(frozen=True)
class RecordConfig(Section):
    """How often beliefs are recorded (to be scored), and the bound on a run's records (:data:`MAX_RECORDS`)."""

    SECTION: ClassVar[str] = "record"

    rate: Annotated[float, msgspec.Meta(gt=0, le=MAX_RECORD_RATE)] = 4.0
    """[Hz] rate at which beliefs are recorded (no input comes faster than about 100 Hz)"""

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
class InitialConfig(Section):
    """Initial-belief std (exponential coordinates, right perturbation) where a source gives none."""

    SECTION: ClassVar[str] = "initial"

    std_xy: Positive = 0.01
    """[m] initial-belief std of x and y"""
    std_theta: Positive = 0.01
    """[rad] initial-belief std of the heading"""

    def cov(self) -> np.ndarray:
        """Initial covariance ``diag(std_xy^2, std_xy^2, std_theta^2)``."""
        return np.diag(np.square([self.std_xy, self.std_xy, self.std_theta]))


_SECTIONS: dict[str, type] = {
    cls.SECTION: cls for cls in (MotionConfig, SensorConfig, FilterConfig, RecordConfig, InitialConfig)
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
        parts: dict[str, Any] = {}
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
            keys = list(_types(sec))
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

    def to_dict(self) -> dict[str, dict[str, Scalar]]:
        """``{section: {key: value}}`` with every key (an optional key that is off, None, becomes False, as in TOML)."""
        out: dict[str, dict[str, Scalar]] = {}
        for name in _SECTIONS:
            sec = getattr(self, name)
            out[name] = {key: False if getattr(sec, key) is None else getattr(sec, key) for key in _types(type(sec))}
        return out

    def to_toml(self) -> str:
        """The configuration as TOML text: every section and key with its value, and its unit and meaning as a comment.

        ``tomllib.loads(c.to_toml())`` given to :meth:`from_dict` gives back an equal ``Config``.
        """
        lines = ["# swarmloc configuration (units: metres, radians, seconds)"]
        for name, body in self.to_dict().items():
            docs, types_ = attribute_docs(_SECTIONS[name]), _types(_SECTIONS[name])
            lines += ["", f"[{name}]"]
            for key, value in body.items():
                unit, meaning = _unit(docs.get(key, ""))
                note = "; ".join(x for x in (f"[{unit}] {meaning}" if unit else meaning, _expected(types_[key])) if x)
                lines.append(f"{key} = {_literal(value)}  # {note}")
        return "\n".join(lines) + "\n"

    def replace(self, **sections: Any) -> Config:
        """A copy with whole sections replaced, e.g. ``c.replace(filter=FilterConfig(gate=None))``."""
        unknown = sorted(set(sections) - set(_SECTIONS))
        if unknown:
            raise ConfigError(f"Config.replace: unknown section(s) {unknown}; known sections: {', '.join(_SECTIONS)}")
        for name, sec in sections.items():
            if not isinstance(sec, _SECTIONS[name]):
                raise ConfigError(f"Config.replace: section {name!r} must be a {_SECTIONS[name].__name__}")
        return dataclasses.replace(self, **sections)

    def with_filter(self, **keys: Any) -> Config:
        """A copy with these ``[filter]`` keys changed (checked as a file's are), e.g. ``c.with_filter(gate=None)``."""
        return dataclasses.replace(self, filter=dataclasses.replace(self.filter, **keys))

    def event_defaults(self) -> dict[str, np.ndarray]:
        """Default noise std per record kind for :func:`swarmloc.datasets.eventfile.load_events`: the detection
        kinds from ``[sensors]`` and ``"initial"`` from ``[initial]``."""
        out = self.sensors.detection_defaults()
        out["initial"] = np.array([self.initial.std_xy, self.initial.std_xy, self.initial.std_theta])
        return out


DEFAULTS = Config()
"""The default configuration (the MRCLAM evaluation defaults)."""


def config_markdown() -> str:
    """Every key of every section with what it takes, its default, unit and meaning: one Markdown table per section,
    the documentation's reference of the keys."""
    out = []
    for name, body in DEFAULTS.to_dict().items():
        docs, types_ = attribute_docs(_SECTIONS[name]), _types(_SECTIONS[name])
        rows = [(f"`{key}`", _expected(types_[key]), f"`{_literal(value)}`", *_unit(docs.get(key, "")))
                for key, value in body.items()]  # fmt: skip
        out.append(f"### `[{name}]`\n\n" + markdown_table(("key", "takes", "default", "unit", "meaning"), rows))
    return "\n".join(out)


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
