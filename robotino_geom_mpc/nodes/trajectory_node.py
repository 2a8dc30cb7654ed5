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
                                  whole reference sampled every control period, published at the start (again
                                  after each goal, and at each start with ``start_on_enable``).
subscribes ``/clock``             rosgraph_msgs/Clock (lockstep only, reliable).
           ``controller_enabled`` std_msgs/Bool, `LATCHED_QOS` (``start_on_enable`` only): the controller's
                                  enabled state.
           ``odom``               nav_msgs/Odometry, best effort, keep-last 1 (``anchor_to_robot`` only): the
                                  robot's pose the reference is anchored at.
           ``goal_pose``, ``plan``  geometry_msgs/PoseStamped, nav_msgs/Path (scenario ``goals`` only:
                                  `nodes.goal_inputs`, which checks them and replans the reference).
           ``odom``, ``/tf``, ``/tf_static``  (scenario ``goals``, for ``follow_path``: the robot's pose for
                                  its goal and progress checks; the transforms of paths into ``odom``,
                                  `ros.tf_listener`).
action     ``follow_path``        nav2_msgs/action/FollowPath, Nav2's controller_server role (scenario ``goals``:
                                  `nodes.follow_path_server`, `reference.follow_path`).

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

Nav2's follow_path
------------------
In scenario ``goals`` the node is also Nav2's controller_server for the paths a planner makes
(`nodes.follow_path_server`: the ``follow_path`` action, each goal a path that `reference.follow_path.PathFollower`
moves into ``odom`` through ``/tf`` and follows like a ``plan``, with feedback, Nav2's result codes, cancel,
preemption and the goal and progress checks of parameters ``follow_path.*``). It steps once a control period, as
the preview is published. docs/howto/nav2.md has the setup.

Timing
------
The decisions below are `loop.reference_clock`'s (`RealtimeStart`, `LockstepPreviews`); the node reads the clock,
the graph and ``controller_enabled`` for them and publishes what they answer.

``realtime``: a timer on the node clock (sim time when ``use_sim_time``)
publishes the preview every control period (every ``preview_every`` periods, each preview that many points
longer less one, so that it holds the reference until the next: a fleet's previews are then a tenth of its
messages; ``follow_path`` steps at that rate too); the reference starts (t = 0)
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

Starting on the enable, from where the robot stands (realtime)
--------------------------------------------------------------
``start_on_enable``: once the start condition above holds, the node holds the reference's start until the
controller's ``controller_enabled`` is true, and the reference's t = 0 is the moment that message arrives
(not the next timer tick). While it holds, it publishes every period the preview of the start point at rest
(all N + 1 points the reference's pose at t = 0, zero velocities and accelerations), so the disabled
controller has a fresh reference at the enable, its watchdog says ``ok``, and its first enabled ticks hold the
robot where the reference starts. A disable (``controller_enabled`` false) returns the node to the hold: the
reference is made anew (goals dropped) and the next enable starts it again from t = 0.

``anchor_to_robot``: at the start the scenario's reference is moved rigidly onto the robot's pose from the
newest ``odom`` (`reference.anchor`: x, y rotated by its heading, the heading added), so it starts exactly at
the robot's pose, at rest; the hold previews follow that pose until then (a robot moved while disabled
starts where it then stands), and the start waits for a first odometry. ``reference_path`` is published
at the start, anchored. In scenario ``goals`` the held start pose is the robot's and goals and paths stay
absolute poses in ``odom``; ``goal_pose`` and ``plan`` are subscribed from the start on (a goal needs the start
pose it moves from), dropped again at a return to the hold.

Both are realtime features (a real robot, started disabled): in lockstep the plant's /clock drives the
reference and the simulated robot starts at the origin with it, so a lockstep node with either true refuses
to start (exit status 2). Both false (the defaults): the reference starts as described under Timing.

