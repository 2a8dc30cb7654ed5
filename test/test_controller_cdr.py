"""The controller's status written as CDR bytes (`ros.controller_cdr.diagnostics_cdr`), in-process: against
rclpy's deserializer and rosbags' (moved from the DDS module test_controller_node: no node, no DDS).
"""

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

pytestmark = pytest.mark.unit


def test_diagnostics_bytes_decode_as_the_message_they_stand_for():
    """`diagnostics_cdr` against rclpy's deserializer and rosbags' (every string length mod 4, non-ASCII)."""
    import random

    from diagnostic_msgs.msg import KeyValue
    from rclpy.serialization import deserialize_message
    from rosbags.typesys import Stores, get_typestore

    from robotino_geom_mpc.ros.controller_cdr import STATUS_NAME, diagnostics_cdr

    store, rng = get_typestore(Stores.ROS2_JAZZY), random.Random(4)
    for case in range(40):
        keys = [f"k{'x' * rng.randrange(6)}" for _ in range(rng.randrange(16))]
        values = [rng.choice(["", "é", "3.14159", "true", "x" * rng.randrange(9)]) for _ in keys]
        message, level, stamp = "tracking" + "°" * (case % 5), bytes([case % 4]), rng.randrange(2**40)
        data = diagnostics_cdr(stamp, level, message, [k.encode() for k in keys], values)
        expected = DiagnosticArray(status=[DiagnosticStatus(
            level=level, name=STATUS_NAME, message=message, hardware_id="robotino",
            values=[KeyValue(key=k, value=v) for k, v in zip(keys, values)])])
        expected.header.stamp.sec, expected.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        assert deserialize_message(data, DiagnosticArray) == expected
        other = store.deserialize_cdr(data, "diagnostic_msgs/msg/DiagnosticArray")
        assert [(p.key, p.value) for p in other.status[0].values] == list(zip(keys, values))
        assert (other.status[0].message, other.header.stamp.nanosec) == (message, stamp % 1_000_000_000)
