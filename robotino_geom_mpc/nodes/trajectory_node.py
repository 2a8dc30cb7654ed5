"""Trajectory node: streams the N-step reference preview the MPCs track (eq. 54) and the whole reference path.

Topics (relative names)
-----------------------
publishes  ``reference_preview``  trajectory_msgs/MultiDOFJointTrajectory, `publish_qos(lockstep)` (lockstep:
                                  keep-all, a slow reader holds the loop back, `publish_acknowledged`):
                                  header.stamp = the tick time t_k, frame ``<frame_prefix>odom``, one joint
                                  ``<frame_prefix>base_link``
                                  (the planar pose of the robot), N + 1 points j = 0..N with
                                  time_from_start = j Ts: transforms (x_d, y_d, yaw quaternion of theta_d),
                                  velocities and accelerations (linear x, y and angular z, in ``odom``).
                                  Point 0 is the reference at t_k itself (tracking error, recording);
                                  points 1..N are `reference.trajectories.preview` (x_d(k+1) .. x_d(k+N)).
           ``reference_path``     nav_msgs/Path in ``<frame_prefix>odom``, `LATCHED_QOS` (transient local), the
                                  whole reference sampled every control period, published once.
subscribes ``/clock``             rosgraph_msgs/Clock (lockstep only, reliable).
           ``goal_pose``, ``plan``  geometry_msgs/PoseStamped, nav_msgs/Path (scenario ``goals`` only:
                                  `nodes.goal_inputs`, which checks them and replans the reference).

Goals
-----
In scenario ``goals`` the reference is a `reference.goals.GoalReference`: it holds the start pose
(the origin) until a goal or path arrives, which starts a C^3 motion at the current reference time
(realtime: node clock minus the start, 0 before the start; lockstep: the latest tick published) from
the reference's state there. The reference_path is published again after each (the new motion only, a
pose every `_GOAL_PATH_STEP` periods), the lockstep table
(`_grid_values`) is rebuilt; the limits (``goals.*``) and ``frame_prefix`` may change while running.
Only a change of ``scenario`` or ``waypoints`` makes a new reference (and drops the goals): a set of
any other parameter, or of these to their current values, leaves the motion alone.

Timing
------
``realtime``: a timer on the node clock (sim time when ``use_sim_time``)
publishes the preview every control period; the reference starts (t = 0)
at the first tick at which, for ``start_settle_s``, a controller has
subscribed the preview and the graph has shown a publisher of ``odom``
(the robot or the plant; a plant process starting last can come up a
second after the others). Until then nothing is published, so the
controller does not answer and the robot stays at rest: the settle lets
discovery end first. Fast DDS's first message from one participant to
another's shared-memory port (here the controller's first ACKNACK to this
node) can sleep 333 ms in a port health check while it holds the
participant's send lock, and a controller publishing its voltages then
waits as long (bench/README.md); during the settle nothing waits for it.

Each pose of ``reference_path`` is stamped with the time the reference
passes there (start time + t), so a recording can be matched with the
odometry stamps in both modes.

``lockstep``: driven by the plant's /clock messages (the node clock is not
read, so `run` and the launch file leave ``use_sim_time`` false: a time
source would add a second /clock reader). On the clock of tick k the node
publishes the preview of tick k + 1 (and, on the first clock, the one of
tick k first). The preview of the next tick is thus computed while the
controller and the plant work on the current one, and is waiting at the
controller when the next odometry arrives: the critical path of a tick is
plant -> controller -> plant only. A repeated clock (the plant resends a
tick nobody answered) publishes both previews again, and so does a newly
matched preview subscription (a controller whose endpoints matched after
the plant started: it gets the current tick's preview at once, not at the
plant's next resend); the controller keys previews by stamp, so repeats
are harmless. Without /clock for ``clock_timeout_s`` (a plant not started,
stalled or ended) the node logs, throttled, what it waits for.

Parameters: ``control.period_s`` and ``control.horizon`` of config/*.yaml
(``/**`` section; fixed while the node runs, as are ``mode`` and
``clock_timeout_s``), the robot's (the wheel kinematics and the motor's nominal speed bound the
goal motions), `TRAJECTORY_SPECS`, `nodes.goal_inputs.GOAL_SPECS` and ``waypoints`` (a flat list
x1, y1, theta1, x2, ... for point-to-point; empty: the scenario's default).
``scenario`` is a name of `robotino_geom_mpc.scenarios.SCENARIOS`; the node
tracks its reference (``robustness``: paper-circle; the mismatch and the
noise are the controller's and the plant's parameters).
"""