Parameters: ``control.period_s`` and ``control.horizon`` of config/*.yaml
(``/**`` section; fixed while the node runs, as are ``mode``, ``clock_timeout_s``, ``start_on_enable`` and
``anchor_to_robot``), the robot's (the wheel kinematics and the motor's nominal speed bound the goal motions),
`TRAJECTORY_SPECS`, `nodes.goal_inputs.GOAL_SPECS`, `nodes.follow_path_server.FOLLOW_PATH_SPECS` and ``waypoints``
(a flat list x1, y1, theta1, x2, ... for
point-to-point; empty: the scenario's default).
``scenario`` is a name of `robotino_geom_mpc.scenarios.SCENARIOS`; the node
tracks its reference (``robustness``: paper-circle; the mismatch and the
noise are the controller's and the plant's parameters).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from nav_msgs.msg import Path
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import PublisherEventCallbacks, QoSPublisherMatchedInfo
from rclpy.node import Node
from nav_msgs.msg import Odometry
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription
from rosgraph_msgs.msg import Clock as ClockMsg
from std_msgs.msg import Bool
from trajectory_msgs.msg import MultiDOFJointTrajectory

from robotino_geom_mpc.loop.reference_clock import LockstepPreviews, RealtimeStart, Tick, path_stamps
from robotino_geom_mpc.nodes.follow_path_server import FOLLOW_PATH_DEFAULTS, FOLLOW_PATH_SPECS, FollowPathServer
from robotino_geom_mpc.reference.anchor import anchored
from robotino_geom_mpc.reference.frames import TransformTree
from robotino_geom_mpc.reference.goals import GoalReference
from robotino_geom_mpc.reference.path_timing import load_splines
from robotino_geom_mpc.params.specs import ALL_SPECS, ParamSpec
from robotino_geom_mpc.nodes.goal_inputs import GOAL_DEFAULTS, GOAL_SPECS, GoalInputs, goal_params_problem
from robotino_geom_mpc.reference.trajectories import Reference, TrajectoryError
from robotino_geom_mpc.ros.cdr import CdrLayout, CdrTemplate, MalformedMessage, cdr_reader
from robotino_geom_mpc.ros.decode import InputRejected, check_yaw_quaternion, odometry_values, time_ns, yaw_of
from robotino_geom_mpc.ros.messages import ODOM_FRAME, odometry_layout, path_cdr, point_values, preview_template, \
    preview_values
from robotino_geom_mpc.ros.parameters import NodeStartError, SpecParameters, spec_defaults
from robotino_geom_mpc.ros.qos import CLOCK_SUB_QOS, LATCHED_QOS, publish_acknowledged, publish_qos
from robotino_geom_mpc.ros.spin import monotonic, run_node
from robotino_geom_mpc.scenarios import SCENARIOS, get_scenario
from robotino_geom_mpc.ros.throttle import warn_throttled
from robotino_geom_mpc.ros.tf_listener import TransformListener

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
    ParamSpec("preview_every", int, "Realtime: publish the preview every this many control periods, each with "
              "preview_every - 1 more points, so that it covers the odometries until the next (the controller takes "
              "its rows of the periods elapsed); fewer messages for a fleet. The controller's reference_timeout_s "
              "must exceed preview_every control periods", "", 1, 100, False),
    ParamSpec("start_on_enable", bool, "Realtime: hold the reference's start (its t = 0 point, at rest) until the "
              "controller's controller_enabled is true, and start t = 0 then; a disable holds again"),
    ParamSpec("anchor_to_robot", bool, "Realtime: move the scenario rigidly onto the robot's pose (newest odom) at "
              "the start, so the reference starts where the robot stands, at rest (goals: hold that pose)"),
)
_DEFAULTS = {"scenario": "paper-circle", "mode": "realtime", "start_settle_s": 1.0, "clock_timeout_s": 5.0,
             "preview_points": 0, "preview_every": 1, "start_on_enable": False, "anchor_to_robot": False}
_FIXED = ("mode", "control.period_s", "control.horizon", "clock_timeout_s", "preview_points", "preview_every",
          "start_on_enable", "anchor_to_robot")
_REALTIME_ONLY = ("start_on_enable", "anchor_to_robot")
# the robot's pose for the anchor: only the newest odometry matters, from any publisher (best effort reads both)
_POSE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
_read_odom = cdr_reader(Odometry, "nav_msgs/msg/Odometry")  # odometry in frames the in-place layout does not read
_GOAL_PATH_STEP = 5  # after a goal, reference_path has a pose every this many control periods
_WAIT_LOG_PERIOD_S = 5.0  # at most one "waiting for /clock" line per this long (or per clock_timeout_s if longer)


def _params_problem(given: dict) -> str | None:
    """Why the node's parameters cannot run: the goal limits' problem, or a realtime feature (``preview_every`` > 1
    too) in lockstep.
    """
    on = [name for name in _REALTIME_ONLY if given[name]]
    if given["mode"] == "lockstep" and given["preview_every"] > 1:
        return ("preview_every > 1 is a realtime feature: in lockstep the controller pairs each tick with the preview "
                "of its stamp; set it to 1 or use mode realtime")
    if given["mode"] == "lockstep" and on:
        return (f"{' and '.join(on)} {'is a realtime feature' if len(on) == 1 else 'are realtime features'} (a "
                "real robot started disabled): in lockstep the plant's /clock drives the reference and the simulated "
                "robot starts at the origin with it; set them false or use mode realtime")
    return goal_params_problem(given)


def _same_waypoints(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    """Whether two ``waypoints`` values are the same (None: the scenario's default)."""
    return a is None and b is None or a is not None and b is not None and np.array_equal(a, b)


class TrajectoryNode(Node):
    """The trajectory node (see the module docstring for its interface)."""

    def __init__(self, **node_options: Any) -> None:
        """`node_options`: rclpy's `Node` options (a fleet's robot: its ``namespace`` and parameter overrides)."""
        super().__init__("robotino_trajectory", **node_options)
        specs = ALL_SPECS + TRAJECTORY_SPECS + GOAL_SPECS + FOLLOW_PATH_SPECS
        self.params = SpecParameters(
            self, specs, {**spec_defaults(ALL_SPECS), **_DEFAULTS, **GOAL_DEFAULTS, **FOLLOW_PATH_DEFAULTS},
            self._on_params, fixed=_FIXED,
            check=_params_problem,
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
        lockstep = self.params["mode"] == "lockstep"  # the mode, chosen here once
        self.start_on_enable, self.anchor_to_robot = self.params["start_on_enable"], self.params["anchor_to_robot"]
        self.anchor: tuple[float, float, float] | None = None  # anchor_to_robot: the pose at the start
        # the timing (`loop.reference_clock`): realtime the start; lockstep the ticks, t = 0 at simulated time 0
        self.start = RealtimeStart(self.params["start_settle_s"], self.start_on_enable, 0 if lockstep else None)
        self.ticks = LockstepPreviews(self.params["control.period_s"])
        reference_time = self._tick_time if lockstep else self._time_since_start
        self.goals = GoalInputs(self, self.params.values, reference_time, self._replanned)
        self.robot_pose: tuple[float, float, float] | None = None  # from the newest odometry (`_watch_robot`)
        self.odom_sub: Subscription | None = None
        self.frames = TransformTree()  # /tf and /tf_static (goals only: `_use_reference`)
        self.tf_listener: TransformListener | None = None
        self.follow_path = FollowPathServer(self, self.params.values, reference_time, lambda: self.robot_pose,
                                            self._replanned, self.frames.lookup,
                                            lambda: self.params["frame_prefix"] + ODOM_FRAME)
        try:
            self._use_reference()
        except TrajectoryError as exc:
            raise NodeStartError(str(exc)) from None
        self.preview_pub = self.create_publisher(
            MultiDOFJointTrajectory, "reference_preview", publish_qos(lockstep),
            event_callbacks=PublisherEventCallbacks(matched=self._on_preview_matched) if lockstep else None,
        )
        self.path_pub = self.create_publisher(Path, "reference_path", LATCHED_QOS)
        self.odom_topic = self.resolve_topic_name("odom")  # realtime: its publisher is part of the start condition
        if self.anchor_to_robot:
            self._watch_robot()
        self.holding = False  # start_on_enable: publishing the start at rest, waiting for the enable
        self.hold_checked_at = 0.0  # steady time the hold last looked for a publisher of controller_enabled
        if self.start_on_enable:
            self.enabled_sub = self.create_subscription(Bool, "controller_enabled", self._on_enabled, LATCHED_QOS)
        self.preview_cdr: CdrTemplate | None = None  # built on first use (horizon and period fixed)
        self.grid: np.ndarray | None = None  # lockstep: point values at k Ts (`_grid_values`)
        if lockstep:
            self.clock_layout = CdrLayout(ClockMsg(), ("clock.sec", "clock.nanosec"))  # read in place
            self.clock_sub = self.create_subscription(ClockMsg, "/clock", self._on_clock, CLOCK_SUB_QOS, raw=True)
            self.clock_heard_at = monotonic()  # steady time of the last /clock (of the start before the first)
            self.clock_watch = self.create_timer(self.params["clock_timeout_s"] / 2, self._check_clock,
                                                 clock=Clock(clock_type=ClockType.STEADY_TIME))
        else:
            self.timer = self.create_timer(self.params["control.period_s"] * self.params["preview_every"],
                                           self._on_timer)
        if self.start.start_ns is not None:
            self._publish_path(self.start.start_ns)
        starts = ("; starts on the controller's enable" if self.start_on_enable else "") + \
            ("; anchored at the robot's pose" if self.anchor_to_robot else "")
        self.get_logger().info(
            f"trajectory '{self.params['scenario']}' (reference {self.reference.name}, "
            f"{self.reference.duration_s:g} s, N = {self.params['control.horizon']}, {self.params['mode']}){starts}"
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
        if any(p.name == "waypoints" for p in params) and not _same_waypoints(self._waypoints(), self.waypoints):
            self._new_reference()  # (None: the scenario's default)

    def _new_reference(self) -> None:
        self._use_reference()
        self._replanned(self.reference)

    def _use_reference(self) -> None:
        """The scenario's reference of the current parameters, anchored once the anchor is known.

        Anchored to the robot, goals are taken from the start on only (they move from the robot's pose).
        """
        self.waypoints = self._waypoints()
        self.scenario_reference = self._make_reference(self.params["scenario"], self.waypoints)
        self.reference = self.scenario_reference if self.anchor is None else \
            anchored(self.scenario_reference, self.anchor)
        self.grid = None
        goals = None if self.anchor_to_robot and self.anchor is None else self.reference
        self.goals.attach(goals)
        self.follow_path.attach(goals)
        if isinstance(goals, GoalReference):
            self._watch_robot()
            if self.tf_listener is None:  # follow_path's paths in other frames (an anchor needs no transforms)
                self.tf_listener = TransformListener(self, self.frames)
            load_splines()  # not at the first path, while the previews wait

    def _watch_robot(self) -> None:
        """Subscribe (once) the robot's odometry (`robot_pose`)."""
        if self.odom_sub is not None:
            return
        self.odom_layout = odometry_layout(self.params["frame_prefix"])
        self.odom_sub = self.create_subscription(Odometry, "odom", self._on_odom, _POSE_QOS, raw=True)

    def _tick_time(self) -> float:
        """Lockstep: the reference time [s] a goal starts at, the latest tick published."""
        return self.ticks.reference_s()

    def _time_since_start(self) -> float:
        """Realtime: the reference time [s] a goal starts at, now (0 before the start)."""
        return self.start.reference_s(self.get_clock().now().nanoseconds)

    def _replanned(self, reference: GoalReference | Reference) -> None:
        """The reference changed: rebuild the lockstep table, publish the path again.

        After a goal or path only the new motion is published, every `_GOAL_PATH_STEP` periods: a path
        of the whole run would stall the previews for as long as its thousands of poses take to build.
        """
        self.grid = None
        start = self.start.start_ns
        if start is None:
            return
        if isinstance(reference, GoalReference) and reference.pieces:
            self._publish_path(start, reference.starts[-1], _GOAL_PATH_STEP)
        else:
            self._publish_path(start)

    # publishing ---------------------------------------------------------------------------------
    def _grid_values(self, t_ns: int) -> list[float] | None:
        """Lockstep: the preview values of a tick on the grid k Ts, sliced from a table sampled once (None off it).

        The table is the reference sampled at every tick in one vectorised call, as
        `simulation.run_scenario` samples its targets, so the positions are those of the offline loop.
        """
        period_s, horizon = self.params["control.period_s"], self._preview_points()
        k = self.ticks.grid_index(t_ns)
        if self.grid is None:
            times = np.arange(int(self.reference.duration_s / period_s) + horizon + 2) * period_s
            self.grid = point_values(*self.reference.sample(times)[:3])
        if k is None or k + horizon >= len(self.grid):
            return None
        return self.grid[k : k + horizon + 1].ravel().tolist()

    def _preview_points(self) -> int:
        """Points after the first: ``preview_points`` (or N), and ``preview_every`` - 1 more to cover its period."""
        return (self.params["preview_points"] or self.params["control.horizon"]) + self.params["preview_every"] - 1

    def _publish_preview(self, t_ns: int, reference_t_ns: int, values: list[float] | None = None) -> None:
        """The preview stamped `t_ns` of the reference at `reference_t_ns` (or of the point `values`: lockstep, the
        grid's, `_grid_values`; None off it).
        """
        period_s, horizon = self.params["control.period_s"], self._preview_points()
        if self.preview_cdr is None:
            self.preview_cdr = preview_template(period_s, horizon, self.params["frame_prefix"])
        if values is None:
            values = preview_values(self.reference, reference_t_ns, period_s, horizon)
        publish_acknowledged(self, self.preview_pub, self.preview_cdr.pack(*divmod(t_ns, 1_000_000_000), *values))
        self.ticks.published(t_ns)

    def _on_clock(self, data: bytes) -> None:
        values = self.clock_layout.read(data)
        if values is None:  # every well-formed Clock has the layout
            warn_throttled(self.get_logger(), f"undecodable /clock ({len(data)} bytes) ignored", 1.0)
            return
        self.clock_heard_at = monotonic()
        self._publish_ticks(self.ticks.on_clock(time_ns(values[0], values[1])))
        self.follow_path.tick()

    def _check_clock(self) -> None:
        """Lockstep: say what the node waits for when /clock has been silent for ``clock_timeout_s``."""
        waited = monotonic() - self.clock_heard_at
        timeout = self.params["clock_timeout_s"]
        if waited < timeout:
            return
        topic = self.clock_sub.topic_name
        last_s = self.ticks.last_clock_s()
        last = "none" if last_s is None else f"{last_s:g} s"
        warn_throttled(
            self.get_logger(),
            f"lockstep: no clock on {topic} for {waited:.1f} s (last tick: {last}): waiting for the plant's next "
            f"tick ({self.count_publishers(topic)} publisher(s) of {topic}); previews follow each clock",
            max(timeout, _WAIT_LOG_PERIOD_S),
        )

    def _on_preview_matched(self, info: QoSPublisherMatchedInfo) -> None:
        """Lockstep: a new subscription gets the previews of the current tick (those sent before missed it)."""
        if info.current_count_change > 0:
            self._publish_ticks(self.ticks.on_matched())

    def _publish_ticks(self, stamps: list[int]) -> None:
        """Lockstep: the previews of the ticks `stamps` (`LockstepPreviews`), from the table of the grid."""
        for stamp in stamps:
            self._publish_preview(stamp, stamp, self._grid_values(stamp))

    def _on_timer(self) -> None:
        now = self.get_clock().now().nanoseconds
        tick = self.start.tick(now, self._ready)
        if tick is Tick.HOLD:
            self._hold(now)
        elif tick is Tick.START:
            self._start(now)
        elif tick is Tick.RUN:
            self._publish_preview(now, self.start.reference_ns(now))
            self.follow_path.tick()

    def _ready(self) -> bool:
        """Realtime: the start condition (module docstring, Timing): a controller listens to the preview, the robot
        sends odometry (and with ``anchor_to_robot`` its pose is known); `RealtimeStart` waits the settle time.
        """
        return self.preview_pub.get_subscription_count() > 0 and self.count_publishers(self.odom_topic) > 0 and \
            not (self.anchor_to_robot and self.robot_pose is None)

    def _start(self, now: int) -> None:
        """Realtime: t = 0 of the reference at `now` (`RealtimeStart` says so), anchored at the robot's pose with
        ``anchor_to_robot``.
        """
        self.holding = False
        pose = self.robot_pose  # (`_ready` waits for one with anchor_to_robot)
        if self.anchor_to_robot and pose is not None:
            self.anchor = pose
            self._use_reference()
            x, y, theta = pose
            self.get_logger().info(f"reference anchored at the robot's pose ({x:.4f} m, {y:.4f} m, {theta:.4f} rad)")
        if self.start_on_enable:
            self.get_logger().info("the controller is enabled: the reference starts (t = 0)")
        self._publish_preview(now, 0)  # the loop's data first: the path is for the tools
        self._publish_path(now)

    def _hold(self, now: int) -> None:
        """start_on_enable: the preview of the reference's start point at rest (anchored: at the robot's pose)."""
        start = self.scenario_reference if self.robot_pose is None or not self.anchor_to_robot else \
            anchored(self.scenario_reference, self.robot_pose)
        points = self._preview_points() + 1
        positions = np.tile(start.position(0.0), (points, 1))
        self._publish_preview(now, 0, point_values(positions, np.zeros((points, 3)), np.zeros((points, 3)))
                              .ravel().tolist())
        topic = self.enabled_sub.topic_name
        if not self.holding:
            self.holding, self.hold_checked_at = True, monotonic()
            self.get_logger().info(f"holding the reference's start at {np.round(positions[0], 4).tolist()} until "
                                   f"{topic} is true (the controller's enable)")
        elif monotonic() - self.hold_checked_at > _WAIT_LOG_PERIOD_S:  # (a graph query: not every period)
            self.hold_checked_at = monotonic()
            if self.count_publishers(topic) == 0:
                self.get_logger().warn(f"holding the reference's start: no publisher of {topic} (a controller of "
                                       "this package says there whether it is enabled)")

    def _on_enabled(self, msg: Bool) -> None:
        """start_on_enable: start at the enable (if the start condition holds, else at the tick it does); a
        disable after the start returns to the hold with the reference made anew.
        """
        now = self.get_clock().now().nanoseconds
        change = self.start.on_enabled(bool(msg.data), now, self._ready)
        if change is Tick.START:
            self._start(now)
        elif change is Tick.HOLD:
            self.anchor = None
            self._use_reference()  # (goals dropped)
            self.get_logger().info("the controller is disabled: the reference holds its start again until the "
                                   "next enable")

    def _on_odom(self, data: bytes) -> None:
        """The robot's pose (x, y, yaw) of an odometry; a malformed one is refused (logged)."""
        try:
            values = self.odom_layout.read(data)
            if values is None:
                values = odometry_values(_read_odom(data))
            x, y, qx, qy, qz, qw = values[2:8]
            if not np.isfinite([x, y, qx, qy, qz, qw]).all():
                raise InputRejected("odom contains non-finite values", "non_finite")
            check_yaw_quaternion(qx, qy, qz, qw, "odom")
        except (MalformedMessage, InputRejected) as exc:
            warn_throttled(self.get_logger(), f"odometry refused (the robot's pose): {exc}", 1.0)
            return
        self.robot_pose = (x, y, yaw_of(qx, qy, qz, qw))

    def _publish_path(self, start_ns: int, from_s: float = 0.0, step: int = 1) -> None:
        """The reference path from `from_s` [s] on, every `step` periods, for a t = 0 at `start_ns` (node clock)."""
        period = self.params["control.period_s"] * step
        times = np.arange(from_s, self.reference.duration_s + 0.5 * period, period)
        stamps = path_stamps(start_ns, times.tolist())
        odom = self.params["frame_prefix"] + ODOM_FRAME
        publish_acknowledged(self, self.path_pub, path_cdr(odom, start_ns, stamps, self.reference.position(times)))

def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run robotino_geom_mpc trajectory_node``."""
    return run_node(TrajectoryNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
