"""The fleet's plain parts: the ``robots`` parameter, the processes' arguments, the lockstep fleet's one clock."""

import pytest

from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.ros.fleet import fleet_namespaces
from robotino_geom_mpc.system.processes import FLEET_NODES, fleet_arguments, node_arguments, robot_names
from robotino_sim_node.plant_lockstep import FleetClock

pytestmark = pytest.mark.unit


def test_robots_are_valid_distinct_namespaces():
    assert fleet_namespaces(["robot1", "/robot2", "team/robot3"]) == ["/robot1", "/robot2", "/team/robot3"]
    for bad, reason in ((["robot1", "/robot1"], "named twice"), ([], "no robot"), (["1robot"], "valid ROS name"),
                        ([""], "no namespace")):
        with pytest.raises(ValueError, match=reason):
            fleet_namespaces(bad)


def _params(argv):
    """The ``-p name:=value`` overrides of `argv` as a dict of strings."""
    return dict(argv[i + 1].split(":=", 1) for i in range(len(argv)) if argv[i] == "-p")


def test_fleet_arguments_are_the_single_runs_plus_the_robots():
    params = default_params_file()
    fleet = fleet_arguments("robustness", params, 2.0, True, 3, seed=5, bag="/tmp/bag")
    single = node_arguments("robustness", params, 2.0, True, 5, "/tmp/bag")
    assert list(fleet) == ["recorder_node", "fleet_trajectory_node", "fleet_controller_node", "fleet_plant_node"]
    assert list(fleet) == [FLEET_NODES[name] for name in single if name in FLEET_NODES]
    assert "robots" not in _params(fleet["recorder_node"])
    for name in ("trajectory_node", "controller_node", "plant_node"):
        got, want = _params(fleet[FLEET_NODES[name]]), _params(single[name])
        assert got.pop("robots") == '["robot1","robot2","robot3"]'
        if name == "plant_node":  # the fleet's one /clock: three trajectory readers and the recorder's
            waits, single_waits = got.pop("lockstep_wait_for"), want.pop("lockstep_wait_for")
            assert '"/clock:4"' in waits and '"/clock:2"' in single_waits
            assert '"joint_states:1"' in waits  # no description publisher in a fleet
        assert got == want, name
    assert robot_names(3) == ["robot1", "robot2", "robot3"]


class _Outputs:
    def __init__(self, log, name):
        self.log, self.name = log, name

    def clock(self, t_ns):
        return ("clock", self.name, t_ns)

    def publish(self, messages):
        self.log.extend(messages)


class _Ticks:
    time_ns = 0


class _Run:
    """A lockstep run as the fleet clock sees it: it publishes its held tick when told."""

    def __init__(self, log, name, clock):
        self.log, self.name = log, name
        self.outputs, self.ticks = _Outputs(log, name), _Ticks()
        clock.join(self)

    def publish_held(self):
        self.log.append(("tick", self.name, self.ticks.time_ns))


def test_the_fleet_clock_sends_a_tick_once_every_robot_is_due():
    log = []
    clock = FleetClock()
    runs = [_Run(log, name, clock) for name in ("a", "b", "c")]
    for k in range(3):
        for run in runs:
            run.ticks.time_ns = k * 10_000_000
        before = len(log)
        clock.due(runs[2])
        clock.due(runs[0])
        assert len(log) == before  # nothing before the last robot's tick is due
        clock.due(runs[1])
        # every robot's tick (its odometry first), then one /clock of the tick's time, through the first's publisher
        assert log[before:] == [("tick", "a", k * 10_000_000), ("tick", "b", k * 10_000_000),
                                ("tick", "c", k * 10_000_000), ("clock", "a", k * 10_000_000)]
    assert sum(entry[0] == "clock" for entry in log) == 3
