"""Benchmark ``cdr``: what the CDR fast path (`ros.cdr`) saves on each message the loop exchanges.

Per message (the plant's ``odom``, the trajectory's ``reference_preview``
with N = 4, the controller's ``wheel_voltages``), side by side in one run,
the repeats interleaved (`registry.median_per_call`):

* writing: `CdrTemplate.pack` of the values against setting them on a
  message kept between samples (as the nodes do with the messages they do
  not template) and ``rclpy.serialization.serialize_message``;
* reading: `CdrLayout.read` against ``deserialize_message`` and against the
  general decoder the nodes fall back to (`cdr.cdr_reader`: rclpy's, its errors
  wrapped), each
  followed by taking the values the node needs (`ros.decode`), as the
  nodes' fallback does.

Before timing, all sides must agree: the packed bytes decode to the message
built field by field, and every reader returns the same values; otherwise
`BenchmarkError`.
"""

from __future__ import annotations

import random
import re
from collections.abc import Callable
from typing import Any

from robotino_geom_mpc.bench.registry import BenchmarkError, BenchmarkSkipped, benchmark, median_per_call

__all__ = ["PREVIEW_HORIZON", "bench_cdr", "message_cases"]

PREVIEW_HORIZON = 4  # N of the benchmarked preview (N + 1 = 5 points)
_SAMPLES = 8  # distinct value sets cycled through by every pass


def message_cases(period_s: float) -> dict[str, dict[str, Any]]:
    """Per message: its type, the template, the layout, a message to set fields on, and how a node reads it.

    Keys of each case: ``type``, ``template`` (`CdrTemplate`), ``layout`` (`CdrLayout`), ``message`` (the
    message the template was made of), ``reader`` (`cdr_reader`) and ``values`` (decoded message -> the
    values `layout.read` returns).
    """
    from nav_msgs.msg import Odometry
    from std_msgs.msg import Float64MultiArray
    from trajectory_msgs.msg import MultiDOFJointTrajectory

    from robotino_geom_mpc.ros.cdr import CdrTemplate, cdr_reader
    from robotino_geom_mpc.ros.decode import ODOM_FIELDS, odometry_values, preview_point_values
    from robotino_geom_mpc.ros.messages import VOLTAGE_LABEL, odometry_layout, odometry_message, \
        preview_layout, preview_skeleton, preview_template, three_values, three_values_layout, three_values_template

    odom = odometry_message()
    preview = preview_template(period_s, PREVIEW_HORIZON)
    return {
        "odometry": {
            "type": Odometry, "template": CdrTemplate(odom, ODOM_FIELDS), "layout": odometry_layout(),
            "message": odom, "reader": cdr_reader(Odometry, "nav_msgs/msg/Odometry"), "values": odometry_values,
        },
        "reference_preview": {
            "type": MultiDOFJointTrajectory, "template": preview, "layout": preview_layout(period_s, PREVIEW_HORIZON),
            "message": preview_skeleton(period_s, PREVIEW_HORIZON),
            "reader": cdr_reader(MultiDOFJointTrajectory, "trajectory_msgs/msg/MultiDOFJointTrajectory"),
            "values": lambda msg: (msg.header.stamp.sec, msg.header.stamp.nanosec,
                                   *preview_point_values(msg, PREVIEW_HORIZON)),
        },
        "wheel_voltages": {
            "type": Float64MultiArray, "template": three_values_template(VOLTAGE_LABEL),
            "layout": three_values_layout(VOLTAGE_LABEL), "message": three_values(VOLTAGE_LABEL),
            "reader": cdr_reader(Float64MultiArray, "std_msgs/msg/Float64MultiArray"),
            "values": lambda msg: tuple(msg.data),
        },
    }


def _parts(path: str) -> list[tuple[str, str | None]]:
    """(name, element index or None) of each part of a field path such as ``pose.covariance[3]``."""
    parts = []
    for part in path.split("."):
        match = re.fullmatch(r"(\w+)(?:\[(\d+)\])?", part)
        if match is None:
            raise ValueError(f"not a field path: {path!r}")
        parts.append((match[1], match[2]))
    return parts


