"""ROS 2 parameter files read as rcl reads them: which files it refuses, the node names and the typed values.

rcl (``rcl_yaml_param_parser``, Jazzy) does not load the YAML into a tree: it walks libyaml's events with a
small state machine (``parse.c``: ``parse_file_events``, ``parse_key``, ``get_value``). This module is a port
of that walk on the same events (PyYAML's libyaml parser), so that a file is refused here exactly when rcl
refuses it, and a value gets here the type a node gets:

* tags are ignored except ``!!str`` (``!!python/tuple``, which launch_ros's ``yaml.dump`` writes for a list,
  is a sequence like any other); anchors are ignored; an alias is an error ("Will not support aliasing");
* a plain scalar is a bool (``true``, ``yes``, ``on``, ``y`` ... as rcl lists them), else an integer if C's
  ``strtoll(s, 0)`` reads all of it (``010`` is 8, ``0x1f`` 31), else a double if ``strtod`` reads all of it
  without a range error (``1e6``, ``nan``, ``.inf``), else a string (``~`` and ``1_000`` too); a quoted
  scalar is a string; an empty plain scalar is an error;
* a sequence holds scalars of one type; an empty one gives the parameter no value (`NO_VALUE`);
* node names (the keys before ``ros__parameters``, joined by ``/``) are checked as rmw checks names,
  ``/**`` and ``/*`` and ``*``/``**`` components allowed.

Lengths of names are not checked (rmw's limits: 255 characters).
"""

from __future__ import annotations

import math
import re
from typing import Any

import yaml

from robotino_geom_mpc.errors import RobotinoError

__all__ = ["NO_VALUE", "RclFileError", "rcl_parameters", "rcl_scalar"]

PARAMS_KEY = "ros__parameters"
_NODE_LEVEL, _PARAMS_LEVEL = 1, 2
_STR_TAG = "tag:yaml.org,2002:str"
_TRUE = ("Y", "y", "yes", "Yes", "YES", "true", "True", "TRUE", "on", "On", "ON")
_FALSE = ("N", "n", "no", "No", "NO", "false", "False", "FALSE", "off", "Off", "OFF")
_YAML_INF_NAN = (".nan", ".NaN", ".NAN", ".inf", ".Inf", ".INF", "+.inf", "+.Inf", "+.INF", "-.inf", "-.Inf", "-.INF")
_WS = "[ \t\n\v\f\r]*"  # C's isspace, skipped by strtoll/strtod
_STRTOLL = re.compile(rf"{_WS}([+-]?)(0[xX][0-9a-fA-F]+|0[0-7]*|[1-9][0-9]*)")
_STRTOD = re.compile(
    rf"{_WS}(?P<sign>[+-]?)(?:(?P<dec>(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?)"
    r"|(?P<hex>0[xX](?:[0-9a-fA-F]+\.?[0-9a-fA-F]*|\.[0-9a-fA-F]+)(?:[pP][+-]?[0-9]+)?)"
    r"|(?P<inf>(?i:inf(?:inity)?))|(?P<nan>(?i:nan)(?:\([0-9A-Za-z_]*\))?))"
)
_INT64 = (-(2**63), 2**63 - 1)
_NAME_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


class RclFileError(RobotinoError, ValueError):
    """What rcl says when it refuses a parameter file (its message, with the line)."""


class _NoValue:
    def __repr__(self) -> str:
        return "NO_VALUE"


NO_VALUE = _NoValue()
"""The value of a parameter rcl read no value for (an empty sequence): rclpy's PARAMETER_NOT_SET."""


def _strtod(text: str) -> float | None:
    """C's ``strtod`` when it reads all of `text` without a range error, else None."""
    match = _STRTOD.fullmatch(text)
    if match is None:
        return None
    if match["inf"] or match["nan"]:
        value = math.inf if match["inf"] else math.nan
    else:
        digits = match["dec"] or match["hex"]
        value = float(digits) if match["dec"] else float.fromhex(digits)
        mantissa = re.split("[pP]" if match["hex"] else "[eE]", digits)[0]
        nonzero = any(c not in "0.xX" for c in mantissa)
        if math.isinf(value) or (nonzero and abs(value) < 2.2250738585072014e-308):
            return None  # ERANGE: overflow, or underflow to a subnormal or zero
    return -value if match["sign"] == "-" else value


