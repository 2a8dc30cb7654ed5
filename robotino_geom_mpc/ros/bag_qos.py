"""QoS profiles as rosbag2 stores them (metadata version 9) and rosbag2's rule for adapting to publishers.

The stored form (dicts of lower-case policy names, or the integers of
version 8, or their YAML text) is rosbags' (`rosbags.rosbag2.metadata`
``dump_qos_v9`` / ``parse_qos``); this module only converts between rclpy's
`QoSProfile` and rosbags' `Qos`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2.errors import ReaderError
from rosbags.rosbag2.metadata import dump_qos_v9, parse_qos

if TYPE_CHECKING:
    from rosbags.rosbag2.metadata import QosDict

__all__ = ["profile_to_dict", "dict_to_profile", "adapt_request_to_offers", "adapt_offer_to_recorded"]


def _time(value: Duration) -> QosTime:
    return QosTime(*divmod(int(value.nanoseconds), 1_000_000_000))


def _duration(value: QosTime) -> Duration:
    return Duration(nanoseconds=int(value.sec) * 1_000_000_000 + int(value.nsec))


def profile_to_dict(qos: QoSProfile) -> dict[str, Any]:
    """One offered QoS profile in rosbag2's version-9 form (policies as lower-case names).

    An infinite duration (RMW_DURATION_INFINITE, 2**63 - 1 ns) becomes
    ``{sec: 9223372036, nsec: 854775807}`` as rosbag2 writes it.
    """
    profile = Qos(
        QosHistory[qos.history.name], int(qos.depth), QosReliability[qos.reliability.name],
        QosDurability[qos.durability.name], _time(qos.deadline), _time(qos.lifespan),
        QosLiveliness[qos.liveliness.name], _time(qos.liveliness_lease_duration),
        bool(qos.avoid_ros_namespace_conventions),
    )
    return dict(dump_qos_v9([profile])[0])


def dict_to_profile(item: dict[str, Any]) -> QoSProfile:
    """Inverse of `profile_to_dict` (also accepts the integer policies of metadata version <= 8).

    Raises
    ------
    ValueError
        If a policy or duration is missing or not a QoS value.
    """
    try:
        (qos,) = parse_qos([cast("QosDict", item)])  # (any dict: parse_qos checks it, its errors caught below)
    except (ReaderError, KeyError, TypeError, AttributeError) as exc:
        raise ValueError(f"not a rosbag2 QoS profile: {item!r} ({exc.__class__.__name__}: {exc})") from None
    return QoSProfile(
        history=HistoryPolicy[qos.history.name],
        depth=max(int(qos.depth), 1),
        reliability=ReliabilityPolicy[qos.reliability.name],
        durability=DurabilityPolicy[qos.durability.name],
        deadline=_duration(qos.deadline),
        lifespan=_duration(qos.lifespan),
        liveliness=LivelinessPolicy[qos.liveliness.name],
        liveliness_lease_duration=_duration(qos.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(qos.avoid_ros_namespace_conventions),
    )


def adapt_request_to_offers(offers: list[QoSProfile], depth: int) -> QoSProfile:
    """A subscription QoS that matches every publisher (rosbag2's rule).

    Reliable only if every publisher offers reliable, transient local only if
    every publisher offers it (then latched messages are received). History:
    keep-last `depth`, or keep-all for ``depth == 0``. Keep-all is what makes
    a reliable recording lossless: a sample the transport dropped is resent
    only after the writer's next heartbeat (Fast DDS: every 3 s), and the
    reader holds the samples received after it until then; a keep-last queue
    shorter than that (1000 messages are 1 s at 1 kHz) would overflow.
    """
    reliable = bool(offers) and all(q.reliability == ReliabilityPolicy.RELIABLE for q in offers)
    latched = bool(offers) and all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offers)
    return QoSProfile(
        history=HistoryPolicy.KEEP_ALL if depth == 0 else HistoryPolicy.KEEP_LAST,
        depth=max(depth, 1),
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


def adapt_offer_to_recorded(profiles: list[dict[str, Any]], depth: int = 10) -> QoSProfile:
    """The QoS a replay publisher offers: the recorded offer when all publishers agreed, else reliable volatile."""
    if profiles:
        first = dict_to_profile(profiles[0])
        same = all(
            (p.reliability, p.durability) == (first.reliability, first.durability)
            for p in map(dict_to_profile, profiles)
        )
        if same:
            first.history = HistoryPolicy.KEEP_LAST
            first.depth = max(first.depth, depth)
            return first
    return QoSProfile(depth=depth)
