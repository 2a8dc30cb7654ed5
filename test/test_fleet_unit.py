"""The fleet's plain parts: the ``robots`` parameter, the processes' arguments, the lockstep fleet's one clock, the
realtime preview's values (the fleet trajectory's cost a robot and tick).
"""

import numpy as np
import pytest

from robotino_geom_mpc.params.files import load_params
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
            # no description publisher in a fleet, and its plant's joint_states are off (publish_joint_states)
            assert "joint_states" not in waits and '"joint_states:2"' in single_waits
        assert got == want, name
    assert robot_names(3) == ["robot1", "robot2", "robot3"]


def test_a_realtime_fleet_sends_a_preview_every_10_periods_and_its_controllers_wait_for_it():
    """Realtime: the single run's arguments but the trajectory nodes' ``preview_every`` 10 and the controllers'
    ``reference_timeout_s`` the default's 0.1 s over those 10 periods; lockstep (above): the single run's.
    """
    params = default_params_file()
    _, control = load_params(params)
    fleet = fleet_arguments("paper-circle", params, 2.0, False, 2)
    single = node_arguments("paper-circle", params, 2.0, False)
    extra = {"trajectory_node": {"preview_every": "10"},
             "controller_node": {"reference_timeout_s": repr(round(0.1 + 10 * control.period_s, 9))}}
    for name in ("trajectory_node", "controller_node", "plant_node"):
        got, want = _params(fleet[FLEET_NODES[name]]), _params(single[name])
        got.pop("robots")
        if name == "plant_node":
            got.pop("lockstep_wait_for"), want.pop("lockstep_wait_for")
        assert got == {**want, **extra.get(name, {})}, name


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


@pytest.mark.parametrize("scenario", ["paper-circle", "lemniscate", "point-to-point", "robustness"])
def test_realtime_preview_values_are_the_reference_sampled_at_once(scenario):
    """`preview_values` (one scalar sample per point) against the reference sampled over the points' times in one
    vectorised call and eq. 54's positions: the same values to an ulp, before, during and after the reference.
    """
    from robotino_geom_mpc.params.files import load_params as load
    from robotino_geom_mpc.reference.trajectories import preview
    from robotino_geom_mpc.ros.messages import preview_values
    from robotino_geom_mpc.scenarios import get_scenario

    _, control = load()
    period, horizon = control.period_s, control.horizon
    reference = get_scenario(scenario).make_reference()
    end_ns = int(reference.duration_s * 1e9)
    for t_ns in (-30_000_000, 0, 1_234_567_891, end_ns // 2 + 7, end_ns - 15_000_000, end_ns + 40_000_000):
        t = t_ns * 1e-9
        pos, vel, acc, _ = reference.sample(t + period * np.arange(horizon + 1))
        pos[1:] = preview(reference, t, period, horizon)
        half = 0.5 * pos[:, 2]
        want = np.column_stack((pos[:, :2], np.sin(half), np.cos(half), vel, acc))
        got = np.reshape(preview_values(reference, t_ns, period, horizon), want.shape)
        np.testing.assert_allclose(got, want, rtol=0.0, atol=1e-12, err_msg=f"{scenario} at {t_ns} ns")


def test_a_parameter_file_may_name_the_fleets_own_nodes(tmp_path):
    """The fleet nodes' sections are checked as the single nodes' are: their parameters pass, a misspelled one is
    refused with a suggestion (`params.files.check_parameter_files`, before rcl reads the file).
    """
    from robotino_geom_mpc.params.files import check_parameter_files
    from robotino_geom_mpc.params.specs import ParamError

    good = tmp_path / "fleet.yaml"
    good.write_text("/robotino_fleet_plant:\n  ros__parameters:\n    timing_report: t.json\n    publish_tf: true\n"
                    "/robotino_fleet_controller:\n  ros__parameters:\n    publish_predicted_path: true\n"
                    "/robotino_fleet_trajectory:\n  ros__parameters:\n    robots: [robot1, robot2]\n")
    check_parameter_files([good])
    bad = tmp_path / "bad.yaml"
    bad.write_text("/robotino_fleet_controller:\n  ros__parameters:\n    publish_predicted_paths: true\n")
    with pytest.raises(ParamError, match="unknown parameter 'publish_predicted_paths'.*did you mean "
                       "'publish_predicted_path'"):
        check_parameter_files([bad])


def test_runs_fleet_summary_names_the_misses_only_when_there_are_some(tmp_path, capsys):
    import json

    from robotino_geom_mpc.cli.run import _print_fleet

    metrics = {f"robot{k}": {"rms_position_error_m": 1e-6, "max_position_error_m": 2e-6, "peak_current_a": 0.3}
               for k in (1, 2)}
    timing = tmp_path / "timing.json"
    timing.write_text(json.dumps({"robot1": {"ticks": 600, "missed": 3}, "robot2": {"ticks": 400, "missed": 0}}))
    _print_fleet(metrics, timing, tmp_path)
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(";")[1].strip() for line in lines[:2]] == ["ticks 600, missed 3", "ticks 400, missed 0"]
    assert "the fleet missed 3 of 1000 ticks (0.3 %)" in lines[2]
    timing.write_text(json.dumps({"robot1": {"ticks": 600, "missed": 0}, "robot2": {"ticks": 400, "missed": 0}}))
    _print_fleet(metrics, timing, tmp_path)
    assert "missed" not in capsys.readouterr().out.split("ticks 400, missed 0")[1]