def _setter(msg: Any, paths: tuple[str, ...]) -> Callable[[tuple], Any]:
    """Sets the `paths` fields of `msg` to given values and returns it (the fields resolved once)."""
    fields = []
    for path in paths:  # (object holding the field, its name, element index or None), as `CdrTemplate` reads paths
        *parents, last = _parts(path)
        holder = msg
        for name, index in parents:
            holder = getattr(holder, name) if index is None else getattr(holder, name)[int(index)]
        fields.append((holder, last[0], None if last[1] is None else int(last[1])))

    def build(values: tuple) -> Any:
        for (holder, name, index), value in zip(fields, values):
            if index is None:
                setattr(holder, name, value)
            else:
                getattr(holder, name)[index] = value
        return msg

    return build


def _sample(template: Any, rng: random.Random) -> tuple:
    """Values for `template`: a stamp (when its first two paths are one), the rest floats of control size."""
    values = [rng.uniform(-2.0, 2.0) for _ in template.paths]
    if template.paths[:2] == ("header.stamp.sec", "header.stamp.nanosec"):
        values[:2] = rng.randrange(2**31), rng.randrange(10**9)
    return tuple(values)


@benchmark("cdr", "CdrTemplate.pack and CdrLayout.read against rclpy's (de)serialization "
           "and the nodes' fallback decoder")
def bench_cdr(quick: bool) -> dict[str, float]:
    """Per message: pack vs set + serialize_message, layout read vs deserialize_message and vs cdr_reader [us]."""
    try:
        from rclpy.serialization import deserialize_message, serialize_message
    except ImportError as exc:
        raise BenchmarkSkipped(f"ROS 2 not available: {exc}") from None
    from robotino_geom_mpc.params.files import load_params

    rounds, repeats = (50, 5) if quick else (500, 15)
    rng = random.Random(1)
    out: dict[str, float] = {}
    for name, case in message_cases(load_params()[1].period_s).items():
        template, layout, msg_type, reader, values = (case[k] for k in ("template", "layout", "type", "reader",
                                                                        "values"))
        build = _setter(case["message"], template.paths)
        samples = [_sample(template, rng) for _ in range(_SAMPLES)]
        datas = [template.pack(*v) for v in samples]
        for v, data in zip(samples, datas):
            decoded = deserialize_message(data, msg_type)
            if deserialize_message(serialize_message(build(v)), msg_type) != decoded:
                raise BenchmarkError(f"cdr {name}: the template's bytes and rclpy's serialization differ")
            if not layout.read(data) == values(decoded) == values(reader(data)):
                raise BenchmarkError(f"cdr {name}: CdrLayout, deserialize_message and cdr_reader read different values")

        def pack() -> None:
            for _ in range(rounds):
                for v in samples:
                    template.pack(*v)

        def build_serialize() -> None:
            for _ in range(rounds):
                for v in samples:
                    serialize_message(build(v))

        def read_layout() -> None:
            for _ in range(rounds):
                for data in datas:
                    layout.read(data)

        def read_rclpy() -> None:
            for _ in range(rounds):
                for data in datas:
                    values(deserialize_message(data, msg_type))

        def read_reader() -> None:
            for _ in range(rounds):
                for data in datas:
                    values(reader(data))

        times = median_per_call([pack, build_serialize, read_layout, read_rclpy, read_reader],
                                rounds * _SAMPLES, repeats)
        pack_us, build_us, layout_us, rclpy_us, reader_us = (1e6 * t for t in times)
        out.update({
            f"cdr_pack_us_{name}": pack_us,
            f"cdr_build_serialize_us_{name}": build_us,
            f"cdr_pack_speedup_{name}": build_us / pack_us,
            f"cdr_layout_read_us_{name}": layout_us,
            f"cdr_deserialize_us_{name}": rclpy_us,
            f"cdr_reader_us_{name}": reader_us,
            f"cdr_read_speedup_{name}": rclpy_us / layout_us,
            f"cdr_read_speedup_vs_reader_{name}": reader_us / layout_us,
        })
    return out
