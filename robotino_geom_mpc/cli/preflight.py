"""`robotino-geom-mpc preflight`: the dry run before the first motion; listens, never commands.

With the driver running and the controller not commanding, a node ``robotino_preflight`` (in ``--namespace``)
subscribes the driver's ``odom`` (the controller's QoS) for ``--seconds``, then reads the ROS graph (the
publishers of ``odom``, the subscribers of ``cmd_vel``) and runs `control.chain_preflight`'s checks against the
chain parameters: the ``chain.*`` the controller gets from ``--params`` (its ``robotino_controller`` and ``/**``
sections; the robocup-logistics preset for what they leave out), with ``--chain-params`` (`identify`'s
chain_params.yaml) over them, which adds the dead-time check. One line per check (PASS/FAIL and the measured
figure); exit status 0 when every check passes, 2 otherwise. It creates no publisher: it never sends a command.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from . import VERBS, UsageError, positive_float

__all__ = ["add_parser", "chain_of_files", "run"]

CONTROLLER_NODE = "robotino_controller"  # the section of the controller's parameters (and identify's file)


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the `preflight` verb."""
    parser = sub.add_parser(
        "preflight", help=VERBS["preflight"],
        description="Listen to the driver for --seconds without commanding and check the chain before the first "
        "motion: one odom publisher and a cmd_vel subscriber on the graph, the odometry's rate and stamp pattern "
        "against the chain parameters, stamps monotonic and fresh, the robot at rest, and with --chain-params the "
        "identified dead time. Exit 0 when every check passes, 2 otherwise.")
    parser.add_argument("--params", type=Path, default=None, metavar="FILE",
                        help="the controller's ROS 2 parameter file, e.g. config/robotino3_real.yaml (default: the "
                        "Robotino 3 preset; chain.* it leaves out: the robocup-logistics preset)")
    parser.add_argument("--chain-params", type=Path, default=None, metavar="FILE",
                        help="identify's chain_params.yaml (over --params; adds the dead-time check)")
    parser.add_argument("--namespace", default="", metavar="NS", help="the driver's namespace (default: none)")
    parser.add_argument("--seconds", type=positive_float, default=5.0, metavar="S",
                        help="listening time [s] (default 5)")
    parser.set_defaults(func=run)
    return parser


def chain_of_files(params: Path | None, chain_file: Path | None):  # noqa: ANN201 - (ChainParams, identified or None)
    """The chain the controller gets from `params` (+ `chain_file` over it), and `chain_file`'s alone (or None)."""
    from robotino_geom_mpc.model.driver_chain import ChainError, chain_params
    from robotino_geom_mpc.params.files import read_parameter_file
    from robotino_geom_mpc.params.presets import default_params_file

    def chain_values(path: Path) -> dict:
        values = read_parameter_file(path, CONTROLLER_NODE)
        return {k: v for k, v in values.items() if k.startswith("chain.") and k != "chain.active"}

    try:
        values = chain_values(params or default_params_file())
        identified = None
        if chain_file is not None:
            values.update(chain_values(chain_file))
            identified = chain_params(values, where=str(chain_file))
        return chain_params(values, where=str(params or "the preset")), identified
    except ChainError as exc:
        raise UsageError(str(exc)) from None


def run(args: argparse.Namespace) -> int:
    """Listen, check, print; returns 0 (all pass) or 2."""
    from robotino_geom_mpc.control.chain_preflight import dead_time_check, graph_checks, odometry_checks

    chain, identified = chain_of_files(args.params, args.chain_params)
    namespace = args.namespace.strip("/")
    print(f"preflight: listening {args.seconds:g} s to the driver{f' in /{namespace}' if namespace else ''} "
          f"(no command is sent)")
    samples, odom_topic, publishers, cmd_vel_topic, subscribers, end = _listen(namespace, args.seconds)
    checks = graph_checks(odom_topic, publishers, cmd_vel_topic, subscribers) + odometry_checks(samples, chain, end)
    if identified is not None:
        checks.append(dead_time_check(samples, identified))
    for check in checks:
        print(f"  {check.line()}")
    failed = [c.name for c in checks if not c.passed]
    print(f"preflight: {'all ' + str(len(checks)) + ' checks pass' if not failed else 'FAILED: ' + ', '.join(failed)}")
    return 0 if not failed else 2


def _listen(namespace: str, seconds: float):  # noqa: ANN202
    """Subscribe odom for `seconds` and read the graph: (samples, odom topic, its publishers, cmd_vel topic, its
    subscribers, the end [s of the node clock]).
    """
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import HistoryPolicy, QoSProfile

    from robotino_geom_mpc.control.chain_preflight import OdometrySample
    from robotino_geom_mpc.ros.messages import quaternion_to_yaw
    from robotino_geom_mpc.ros.qos import CONTROL_QOS
    from robotino_geom_mpc.ros.spin import clock_s

    context = Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node("robotino_preflight", namespace=f"/{namespace}", context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        samples: list = []

        def on_odom(msg: Odometry) -> None:
            received = clock_s(node)
            p, t = msg.pose.pose.position, msg.twist.twist
            samples.append(OdometrySample(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec, received,
                                          (p.x, p.y, quaternion_to_yaw(msg.pose.pose.orientation)),
                                          (t.linear.x, t.linear.y, t.angular.z)))

        # the controller's reliability and durability (what it cannot match, neither does this), kept all: two
        # samples of one driver pass arrive together, none is dropped while the spinning lags
        qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=CONTROL_QOS.reliability,
                         durability=CONTROL_QOS.durability)
        sub = node.create_subscription(Odometry, "odom", on_odom, qos)
        odom_topic, cmd_vel_topic = sub.topic_name, node.resolve_topic_name("cmd_vel")
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.01)
        end = clock_s(node)

        def names(infos: list) -> list[str]:
            return [f"{info.node_namespace.rstrip('/')}/{info.node_name}" for info in infos]
        publishers = names(node.get_publishers_info_by_topic(odom_topic))
        subscribers = names(node.get_subscriptions_info_by_topic(cmd_vel_topic))
        executor.shutdown()
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    return samples, odom_topic, publishers, cmd_vel_topic, subscribers, end
