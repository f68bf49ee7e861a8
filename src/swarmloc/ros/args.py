"""ROS 2 command-line arguments and names, as ``rcl`` reads them: ``--ros-args`` with remapping, parameters and
parameter files, and the expansion of relative and private names.

Rules followed (ROS 2 design articles "Topic and Service names" and "Remapping Names", and ``rcl``'s
``arguments.c``):

* **Arguments.** Everything after ``--ros-args`` up to ``--`` (or the end) is ROS's: ``-r``/``--remap FROM:=TO``
  (``NODE:FROM:=TO`` for one node only), ``-p``/``--param NAME:=VALUE`` (the value read as YAML, as rcl does),
  ``--params-file FILE``, and the special remaps ``__ns:=/NAMESPACE`` and ``__node:=NAME`` (``__name`` too).
* **Names.** A name is ``/``-separated tokens of letters, digits and ``_``; a token does not start with a digit,
  there are no repeated ``/`` or ``_``, no trailing ``/``; ``~`` (alone or as ``~/...``) is the node's private
  namespace. :func:`expand` makes a name fully qualified: absolute names stay, ``~`` becomes
  ``<namespace>/<node>``, a relative name is put under the namespace.
* **Remapping.** A rule's ``FROM`` and ``TO`` are expanded like any name of the node; a topic whose fully
  qualified name equals a rule's ``FROM`` takes its ``TO`` (the first matching rule wins: rcl's order).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

_NODE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class RosArgsError(ValueError):
    """A malformed ROS argument or name (the message names it)."""


def check_name(name: str, what: str = "name") -> str:
    """``name`` if it is a valid ROS 2 name (absolute, relative or private; module docstring), else
    :class:`RosArgsError` saying why. The token rules are :mod:`swarmloc.rmw.names`' (of a fully qualified name)."""
    from swarmloc.rmw.names import check_namespace

    if not isinstance(name, str) or not name:
        raise RosArgsError(f"{what}: a ROS name must be a non-empty string, got {name!r}")
    body = name[1:] if name.startswith("/") else name
    if body == "~":
        return name
    if body.startswith("~/"):
        body = body[2:]
    try:
        check_namespace("/" + body)
    except ValueError as exc:
        raise RosArgsError(f"{what} {name!r}: {exc}") from None
    if body == "" or "~" in body:
        raise RosArgsError(f"{what} {name!r}: empty, or '~' not at the start ('~' or '~/...')")
    return name


def expand(name: str, namespace: str = "/", node: str = "node") -> str:
    """The fully qualified form of ``name`` for node ``node`` in ``namespace`` (module docstring)."""
    check_name(name)
    ns = namespace.rstrip("/")
    if name.startswith("/"):
        return name
    if name == "~":
        return f"{ns}/{node}"
    if name.startswith("~/"):
        return f"{ns}/{node}/{name[2:]}"
    return f"{ns}/{name}"


@dataclass
class RosArgs:
    """What ``--ros-args`` said: remap rules ``(node or None, from, to)``, parameter overrides (``name -> value``),
    parameter files, and the node's name and namespace when remapped (``__node``, ``__ns``)."""

    remaps: list[tuple[str | None, str, str]] = field(default_factory=list)
    params: dict[str, Any] = field(default_factory=dict)
    params_files: list[str] = field(default_factory=list)
    node: str | None = None
    namespace: str | None = None

    def resolve(self, name: str, namespace: str, node: str) -> str:
        """``name`` expanded for the node and remapped by the first rule that matches it."""
        full = expand(name, namespace, node)
        for only, src, dst in self.remaps:
            if only is not None and only != node:
                continue
            if expand(src, namespace, node) == full:
                return expand(dst, namespace, node)
        return full


def _yaml_value(text: str) -> Any:
    import yaml

    try:
        return yaml.safe_load(text) if text != "" else ""
    except yaml.YAMLError as exc:
        raise RosArgsError(f"parameter value {text!r} is not YAML: {exc}") from None


def _split(rule: str, flag: str) -> tuple[str, str]:
    if ":=" not in rule:
        raise RosArgsError(f"{flag} {rule!r}: expected FROM:=TO")
    a, b = rule.split(":=", 1)
    if not a or not b:
        raise RosArgsError(f"{flag} {rule!r}: empty side")
    return a, b


def parse_ros_args(argv: Sequence[str]) -> tuple[RosArgs, list[str]]:
    """Split ``argv`` into the ROS arguments (every ``--ros-args`` section) and the rest (returned in order)."""
    out, rest = RosArgs(), []
    i, ros = 0, False
    argv = list(argv)
    while i < len(argv):
        a = argv[i]
        if a == "--ros-args":
            ros = True
        elif a == "--" and ros:
            ros = False
        elif not ros:
            rest.append(a)
        elif a in ("-r", "--remap", "-p", "--param", "--params-file"):
            if i + 1 >= len(argv):
                raise RosArgsError(f"{a} needs a value")
            _one(out, a, argv[i + 1])
            i += 1
        else:
            raise RosArgsError(f"unknown ROS argument {a!r} (known: -r/--remap, -p/--param, --params-file)")
        i += 1
    return out, rest


def _one(out: RosArgs, flag: str, value: str) -> None:
    if flag == "--params-file":
        out.params_files.append(value)
        return
    a, b = _split(value, flag)
    if flag in ("-p", "--param"):
        if not re.match(r"^[A-Za-z_][A-Za-z0-9_.]*$", a):
            raise RosArgsError(f"{flag} {value!r}: bad parameter name {a!r}")
        out.params[a] = _yaml_value(b)
        return
    only, _, src = a.rpartition(":") if ":" in a else (None, "", a)
    if src in ("__ns", "__node", "__name"):
        if src == "__ns":
            if not b.startswith("/"):
                raise RosArgsError(f"{flag} {value!r}: the namespace must be absolute")
            if b != "/":
                check_name(b, "namespace")
            out.namespace = b
        else:
            if not _NODE.match(b):
                raise RosArgsError(f"{flag} {value!r}: bad node name {b!r}")
            out.node = b
        return
    check_name(src, "remap source")
    check_name(b, "remap target")
    out.remaps.append((only or None, src, b))
