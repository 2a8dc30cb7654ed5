"""The controller node's own parameters and the refusals they steer (the loop decides: `loop.controller_loop`).

Plain Python (no rclpy): the specs, their defaults, what cannot change while the node runs, and the check of a
parameter set (`closed_loop_problem`). The input checks are `loop.inputs`'s, made by the controller loop.

Bad input (`loop.inputs` and `control.motion_controller.MotionController.state_problem` check the values read):

* refused, with zero volts, an ERROR diagnostic naming the reason key, a
  throttled warning and ``rejected`` counted: non-finite values
  (``non_finite``), a wrongly sized preview (``size``), undecodable bytes
  (``malformed``), a stamp that is no time (``stamp``: sec < 0 or nanosec
  outside [0, 1e9)), a quaternion whose norm is off 1 by more than
  ``quaternion_norm_tolerance`` (``quaternion_norm``: the all-zero one, or
  (0, 0, 0.5, 0.5)) or that tilts the robot by more than
  ``tilt_tolerance_rad`` (``quaternion_tilt``), on odometry and on every
  preview point; a measurement no robot on its wheels gives (``implausible``:
  a twist whose motor speeds exceed twice the no-load speed U_supply / Km, a
  pose or preview position beyond 1000 km); a preview whose frame_id is not
  the controller's ``<frame_prefix>odom`` (``frame``); in realtime, a stamp older than
  ``odom_timeout_s`` (preview: ``reference_timeout_s``) against the node clock
  (``stale``: an hour old, or zero) or ahead of it by more than
  ``future_tolerance_s`` (``future``). In lockstep a refused preview makes the
  tick of its stamp get zero volts (reason ``preview_<reason>``). A step that
  fails all the same (a bug) gives zero volts, an ERROR log with the traceback
  (reason ``internal_error``) and a bumpless restart at the next tick;
* dropped, counted (``dropped_duplicate``, ``dropped_old``), with a WARN
  diagnostic and no output (a newer input was used already): an odometry
  (realtime: also a preview) whose stamp equals the last used one
  (``duplicate``; in lockstep the plant's resend, which only releases answers
  still held for their readers, `controller_outputs`: none is sent twice) or
  is older (``old``: a late message). If nothing valid follows, the watchdog gives zero volts after
  the timeout.

Stale data: a watchdog checks the arrival age of the accepted odometry and
preview, in steady time, or in node-clock time under ``use_sim_time`` (a slow
simulation is slow, not stale): older than ``odom_timeout_s`` / ``reference_timeout_s``
means (realtime) zero volts (with plans also a plan of zeros, which replaces
the plans the robot holds), a throttled warning, the watchdog state in the
diagnostics, and a bumpless restart when data return; the stamps used so far
are forgotten then, so inputs stamped before them are taken (a clock that went
back: a simulator reset, a bag replayed in a loop). In lockstep the plant
holds the time, so the watchdog only reports, and a controller that has heard
nothing for a timeout (no odometry, or an odometry waiting for its preview)
logs what it waits for (every 5 s).

Stop: a realtime controller that stops (SIGINT, SIGTERM, or a failed
callback) sends zero volts (a zero twist) as its last command (with plans also
a plan of zeros; ``publish_plain_command`` false: that plan only).
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

from robotino_geom_mpc.control.motion_controller import MotionController
from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.control.mpc import check_closed_loop
from robotino_geom_mpc.params.specs import LOOP_SPECS, ParamSpec, params_from_values
from robotino_geom_mpc.loop.controller_loop import LoopSettings

__all__ = ["CONTROLLER_DEFAULTS", "CONTROLLER_SPECS", "FIXED_WHILE_RUNNING", "closed_loop_problem"]

CONTROLLER_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("mode", str, "realtime: freshest preview, watchdog outputs zero volts; "
              "lockstep: preview of the same stamp",
              choices=("realtime", "lockstep")),
    *LOOP_SPECS,
    ParamSpec("frame_prefix", str, "Prefix of the odom frame of predicted_path (e.g. 'robot1/'; '' for 'odom')"),
    ParamSpec("command_interface", str, "voltages: wheel_voltages (std_msgs/Float64MultiArray) to the DC drives; "
              "cmd_vel: the MPC's base_link velocity for the next period (geometry_msgs/Twist) to a velocity-"
              "controlled base", choices=("voltages", "cmd_vel")),
    ParamSpec("plans", bool, "Off-board over a network: per odometry a delay-compensated plan of control.plan_length "
              "commands on wheel_voltage_plan / cmd_vel_plan (the plain command, unless publish_plain_command is "
              "false, carries its first entry; a zero is also a plan of zeros that outlasts the plans sent); reads "
              "command_applied (loop.controller_loop)"),
    ParamSpec("publish_plain_command", bool, "With plans: also publish the plain command (wheel_voltages / cmd_vel: "
              "the plan's first entry, zero when disabled or on a refused input) for observers; false where a "
              "robot-side command buffer drives the robot's cmd_vel from the plans (the controller's would be a "
              "second, delayed source on the driver's topic). Without plans it must stay true"),
    ParamSpec("publish_predicted_path", bool, "Publish predicted_path (the MPCs' predicted poses, computed only while "
              "a subscription is matched; the report does not read it)"),
    ParamSpec("lockstep_command_readers", int, "Lockstep: readers of the topic the plant reads its answers on "
              "(wheel_voltages / cmd_vel; with plans the plan topic) that its publisher must have matched before the "
              "first answer goes out; the answers are held until then: the plant's, and a recorder's or a live "
              "view's (an answer sent while only some had matched never reaches the others)", "", 1, 1000, False),
    ParamSpec("start_enabled", bool, "false: the node starts disabled, as after ~/enable false (zero volts / zero "
              "twist every tick, diagnostic 'disabled') until ~/enable true, then tracks bumplessly"),
)
CONTROLLER_DEFAULTS: dict[str, Any] = {
    "mode": "realtime", **asdict(LoopSettings()),
    "frame_prefix": "", "command_interface": "voltages", "plans": False, "start_enabled": True,
    "publish_predicted_path": True, "publish_plain_command": True, "lockstep_command_readers": 1,
}
# the mode, the outputs, and what must agree with the trajectory node (the preview's layout)
FIXED_WHILE_RUNNING = ("mode", "frame_prefix", "command_interface", "control.period_s", "control.horizon", "plans",
                       "control.plan_length", "control.lead_max_periods",
                       "start_enabled",  # (a start value: ~/enable switches a running node)
                       "publish_predicted_path", "publish_plain_command", "lockstep_command_readers")


def closed_loop_problem(values: dict[str, Any]) -> str | None:
    """Why the candidate parameter values cannot run, or None.

    A timeout shorter than two control periods (every tick's input would be stale, and the
    watchdog's timer would run at half of it), an unstable nominal closed loop, a model the
    controller cannot be built on (e.g. a singular T(theta)), or no output at all (no plans and no
    plain command): refused before the node takes them.
    """
    if not values["plans"] and not values["publish_plain_command"]:
        return "parameter 'publish_plain_command' false needs 'plans' true: the controller would send nothing"
    period = values["control.period_s"]
    for name in ("odom_timeout_s", "reference_timeout_s"):
        if values[name] < 2.0 * period:
            return (f"parameter '{name}' = {values[name]:g} s is shorter than two control periods "
                    f"({2.0 * period:g} s): every input would be stale")
    try:
        robot, control = params_from_values(values, "parameters of the controller")
        check_closed_loop(robot, control)
        MotionController(robot, control)
    except RobotinoError as exc:  # UnstableClosedLoopError, ParamError, GeometryError, ...
        return str(exc)
    return None
