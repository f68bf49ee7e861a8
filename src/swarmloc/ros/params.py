"""The ROS node's parameters, declared once: names, types, constraints, defaults, units and meaning in
:class:`RosParams`, from which the check, ``swarmloc ros params`` (the defaults as a ``ros__parameters`` YAML) and the
documentation's table are made.

Read as ``rcl`` reads parameters (ROS 2 design article "ROS 2 parameters", and robot_localization's params files):
a YAML file of ``<node name>: {ros__parameters: {...}}`` sections, where ``<node name>`` is the node's name, its
fully qualified name (``/robot1/swarmloc``), or a wildcard (``/**``, ``/robot*/swarmloc``); nested maps are the
dotted parameter names (``motion: {q_v0: 1e-4}`` is ``motion.q_v0``). Files apply in order, then every
``-p NAME:=VALUE``. A wrong name, type or value is a :class:`ParamsError` naming the parameter and the file.
"""

from __future__ import annotations

import fnmatch
import math
import os
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec

from swarmloc.config import Config, ConfigError
from swarmloc.declared import attribute_docs, markdown_table
from swarmloc.net.settings import MAX_ROS_DOMAIN

Hz = Annotated[float, msgspec.Meta(gt=0, le=1000)]
Seconds = Annotated[float, msgspec.Meta(ge=0, le=3600)]
RobotId = Annotated[int, msgspec.Meta(ge=0, lt=2**31)]
Frame = Annotated[str, msgspec.Meta(min_length=1, max_length=256, pattern=r"^[A-Za-z0-9_/.\-]+$")]
Topic = Annotated[str, msgspec.Meta(min_length=1, max_length=256)]
Estimator = Literal["diekf", "rdl", "irdl", "dekf", "ci", "expfusion", "dr"]

MAX_PARAMS_BYTES = 1 << 20
"""[bytes] the largest params file read."""


