"""The plant node's run: its end (the timing report, the exit status) and the robot loop's log lines.

`RunEnd` is what every run of the plant (`plant_lockstep.LockstepRun`, `plant_realtime.RealtimeRun`,
`chain_driver.ChainRun`) ends through: the timing report written to ``timing_report`` (if set) once every reader has
acknowledged the run's samples (so `run` may stop the other nodes once it is there; a failure is logged and the
exit status 1), then the node's ``done`` future set (`ros.spin.run_node` ends the spin on it).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from rclpy.node import Node
from rclpy.task import Future

from robotino_geom_mpc.loop.events import Log
from robotino_geom_mpc.loop.robot_loop import RobotLoop, Triple
from robotino_geom_mpc.ros.qos import wait_acknowledged
from robotino_geom_mpc.ros.spin import FINISHED_ACK_WAIT_S, data_publishers
from robotino_geom_mpc.ros.throttle import log_throttled
from robotino_sim_node.loop_timing import write_report

__all__ = ["RunEnd", "emit"]


class RunEnd:
    """The end of a plant node's run.

    Parameters
    ----------
    node
        The plant node.
    path
        The timing report's file (empty: none).
    """

    def __init__(self, node: Node, path: str) -> None:
        self.node, self.path = node, path
        self.done: Future = Future()
        self.exit_status = 0
        self.summary: dict | None = None  # the timing report once the run is over (a fleet gathers them)

    def report(self, report: dict) -> None:
        """Write the timing report (if a file is set) when the readers have the run's samples."""
        if self.path:
            wait_acknowledged(self.node, data_publishers(self.node), FINISHED_ACK_WAIT_S)
            try:
                write_report(self.path, report)
            except OSError as exc:
                self.node.get_logger().error(f"cannot write the timing report: {exc}")
                self.exit_status = 1

    def finish(self, report: dict) -> None:
        """`report`, then the run is over."""
        self.summary = report
        self.report(report)
        self.done.set_result(True)


def checked_command(node: Node, robot: RobotLoop, values: Sequence[float]) -> tuple[Triple, bool]:
    """`RobotLoop.check_command` of a command (its log line printed): what to apply and whether it is not a
    refusal's zero.
    """
    checked, log = robot.check_command(values)
    if log is not None:
        emit(node, [log])
    return checked, log is None or log.key != "refused"


def emit(node: Node, logs: Iterable[Log]) -> None:
    """The robot loop's log lines on the node's logger, throttled per key."""
    logger = node.get_logger()
    for log in logs:
        log_throttled(logger, log.level.name, log.text, log.throttle_s, log.key)