from __future__ import annotations

import numpy as np
from nav_msgs.msg import Path
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import PublisherEventCallbacks, QoSPublisherMatchedInfo
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock as ClockMsg
from trajectory_msgs.msg import MultiDOFJointTrajectory

from robotino_geom_mpc.reference.goals import GoalReference
from robotino_geom_mpc.params.specs import ALL_SPECS, ParamSpec
from robotino_geom_mpc.nodes.goal_inputs import GOAL_DEFAULTS, GOAL_SPECS, GoalInputs, goal_params_problem
from robotino_geom_mpc.reference.trajectories import Reference, TrajectoryError
from robotino_geom_mpc.ros.cdr import CdrLayout, CdrTemplate
from robotino_geom_mpc.ros.messages import ODOM_FRAME, path_cdr, point_values, preview_template, preview_values
from robotino_geom_mpc.ros.parameters import NodeStartError, SpecParameters, spec_defaults
from robotino_geom_mpc.ros.qos import CLOCK_SUB_QOS, LATCHED_QOS, publish_acknowledged, publish_qos
from robotino_geom_mpc.ros.spin import monotonic, run_node
from robotino_geom_mpc.scenarios import SCENARIOS, get_scenario
from robotino_geom_mpc.ros.throttle import warn_throttled

__all__ = ["TRAJECTORY_SPECS", "TrajectoryNode", "main"]


TRAJECTORY_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("scenario", str, "Scenario whose reference the node streams (robustness: paper-circle's)",
              choices=tuple(SCENARIOS)),
    ParamSpec("mode", str, "realtime: timer on the node clock; lockstep: driven by /clock",
              choices=("realtime", "lockstep")),
    ParamSpec("start_settle_s", float, "Realtime: start the reference this long after a controller subscribes the "
              "preview and odom has a publisher (discovery between the nodes ends first)", "s", 0.0, 60.0, False),
    ParamSpec("clock_timeout_s", float, "Lockstep: after this long without /clock, log (throttled) what the node "
              "waits for", "s", 0.0, 3600.0, True),
    ParamSpec("preview_points", int, "Points after the first in each preview; 0: control.horizon (N). A controller "
              "with plans needs its DelayCompensatingController.preview_length", "", 0, 10000, False),
)
_DEFAULTS = {"scenario": "paper-circle", "mode": "realtime", "start_settle_s": 1.0, "clock_timeout_s": 5.0,
             "preview_points": 0}
_FIXED = ("mode", "control.period_s", "control.horizon", "clock_timeout_s", "preview_points")
_GOAL_PATH_STEP = 5  # after a goal, reference_path has a pose every this many control periods
_WAIT_LOG_PERIOD_S = 5.0  # at most one "waiting for /clock" line per this long (or per clock_timeout_s if longer)
_GAP_FILL_TICKS = 100  # lockstep: the previews of at most this many skipped ticks are sent late