class RosParams(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Every parameter of ``swarmloc ros`` (units: metres, radians, seconds). Each field's comment is its help."""

    robot_id: RobotId = msgspec.field(default=0)
    """This robot's id in the team (``robot<id>`` names it in detections)."""
    team: Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_\-]{1,64}$")] = "swarmloc"
    """The team's name: part of every key of the team's own network."""
    team_robots: list[RobotId] = msgspec.field(default_factory=list)
    """Every robot id of the team (this one included; empty: this robot alone)."""
    estimator: Estimator = "diekf"
    """The distributed estimator (one node per robot); diekf: the exact distributed invariant EKF."""
    frequency: Hz = 10.0
    """[Hz] rate of the outputs (Odometry, pose, TF), on ROS time from the first odometry."""
    window: Annotated[float, msgspec.Meta(ge=0, le=10)] = 0.25
    """[s] reorder slack: an input stamped more than this before ROS time is late (refused, counted)."""
    world_frame: Frame = "map"
    """Frame of the estimate (robot_localization's world_frame): the map frame."""
    odom_frame: Frame = "odom"
    """The robot's odometry frame (the parent of base_link in the odometry messages)."""
    base_link_frame: Frame = "base_link"
    """The robot's body frame (child frame of the output Odometry)."""
    publish_tf: bool = True
    """Publish the world_frame -> odom_frame transform on /tf at each output."""
    use_sim_time: bool = False
    """Take ROS time from /clock instead of the system clock."""
    initial_state: Annotated[list[float], msgspec.Meta(min_length=3, max_length=3)] = msgspec.field(
        default_factory=lambda: [0.0, 0.0, 0.0]
    )
    """[m, m, rad] the robot's pose (x, y, yaw) in world_frame at its first odometry."""
    initial_covariance: Annotated[list[float], msgspec.Meta(min_length=3, max_length=9)] = msgspec.field(
        default_factory=lambda: [1e-4, 1e-4, 1e-4]
    )
    """[m^2, m^2, rad^2] its covariance: 3 variances (x, y, yaw) or a 3x3 matrix row-major (9 numbers)."""
    odom_topic: Topic = "odom"
    """Input nav_msgs/Odometry: the robot's wheel odometry (twist used: forward speed, yaw rate)."""
    detections_topic: Topic = "detections"
    """Input vision_msgs/Detection3DArray: teammates (class id robot<N>) and landmarks (landmark<N>) seen."""
    initialpose_topic: Topic = "initialpose"
    """Input geometry_msgs/PoseWithCovarianceStamped: sets the robot's pose (RViz's "2D Pose Estimate")."""
    odometry_topic: Topic = "odometry/filtered"
    """Output nav_msgs/Odometry: the estimate in world_frame, child base_link_frame."""
    pose_topic: Topic = "pose"
    """Output geometry_msgs/PoseWithCovarianceStamped: the same pose and covariance."""
    diagnostics_topic: Topic = "/diagnostics"
    """Output diagnostic_msgs/DiagnosticArray: inputs fused, gated, rejected, unknown; teammates; refusals."""
    diagnostics_period: Annotated[float, msgspec.Meta(gt=0, le=3600)] = 1.0
    """[s] wall time between diagnostics."""
    sensor_mounts: dict[str, Annotated[list[float], msgspec.Meta(min_length=3, max_length=3)]] = msgspec.field(
        default_factory=dict
    )
    """Sensor frame -> [x, y, yaw] of the sensor in base_link_frame (a frame not given is base_link itself)."""
    unused_variance: Annotated[float, msgspec.Meta(ge=0, le=1e12)] = 0.0
    """[m^2, rad^2] variance written for z, roll and pitch of the outputs (0: planar, as nav2's amcl)."""
    middleware: Literal["cyclonedds", "zenoh"] = "cyclonedds"
    """ROS 2 middleware spoken: DDS (cyclonedds, as a stock rmw_cyclonedds_cpp or rmw_fastrtps_cpp robot) or
    rmw_zenoh's layout on Zenoh."""
    domain_id: Annotated[int, msgspec.Meta(ge=0, le=MAX_ROS_DOMAIN)] = 0
    """ROS_DOMAIN_ID of the robot's ROS graph (default: the environment's ROS_DOMAIN_ID, else 0)."""
    discovery_range: Literal["localhost", "subnet"] = "localhost"
    """Where ROS inputs may come from: this host only (inputs cannot be written from elsewhere) or the subnet."""
    ros_endpoints: list[Annotated[str, msgspec.Meta(max_length=256)]] = msgspec.field(default_factory=list)
    """middleware zenoh: the router or peers of the robot's ROS graph (default: rmw_zenoh's tcp/127.0.0.1:7447)."""
    team_listen: list[Annotated[str, msgspec.Meta(max_length=256)]] = msgspec.field(default_factory=list)
    """Zenoh endpoints this node listens on for its teammates (tcp/HOST:PORT)."""
    team_connect: list[Annotated[str, msgspec.Meta(max_length=256)]] = msgspec.field(default_factory=list)
    """Zenoh endpoints of the teammates (or of routers)."""
    key_file: str = ""
    """This robot's private key (swarmloc keys); with roster_file every team message is signed."""
    roster_file: str = ""
    """The team's roster (members' public keys)."""
    no_auth: bool = False
    """Team messages unsigned (a trusted network only); needs neither key_file nor roster_file."""
    run_id: Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_\-]{0,64}$")] = ""
    """This run's id in every team key (empty: none)."""
    start_timeout: Seconds = 30.0
    """[s] wall time to wait for the teammates to be up before reading inputs."""
    motion: dict[str, Any] = msgspec.field(default_factory=dict)
    """The unicycle process noise, as the [motion] section of swarmloc's configuration (q_v0, q_w0, ...)."""
    sensors: dict[str, Any] = msgspec.field(default_factory=dict)
    """Default detection noise, as [sensors] (used for a detection without covariance)."""
    filter: dict[str, Any] = msgspec.field(default_factory=dict)
    """Filter settings, as [filter] (gate, horizon, ...)."""
    landmarks: dict[str, Annotated[list[float], msgspec.Meta(min_length=2, max_length=4)]] = msgspec.field(
        default_factory=dict
    )
    """Known landmarks: landmark<N> -> [x, y] or [x, y, std_x, std_y] in world_frame."""

    @property
    def team_ids(self) -> list[int]:
        """The roster: :attr:`team_robots` with this robot (sorted)."""
        return sorted(set(self.team_robots) | {self.robot_id})

    def config(self) -> Config:
        """The models' :class:`~swarmloc.config.Config` from ``motion``, ``sensors`` and ``filter``."""
        parts = {k: v for k, v in (("motion", self.motion), ("sensors", self.sensors), ("filter", self.filter)) if v}
        try:
            return Config.from_dict(parts, source="parameters")
        except ConfigError as exc:
            raise ParamsError(str(exc)) from None

    def landmark_table(self) -> dict[int, tuple[float, float, float, float]] | None:
        """``id -> (x, y, std_x, std_y)`` of :attr:`landmarks` (std 0 where not given), None without any."""
        out = {}
        for name, v in self.landmarks.items():
            if not (name.startswith("landmark") and name[8:].isdigit()):
                raise ParamsError(f"landmarks: {name!r} is not landmark<N>")
            x, y, sx, sy = (*v, 0.0, 0.0)[:4]
            out[int(name[8:])] = (float(x), float(y), float(sx), float(sy))
        return out or None