def rcl_scalar(text: str, quoted: bool = False, str_tag: bool = False) -> bool | int | float | str:
    """The typed value of one scalar as rcl's ``get_value`` reads it (see the module doc)."""
    if str_tag or quoted:
        return text
    if text in _TRUE or text in _FALSE:
        return text in _TRUE
    match = _STRTOLL.fullmatch(text)
    if match is not None:
        magnitude = int(match[2], 0) if not re.fullmatch("0[0-7]+", match[2]) else int(match[2], 8)
        integer = -magnitude if match[1] == "-" else magnitude
        if _INT64[0] <= integer <= _INT64[1]:
            return integer
    if text in _YAML_INF_NAN:
        special = math.nan if "nan" in text.lower() else math.inf
        return -special if text.startswith("-") else special
    real = _strtod(text)
    return text if real is None else real


def _check_name(name: str) -> str | None:
    """rcl's ``_validate_name`` of a node key (namespace and node name as rmw validates them): None, or why not."""
    if name in ("/**", "/*"):
        return None
    namespace, slash, node = name.rpartition("/")
    absolute = namespace + slash if (namespace + slash).startswith("/") else f"/{namespace}{slash}"  # ends in '/'
    for token in absolute[1:-1].split("/") if slash and absolute != "/" else ():
        if token == "":
            return f"{absolute} contains repeated forward slash"
        if token not in ("**", "*") and not _NAME_TOKEN.fullmatch(token):
            return f"namespace '{absolute}' is not valid (letters, digits, '_', not starting with a digit)"
    if node not in ("*", "**") and not _NAME_TOKEN.fullmatch(node):
        return f"node name '{node}' is not valid (letters, digits, '_', not starting with a digit)"
    return None


class _Variant:
    """rcl's ``rcl_variant_t`` of one parameter: each kind in its own field; rclpy reads the first set one."""

    _ORDER = (bool, int, float, str, "bool[]", "int[]", "float[]", "str[]")

    def __init__(self) -> None:
        self.fields: dict[Any, Any] = {}

    def value(self) -> Any:
        for kind in self._ORDER:
            if kind in self.fields:
                return self.fields[kind]
        return NO_VALUE


