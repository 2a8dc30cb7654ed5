"""The plant's emulated radio link as ROS parameters: ``link.up.*`` and ``link.down.*`` (`network.link`).

``up`` is everything the plant (the robot) publishes to the off-board nodes: ``odom``, ``wheel_currents``,
``applied_voltages``, ``joint_states``, ``/tf``, ``ground_truth/odom`` and ``command_applied``; ``down`` is
what they send it: ``wheel_voltages`` / ``cmd_vel`` and the plans ``wheel_voltage_plan`` / ``cmd_vel_plan``.
Per direction: ``delay_s`` (fixed part of the one-way delay), ``jitter_s`` (plus a uniform draw in
[0, jitter_s] per packet), ``loss`` (long-run loss probability, Gilbert-Elliott bursts), ``burst_length``
(mean loss-burst length in packets), ``duplicate`` (probability of a second copy). The plant's ``seed`` seeds
both directions as the offline loop does (`offline.networked`: up ``seed + 1``, down ``seed + 2``). All zero: no
link (the messages go out as before). A value out of range is refused with its name (`link_problem`, the
`SpecParameters` check).
"""

from __future__ import annotations

from typing import Any

from robotino_geom_mpc.network.link import MAX_DELAY_S, LinkError, LinkParams
from robotino_geom_mpc.params.specs import ParamSpec

__all__ = ["DIRECTIONS", "LINK_DEFAULTS", "LINK_SPECS", "link_params", "link_problem"]

DIRECTIONS = ("up", "down")

_FIELDS = (  # (parameter suffix, LinkParams field, spec)
    ("delay_s", "delay_s", "fixed part of the one-way delay", "s", 0.0, MAX_DELAY_S),
    ("jitter_s", "jitter_s", "plus a uniform draw in [0, jitter_s] per packet (reordering falls out of it)", "s",
     0.0, MAX_DELAY_S),
    ("loss", "loss", "long-run loss probability in [0, 1) (two-state Gilbert-Elliott chain)", "", 0.0, 1.0),
    ("burst_length", "burst_length", "mean loss-burst length in packets (1: independent losses)", "packets", 1.0,
     1e6),
    ("duplicate", "duplicate", "probability that a delivered packet is delivered twice", "", 0.0, 1.0),
)
_WHAT = {"up": "Link robot -> off-board (everything the plant publishes)",
         "down": "Link off-board -> robot (commands and plans to the plant)"}

LINK_SPECS: tuple[ParamSpec, ...] = tuple(
    ParamSpec(f"link.{way}.{suffix}", float, f"{_WHAT[way]}: {text}", unit, low, high, False)
    for way in DIRECTIONS for suffix, _, text, unit, low, high in _FIELDS)

LINK_DEFAULTS: dict[str, Any] = {f"link.{way}.{suffix}": (1.0 if suffix == "burst_length" else 0.0)
                                  for way in DIRECTIONS for suffix, *_ in _FIELDS}


def link_params(values: dict[str, Any], way: str) -> LinkParams:
    """The `LinkParams` of direction `way` (``up`` or ``down``) from the node's values; `LinkError` naming the
    parameter when they cannot make a link (e.g. ``link.up.loss`` 1).
    """
    try:
        return LinkParams(**{field: float(values[f"link.{way}.{suffix}"]) for suffix, field, *_ in _FIELDS})
    except LinkError as exc:
        raise LinkError(f"parameter 'link.{way}.{_suffix_named(str(exc))}': {exc}") from None


def _suffix_named(message: str) -> str:
    """The parameter suffix a `LinkError` message names (its first field name found in it)."""
    for suffix, field, *_ in _FIELDS:
        if field in message:
            return suffix
    return "*"


def link_problem(values: dict[str, Any]) -> str | None:
    """Why the values cannot make the two links (the message names the parameter), None when they can."""
    for way in DIRECTIONS:
        try:
            link_params(values, way)
        except LinkError as exc:
            return str(exc)
    return None
