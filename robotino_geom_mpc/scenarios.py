"""The scenario registry: what each named run tracks, how the controller's model is off, how noisy odometry is.

A scenario is the one place that says, for a name given to ``simulate``,
``run``, the trajectory node or the launch file:

* the reference it tracks: a key of `reference.trajectories.REFERENCES` plus options
  of that reference's class;
* the controller's model mismatch: factors on mass, yaw inertia and body
  friction of the controller's model over the true robot
  (`params.specs.RobotinoParams.scaled`), or none;
* the odometry noise: standard deviations of the measured position [m] and
  yaw [rad] (the plant's Gaussian noise);
* the default run length: the reference's own duration.

``paper-circle-step`` is the circle as the paper ran it: at full speed from
rest (no ramp-in), the start transient of its Fig. 6.

``goals`` holds the start pose until goals (geometry_msgs/PoseStamped on
``goal_pose``) and planner paths (nav_msgs/Path on ``plan``) arrive at the
trajectory node (`reference.goals.GoalReference`; offline, without goals,
it holds for its 10 s).

``wifi`` runs paper-circle over a WiFi-like radio link (`WIFI_LINK`, each way) between
the robot and the off-board nodes: the controller then sends plans (`control.delay_compensation`).

``robustness`` runs paper-circle with a controller whose model is off:
mass +20 %, yaw inertia -20 % (the two errors push the translational and
rotational loops in opposite directions), body friction twice the true one,
and odometry noise 1 mm / 1 mrad.

`node_parameters` turns a scenario into the ROS parameter overrides of each
node, so the offline loop (`simulation.run_scenario`), ``run`` and the launch
file agree. Plain Python: no rclpy.
"""

from __future__ import annotations

import difflib
from dataclasses import asdict, dataclass
from typing import Any

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.network.link import LinkParams
from robotino_geom_mpc.params.specs import ROBOT_SPECS, RobotinoParams
from robotino_geom_mpc.reference.goals import GoalReference
from robotino_geom_mpc.reference.trajectories import Reference, make_reference

__all__ = [
    "ScenarioError",
    "ModelMismatch",
    "OdometryNoise",
    "Scenario",
    "SCENARIOS",
    "get_scenario",
    "node_parameters",
]


class ScenarioError(RobotinoError, ValueError):
    """An unknown scenario name (the message suggests the closest one and lists all)."""


@dataclass(frozen=True)
class ModelMismatch:
    """Factors of the controller's model over the true robot (`RobotinoParams.scaled`)."""

    mass: float = 1.0
    inertia: float = 1.0
    friction: float = 1.0


@dataclass(frozen=True)
class OdometryNoise:
    """Standard deviations of the odometry noise: position x, y [m] and yaw [rad]."""

    position_m: float = 0.0
    yaw_rad: float = 0.0


@dataclass(frozen=True)
class Scenario:
    """One named scenario.

    Attributes
    ----------
    name
        The name the command line, the nodes and the launch file use.
    description
        One line for help texts.
    reference
        The tracked reference: a key of `reference.trajectories.REFERENCES`, or ``goals`` (`GoalReference`).
    reference_options
        (option, value) pairs for that reference's class; empty: its defaults.
    mismatch
        The controller's model over the true robot; None: the controller knows the robot.
    noise
        The odometry noise the plant adds.
    link
        The radio link between the robot and the off-board nodes, the same each way
        (`network.link.LinkParams`); None: the nodes talk without one.
    """

    name: str
    description: str
    reference: str
    reference_options: tuple[tuple[str, Any], ...] = ()
    mismatch: ModelMismatch | None = None
    noise: OdometryNoise = OdometryNoise()
    link: LinkParams | None = None

    def make_reference(self, **options: Any) -> Reference:
        """The scenario's reference; `options` (e.g. point-to-point ``waypoints``) override its own."""
        if self.reference == "goals":
            return GoalReference(**{**dict(self.reference_options), **options})
        return make_reference(self.reference, **{**dict(self.reference_options), **options})

    @property
    def duration_s(self) -> float:
        """The default run length [s]: the reference's duration."""
        return self.make_reference().duration_s

    def controller_model(self, robot: RobotinoParams) -> RobotinoParams:
        """The robot model the controller uses when `robot` is the truth."""
        return robot if self.mismatch is None else robot.scaled(**asdict(self.mismatch))