class _Walk:
    """The state of rcl's ``parse_file_events`` (names as in parse.c)."""

    def __init__(self) -> None:
        self.nodes: dict[str, list[list]] = {}  # node name -> its [parameter name, _Variant] (names may repeat)
        self.node: str | None = None
        self.index = 0  # parameter_idx: the current parameter of the node
        self.is_key, self.is_seq, self.is_new_map = True, False, False
        self.map_level, self.map_depth = _NODE_LEVEL, 0
        self.node_ns: str | None = None  # ns_tracker: the node namespace (names joined by '/') and its count
        self.node_ns_count = 0
        self.param_ns: str | None = None  # ns_tracker: the parameter namespace (joined by '.') and its count
        self.param_ns_count = 0
        self.seq_kind: str | None = None

    def remove_node_name(self) -> None:
        """rcl's ``rem_name_from_ns``: the namespace up to its last '/' (none after the first name)."""
        if self.node_ns_count > 0:
            assert self.node_ns is not None  # a count above zero means names were added
            self.node_ns_count -= 1
            self.node_ns = None if self.node_ns_count == 0 else self.node_ns.rsplit("/", 1)[0]

    def node_params(self) -> list[list[Any]]:
        """The [parameter name, _Variant] list of the node whose ``ros__parameters`` are being read."""
        assert self.node is not None  # set when the walk enters a node's parameters (_PARAMS_LEVEL)
        return self.nodes[self.node]

    def find_parameter(self, name: str) -> int:
        """The index of the node's first parameter called `name`, added if there is none."""
        params = self.node_params()
        found = next((i for i, (known, _) in enumerate(params) if known == name), None)
        if found is None:
            params.append([name, _Variant()])
            found = len(params) - 1
        return found

    def key(self, value: str, line: int) -> None:
        if value == "":
            raise RclFileError(f"No key at line {line}")
        if self.map_level == _NODE_LEVEL:
            if not value.startswith(PARAMS_KEY):  # add_name_to_ns
                sep = "" if self.node_ns is None or self.node_ns.endswith("/") else "/"
                self.node_ns = value if self.node_ns is None else f"{self.node_ns}{sep}{value}"
                self.node_ns_count += 1
                return
            if self.node_ns_count == 0 or self.node_ns is None:
                raise RclFileError(f"There are no node names before {PARAMS_KEY} at line {line}")
            why = _check_name(self.node_ns)
            if why:
                raise RclFileError(why)
            self.node = self.node_ns
            self.nodes.setdefault(self.node_ns, [])
            self.remove_node_name()  # the last name was the node's, not a namespace
            self.map_level = _PARAMS_LEVEL
            return
        if self.is_new_map:  # the previous key was a parameter namespace
            self.param_ns = self.node_params()[self.index][0]
            self.param_ns_count += 1
            self.is_new_map = False
        if self.param_ns is None:
            self.index = self.find_parameter(value)
        else:  # the parameter called like the namespace (a new one if none) is renamed to namespace.key
            self.index = self.find_parameter(self.param_ns)
            self.node_params()[self.index][0] = f"{self.param_ns}.{value}"

    def value(self, event: yaml.ScalarEvent, line: int) -> None:
        if self.map_level < _PARAMS_LEVEL or self.node is None or not self.nodes[self.node]:
            raise RclFileError(f"Cannot have a value before {PARAMS_KEY} at line {line}")
        quoted = event.style in ("'", '"')
        if not quoted and event.value == "":
            raise RclFileError(f"No value at line {line}")
        value = rcl_scalar(event.value, quoted, event.tag == _STR_TAG)
        kind = {bool: bool, int: int, float: float, str: str}[type(value)]
        variant = self.node_params()[self.index][1]
        if not self.is_seq:
            variant.fields[kind] = value
            self.is_key = True
            return
        if self.seq_kind is None:
            self.seq_kind = f"{kind.__name__}[]"
            variant.fields[self.seq_kind] = []
        elif self.seq_kind != f"{kind.__name__}[]":
            raise RclFileError(f"Sequence should be of same type. Value type '{kind.__name__}' do not belong "
                               f"at line_num {line}")
        variant.fields[self.seq_kind].append(value)

    def mapping_end(self) -> None:
        if self.map_level == _PARAMS_LEVEL:
            if self.param_ns_count > 0:
                assert self.param_ns is not None  # a count above zero means a namespace was entered
                self.param_ns_count -= 1
                self.param_ns = self.param_ns.rsplit(".", 1)[0] if self.param_ns_count else None
            else:
                self.map_level -= 1
        elif self.map_depth == self.node_ns_count + 1:
            self.remove_node_name()
        self.map_depth -= 1


def _step(walk: _Walk, event: yaml.Event) -> None:
    line = event.start_mark.line + 1
    if isinstance(event, yaml.ScalarEvent):
        if walk.is_key:
            walk.key(event.value, line)
            walk.is_key = False
        else:
            walk.value(event, line)
    elif isinstance(event, yaml.SequenceStartEvent):
        if walk.is_key:
            raise RclFileError(f"Sequences cannot be key at line {line}")
        if walk.map_level < _PARAMS_LEVEL:
            raise RclFileError(f"Sequences can only be values and not keys in params. Error at line {line}")
        walk.is_seq, walk.seq_kind = True, None
    elif isinstance(event, yaml.SequenceEndEvent):
        walk.is_seq, walk.is_key = False, True
    elif isinstance(event, yaml.MappingStartEvent):
        walk.map_depth += 1
        walk.is_new_map = not (walk.map_level == _PARAMS_LEVEL and walk.map_depth - (walk.node_ns_count + 1) == 2)
        walk.is_key = True
    elif isinstance(event, yaml.MappingEndEvent):
        walk.mapping_end()
    elif isinstance(event, yaml.AliasEvent):
        raise RclFileError(f"Will not support aliasing at line {line}")


def rcl_parameters(text: str) -> dict[str, dict[str, Any]]:
    """Every node section of a parameter file as rcl reads it: node name (as written, namespace levels joined
    by '/') -> parameter (dotted) -> value (bool, int, float, str, a list of one of them, or `NO_VALUE`).

    Raises
    ------
    RclFileError
        Where rcl refuses the file: not YAML (libyaml's error), or not a parameter file rcl reads.
    """
    walk = _Walk()
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml's parser, as rcl's
    try:
        events = list(yaml.parse(text, Loader=loader))  # a YAML error first: rcl may stop at an earlier event
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or "not valid YAML"
        raise RclFileError(f"not valid YAML{where}: {problem}") from None
    for event in events:
        _step(walk, event)
    return {node: {name: v.value() for name, v in params} for node, params in walk.nodes.items()}