class ParamsError(ValueError):
    """A parameter that is unknown, of the wrong type or out of range (the message names it and where from)."""


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict) and name.split(".")[0] not in _MAPS:
            out.update(_flatten(v, name + "."))
        else:
            out[name] = v
    return out


_MAPS = ("sensor_mounts", "landmarks")  # parameters whose values are maps (their keys are frames or names)
_SECTIONS = ("motion", "sensors", "filter")


def _nest(flat: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, v in flat.items():
        head, _, rest = name.partition(".")
        if rest and (head in _SECTIONS or head in _MAPS):
            out.setdefault(head, {})
            if not isinstance(out[head], dict):
                raise ParamsError(f"{name}: {head} is a map, not a value")
            out[head][rest] = v
        else:
            out[name] = v
    return out


def _matches(key: str, node: str, fqn: str) -> bool:
    key = key.strip()
    if key in ("/**", "**", node, fqn, fqn.lstrip("/")):
        return True
    pattern = key if key.startswith("/") else "/" + key
    return fnmatch.fnmatchcase(fqn, pattern.replace("**", "*"))


def read_params_file(path: str | os.PathLike[str], node: str, fqn: str) -> dict[str, Any]:
    """The flat parameters (dotted names) of every section of ``path`` that matches the node."""
    import yaml

    p = Path(path)
    try:
        if p.stat().st_size > MAX_PARAMS_BYTES:
            raise ParamsError(f"{path}: larger than {MAX_PARAMS_BYTES} bytes")
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ParamsError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:  # PyYAML's message spans lines (with a caret): one line
        why = " ".join(str(exc).replace(" ^", " ").split()).rstrip(": ")
        raise ParamsError(f"{path}: not a YAML file: {why}") from None
    if not isinstance(data, dict):
        raise ParamsError(f"{path}: expected '<node name>: {{ros__parameters: {{...}}}}' sections")
    out: dict[str, Any] = {}
    for key, body in data.items():
        if not isinstance(body, dict) or "ros__parameters" not in body:
            raise ParamsError(f"{path}: section {key!r} has no 'ros__parameters'")
        if _matches(str(key), node, fqn):
            params = body["ros__parameters"]
            if not isinstance(params, dict):
                raise ParamsError(f"{path}: {key}.ros__parameters must be a map")
            out.update(_flatten(params))
    return out


def load_params(files: list[str], overrides: dict[str, Any], node: str = "swarmloc", namespace: str = "/") -> RosParams:
    """The node's :class:`RosParams` from ``files`` (in order) then ``overrides`` (``-p NAME:=VALUE``)."""
    fqn = f"{namespace.rstrip('/')}/{node}"
    flat: dict[str, Any] = {}
    where: dict[str, str] = {}
    for f in files:
        got = read_params_file(f, node, fqn)
        flat.update(got)
        where.update(dict.fromkeys(got, str(f)))
    flat.update(overrides)
    where.update(dict.fromkeys(overrides, "-p"))
    if "domain_id" not in flat and os.environ.get("ROS_DOMAIN_ID", "").strip():
        flat["domain_id"] = os.environ["ROS_DOMAIN_ID"].strip()
        where["domain_id"] = "ROS_DOMAIN_ID"
    nested = _nest(flat)
    try:
        params = msgspec.convert(nested, RosParams, strict=False)
    except msgspec.ValidationError as exc:
        raise ParamsError(_explain(str(exc), where)) from None
    _check(params)
    return params


def _explain(msg: str, where: dict[str, str]) -> str:
    """msgspec's message with the parameter's name and where it was set."""
    import re

    hit = re.search(r"at `\$\.([A-Za-z0-9_]+)(?:\.|\[|`)", msg)
    if hit is None and "unknown field" in msg:
        field = re.search(r"`([^`]+)`", msg)
        known = ", ".join(f.name for f in msgspec.structs.fields(RosParams))
        return f"unknown parameter {field.group(1) if field else '?'} (known: {known})"
    name = hit.group(1) if hit else "?"
    src = where.get(name) or next((v for k, v in where.items() if k.startswith(name + ".")), "")
    return f"parameter {name}{f' ({src})' if src else ''}: {msg}"


def _check(p: RosParams) -> None:
    """What the declaration cannot say: finite numbers, a valid covariance, known frames."""
    nums = [*p.initial_state, *p.initial_covariance, *(x for v in p.sensor_mounts.values() for x in v)]
    if not all(math.isfinite(x) for x in nums):
        raise ParamsError("initial_state, initial_covariance and sensor_mounts must be finite numbers")
    if len(p.initial_covariance) not in (3, 9):
        raise ParamsError(f"initial_covariance: 3 variances or 9 numbers (3x3), got {len(p.initial_covariance)}")
    if not p.no_auth and bool(p.key_file) != bool(p.roster_file):
        raise ParamsError("key_file and roster_file go together (or no_auth: true on a trusted network)")
    p.config()
    p.landmark_table()


def defaults_yaml(node: str = "swarmloc") -> str:
    """Every parameter with its default, as a ``ros__parameters`` YAML with each one's meaning as a comment."""
    import json

    lines = [f"{node}:", "  ros__parameters:"]
    for f, value, doc in _fields():
        lines.append(f"    # {doc}")
        lines.append(f"    {f.name}: {json.dumps(value)}")  # JSON is YAML's flow style
    return "\n".join(lines) + "\n"


def _fields() -> list[tuple[Any, Any, str]]:
    """``(field, default value, attribute docstring)`` of every parameter of :class:`RosParams`, in field order."""
    docs = attribute_docs(RosParams)
    return [(f, f.default if f.default is not msgspec.NODEFAULT else f.default_factory(), docs.get(f.name, ""))
            for f in msgspec.structs.fields(RosParams)]  # fmt: skip


def params_markdown() -> str:
    """Every parameter as a Markdown table (name, type and range, default, meaning): the documentation's table."""
    import json
    import typing

    rows = [(f"`{f.name}`", _type_text(f.type, typing), f"`{json.dumps(value)}`", doc) for f, value, doc in _fields()]
    return markdown_table(("parameter", "type", "default", "meaning"), rows)


def _type_text(tp: Any, typing: Any) -> str:
    """``float, > 0, <= 1000`` / ``list of float (3)`` / one of the literals."""
    if typing.get_origin(tp) is Annotated:
        base, *meta = typing.get_args(tp)
        marks = []
        for m in meta:
            for key, sym in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
                v = getattr(m, key, None)
                if v is not None:
                    marks.append(f"{sym} {v if isinstance(v, int) else format(v, 'g')}")
            if getattr(m, "min_length", None) is not None and m.min_length == m.max_length:
                marks.append(f"{m.min_length} items")
            elif getattr(m, "max_length", None) is not None and typing.get_origin(base) is list:
                marks.append(f"{m.min_length or 0}-{m.max_length} items")
        return ", ".join([_type_text(base, typing), *marks])
    if typing.get_origin(tp) is Literal:
        return " / ".join(f"`{a}`" for a in typing.get_args(tp))
    if typing.get_origin(tp) in (list, dict):
        return f"{typing.get_origin(tp).__name__} of {_type_text(typing.get_args(tp)[-1], typing)}"
    return "map" if tp is Any else getattr(tp, "__name__", str(tp))