_MISMATCH = ModelMismatch(mass=1.2, inertia=0.8, friction=2.0)

WIFI_LINK = LinkParams(delay_s=0.015, jitter_s=0.015, loss=0.05, burst_length=3.0)
"""A WiFi-like link, each way: 15-30 ms one way (a loaded 2.4 GHz cell with a few stations and retries; a quiet
one is 2-5 ms), 5 % of the packets lost in bursts of 3 on average (fading, a station roaming or scanning)."""

SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario("paper-circle", "the paper's circle (Figs. 4-6): radius 0.5 m, 10 s a lap, theta_d = 0",
                 "paper-circle"),
        Scenario("paper-circle-step", "the paper's start: paper-circle at full speed (0.31 m/s) from rest, no "
                 "ramp-in (2 laps, 21 s): the start current transient of its Fig. 6", "paper-circle",
                 reference_options=(("ramp_in", False),)),
        Scenario("lemniscate", "a figure-eight 1 m wide, 20 s a lap, theta_d along the path", "lemniscate"),
        Scenario("point-to-point", "rest-to-rest moves through waypoints (x, y, theta)", "point-to-point"),
        Scenario("robustness", "paper-circle with the controller's model off (mass x1.2, yaw inertia x0.8, "
                 "body friction x2) and odometry noise 1 mm / 1 mrad", "paper-circle",
                 mismatch=_MISMATCH, noise=OdometryNoise(position_m=1e-3, yaw_rad=1e-3)),
        Scenario("wifi", "paper-circle over a WiFi-like link: 15 ms plus up to 15 ms each way, 5 % loss in "
                 "bursts of 3 packets", "paper-circle", link=WIFI_LINK),
        Scenario("goals", "hold the pose until goals (goal_pose) and planner paths (plan) arrive; C^3 motions "
                 "within velocity, acceleration, jerk and rim-speed limits", "goals"),
    )
}


def get_scenario(name: str) -> Scenario:
    """The scenario called `name`.

    Raises
    ------
    ScenarioError
        For an unknown name, with the closest valid name when there is one.
    """
    try:
        return SCENARIOS[name]
    except (KeyError, TypeError):
        close = difflib.get_close_matches(str(name), SCENARIOS, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ScenarioError(f"unknown scenario {name!r}{hint} (valid: {', '.join(SCENARIOS)})") from None


def node_parameters(scenario: str | Scenario, robot: RobotinoParams) -> dict[str, dict[str, Any]]:
    """The ROS parameter overrides a scenario gives each node, on top of the run's parameter file.

    Parameters
    ----------
    scenario
        A scenario or its name.
    robot
        The robot of the parameter file (the truth the controller's model is scaled from).

    Returns
    -------
    dict
        ``{"plant_node": ..., "controller_node": ..., "trajectory_node": ...}``: the plant's
        ``odometry_noise.*`` (and ``link.up.*`` / ``link.down.*`` for a scenario over a link); the
        controller's robot parameters (the config/*.yaml names, e.g.
        ``robot.mass_kg``) that its mismatched model changes; the trajectory's ``scenario``.

    Raises
    ------
    ScenarioError
        For an unknown name.
    """
    if not isinstance(scenario, Scenario):
        scenario = get_scenario(scenario)
    model = scenario.controller_model(robot)
    return {
        "plant_node": {
            "odometry_noise.position_m": float(scenario.noise.position_m),
            "odometry_noise.yaw_rad": float(scenario.noise.yaw_rad),
            **({f"link.{way}.{name}": value for way in ("up", "down") for name, value in asdict(scenario.link).items()}
               if scenario.link is not None else {}),
        },
        "controller_node": {
            spec.name: getattr(model, spec.attr)
            for spec in ROBOT_SPECS
            if getattr(model, spec.attr) != getattr(robot, spec.attr)
        },
        "trajectory_node": {"scenario": scenario.name},
    }