class TrajectoryNode(Node):
    """The trajectory node (see the module docstring for its interface)."""

    def __init__(self) -> None:
        super().__init__("robotino_trajectory")
        specs = ALL_SPECS + TRAJECTORY_SPECS + GOAL_SPECS
        self.params = SpecParameters(
            self, specs, {**spec_defaults(ALL_SPECS), **_DEFAULTS, **GOAL_DEFAULTS}, self._on_params, fixed=_FIXED,
            check=goal_params_problem,
        )
        self.declare_parameter(
            "waypoints",
            Parameter.Type.DOUBLE_ARRAY,
            ParameterDescriptor(
                description="point-to-point waypoints as a flat list x1 [m], y1 [m], theta1 [rad], x2, ...; "
                "empty: the scenario's default",
                additional_constraints="a multiple of 3 finite values",
            ),
        )
        self.add_on_set_parameters_callback(self._check_waypoints)
        self.add_post_set_parameters_callback(self._on_waypoints)
        try:
            self.waypoints = self._waypoints()
            self.reference = self._make_reference(self.params["scenario"], self.waypoints)
        except TrajectoryError as exc:
            raise NodeStartError(str(exc)) from None
        self.lockstep = self.params["mode"] == "lockstep"
        self.goals = GoalInputs(self, self.params.values, self._reference_time, self._replanned)
        self.goals.attach(self.reference)
        self.preview_pub = self.create_publisher(
            MultiDOFJointTrajectory, "reference_preview", publish_qos(self.lockstep),
            event_callbacks=PublisherEventCallbacks(matched=self._on_preview_matched),
        )
        self.path_pub = self.create_publisher(Path, "reference_path", LATCHED_QOS)
        self.last_clock_ns: int | None = None
        self.last_published_ns: int | None = None
        self.start_ns: int | None = 0 if self.lockstep else None  # node-clock time of the reference's t = 0
        self.subscribed_since: int | None = None  # realtime: node-clock time since which the start condition holds
        self.odom_topic = self.resolve_topic_name("odom")  # realtime: its publisher is part of the start condition
        self.preview_cdr: CdrTemplate | None = None  # built on first use (horizon and period fixed)
        self.grid: np.ndarray | None = None  # lockstep: point values at k Ts (`_grid_values`)
        if self.lockstep:
            self.clock_layout = CdrLayout(ClockMsg(), ("clock.sec", "clock.nanosec"))  # read in place
            self.clock_sub = self.create_subscription(ClockMsg, "/clock", self._on_clock, CLOCK_SUB_QOS, raw=True)
            self.clock_heard_at = monotonic()  # steady time of the last /clock (of the start before the first)
            self.clock_watch = self.create_timer(self.params["clock_timeout_s"] / 2, self._check_clock,
                                                 clock=Clock(clock_type=ClockType.STEADY_TIME))
        else:
            self.timer = self.create_timer(self.params["control.period_s"], self._on_timer)
        if self.start_ns is not None:
            self._publish_path()
        self.get_logger().info(
            f"trajectory '{self.params['scenario']}' (reference {self.reference.name}, "
            f"{self.reference.duration_s:g} s, N = {self.params['control.horizon']}, {self.params['mode']})"
        )

    # parameters ---------------------------------------------------------------------------------
    def _waypoints(self, value=None) -> np.ndarray | None:
        if value is None:
            param = self.get_parameter_or("waypoints", Parameter("waypoints", Parameter.Type.DOUBLE_ARRAY, []))
            value = param.value if param.type_ != Parameter.Type.NOT_SET else []
        flat = list(value or [])
        if not flat:
            return None
        if len(flat) % 3 or not np.all(np.isfinite(flat)):
            raise TrajectoryError(f"parameter 'waypoints' must hold a multiple of 3 finite values, got {flat!r}")
        return np.asarray(flat, dtype=float).reshape(-1, 3)

    @staticmethod
    def _make_reference(name: str, waypoints: np.ndarray | None) -> Reference:
        scenario = get_scenario(name)
        if waypoints is None:
            return scenario.make_reference()
        if scenario.reference != "point-to-point":
            raise TrajectoryError(f"parameter 'waypoints' applies to point-to-point only, not to {name!r}")
        return scenario.make_reference(waypoints=waypoints)

    def _check_waypoints(self, params: list[Parameter]) -> SetParametersResult:
        names = {p.name: p.value for p in params}
        scenario = names.get("scenario", self.params["scenario"])
        if ("waypoints" not in names and "scenario" not in names) or scenario not in TRAJECTORY_SPECS[0].choices:
            return SetParametersResult(successful=True)  # an unknown scenario: the spec's check refuses it
        try:
            wp = self._waypoints(names["waypoints"]) if "waypoints" in names else self._waypoints()
            self._make_reference(scenario, wp)
        except TrajectoryError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _on_params(self, changed: dict) -> None:
        """A new reference for a new scenario; previews and path in the frame of a new prefix.

        New limits are read at the next goal; other parameters (the robot's, the controller's weights)
        do not touch the reference.
        """
        if "frame_prefix" in changed:
            self.preview_cdr = None  # built again in the new frame
        if "scenario" in changed:
            self._new_reference()
        elif "frame_prefix" in changed:
            self._replanned(self.reference)

    def _on_waypoints(self, params: list[Parameter]) -> None:
        """A new reference when ``waypoints`` changed value (checked by `_check_waypoints`)."""
        if any(p.name == "waypoints" for p in params) and not np.array_equal(self._waypoints(), self.waypoints):
            self._new_reference()  # (None: the scenario's default)

    def _new_reference(self) -> None:
        self.waypoints = self._waypoints()
        self.reference = self._make_reference(self.params["scenario"], self.waypoints)
        self.goals.attach(self.reference)
        self._replanned(self.reference)

    def _reference_time(self) -> float:
        """The reference time [s] a goal starts at: the latest tick published (lockstep), now (realtime)."""
        if self.lockstep:
            return (self.last_published_ns or 0) * 1e-9
        if self.start_ns is None:
            return 0.0
        return (self.get_clock().now().nanoseconds - self.start_ns) * 1e-9

    def _replanned(self, reference: GoalReference | Reference) -> None:
        """The reference changed: rebuild the lockstep table, publish the path again.

        After a goal or path only the new motion is published, every `_GOAL_PATH_STEP` periods: a path
        of the whole run would stall the previews for as long as its thousands of poses take to build.
        """
        self.grid = None
        if self.start_ns is None:
            return
        if isinstance(reference, GoalReference) and reference.pieces:
            self._publish_path(reference.starts[-1], _GOAL_PATH_STEP)
        else:
            self._publish_path()

    # publishing ---------------------------------------------------------------------------------
    def _grid_values(self, t_ns: int) -> list[float] | None:
        """Lockstep: the preview values of a tick on the grid k Ts, sliced from a table sampled once (None off it).

        The table is the reference sampled at every tick in one vectorised call, as
        `simulation.run_scenario` samples its targets, so the positions are those of the offline loop.
        """
        period_s, horizon = self.params["control.period_s"], self._preview_points()
        k, off = divmod(t_ns, self._period_ns())
        if self.grid is None:
            times = np.arange(int(self.reference.duration_s / period_s) + horizon + 2) * period_s
            self.grid = point_values(*self.reference.sample(times)[:3])
        if off or k < 0 or k + horizon >= len(self.grid):
            return None
        return self.grid[k : k + horizon + 1].ravel().tolist()

    def _preview_points(self) -> int:
        return self.params["preview_points"] or self.params["control.horizon"]

    def _publish_preview(self, t_ns: int, reference_t_ns: int) -> None:
        period_s, horizon = self.params["control.period_s"], self._preview_points()
        if self.preview_cdr is None:
            self.preview_cdr = preview_template(period_s, horizon, self.params["frame_prefix"])
        values = self._grid_values(reference_t_ns) if self.lockstep else None
        if values is None:
            values = preview_values(self.reference, reference_t_ns, period_s, horizon)
        publish_acknowledged(self, self.preview_pub, self.preview_cdr.pack(*divmod(t_ns, 1_000_000_000), *values))
        self.last_published_ns = t_ns

    def _on_clock(self, data: bytes) -> None:
        values = self.clock_layout.read(data)
        if values is None:  # every well-formed Clock has the layout
            warn_throttled(self.get_logger(), f"undecodable /clock ({len(data)} bytes) ignored", 1.0)
            return
        self.clock_heard_at = monotonic()
        now = values[0] * 1_000_000_000 + values[1]
        # the preview of the tick itself only on the first tick, a jump, or a resent tick
        self._publish_ahead(now, current=now == self.last_clock_ns or self.last_published_ns != now)
        self.last_clock_ns = now

    def _check_clock(self) -> None:
        """Lockstep: say what the node waits for when /clock has been silent for ``clock_timeout_s``."""
        waited = monotonic() - self.clock_heard_at
        timeout = self.params["clock_timeout_s"]
        if waited < timeout:
            return
        topic = self.clock_sub.topic_name
        last = "none" if self.last_clock_ns is None else f"{self.last_clock_ns * 1e-9:g} s"
        warn_throttled(
            self.get_logger(),
            f"lockstep: no clock on {topic} for {waited:.1f} s (last tick: {last}): waiting for the plant's next "
            f"tick ({self.count_publishers(topic)} publisher(s) of {topic}); previews follow each clock",
            max(timeout, _WAIT_LOG_PERIOD_S),
        )

    def _on_preview_matched(self, info: QoSPublisherMatchedInfo) -> None:
        """Lockstep: a new subscription gets the previews of the current tick (those sent before missed it)."""
        if self.lockstep and info.current_count_change > 0 and self.last_clock_ns is not None:
            self._publish_ahead(self.last_clock_ns, current=True)

    def _publish_ahead(self, now: int, current: bool) -> None:
        """Lockstep: the preview of the tick after `now`, after that of `now` itself if `current`, and before it
        those of the ticks since the last one published (up to `_GAP_FILL_TICKS`): a /clock the reader's history
        dropped in a burst of ticks (over a link the plant runs on at once through ticks with no answer due)
        would leave the preview of its next tick unsent, and an odometry of that stamp, delivered later, waiting.
        """
        if current:
            period, last = self._period_ns(), self.last_published_ns
            if last is not None and now - _GAP_FILL_TICKS * period <= last < now - period:
                for stamp in range(last + period, now, period):
                    self._publish_preview(stamp, stamp)
            self._publish_preview(now, now)
        after = now + self._period_ns()
        self._publish_preview(after, after)

    def _period_ns(self) -> int:
        return int(round(self.params["control.period_s"] * 1e9))

    def _on_timer(self) -> None:
        now = self.get_clock().now().nanoseconds
        if self.start_ns is None:
            if self.preview_pub.get_subscription_count() == 0 or self.count_publishers(self.odom_topic) == 0:
                self.subscribed_since = None
                return  # the reference starts when a controller listens and the robot sends odometry ...
            if self.subscribed_since is None:
                self.subscribed_since = now
            if now - self.subscribed_since < int(self.params["start_settle_s"] * 1e9):
                return  # ... and has for the settle time
            self.start_ns = now
            self._publish_preview(now, 0)  # the loop's data first: the path is for the tools
            self._publish_path()
            return
        self._publish_preview(now, now - self.start_ns)

    def _publish_path(self, from_s: float = 0.0, step: int = 1) -> None:
        period = self.params["control.period_s"] * step
        times = np.arange(from_s, self.reference.duration_s + 0.5 * period, period)
        stamps = [self.start_ns + int(round(t * 1e9)) for t in times.tolist()]
        odom = self.params["frame_prefix"] + ODOM_FRAME
        publish_acknowledged(self, self.path_pub, path_cdr(odom, self.start_ns, stamps, self.reference.position(times)))

def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run robotino_geom_mpc trajectory_node``."""
    return run_node(TrajectoryNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
