"""A slow simulation is slow, not stale: the controller's watchdog counts node-clock time under use_sim_time.

The lockstep loop runs at 0.1x real time (the plant's ``lockstep_max_realtime_factor``: one 10 ms tick per
100 ms), with the controller's timeouts at 50 ms. With ``use_sim_time`` the controller's watchdog counts
the plant's /clock, in which every input is one period old: no diagnostic of the run carries a stale
watchdog state. The same loop with the controller on steady time (no ``use_sim_time``) is the control:
there every input is 100 ms old in steady time, past the timeout, so its diagnostics do report stale data,
which shows the test can tell the two apart.
"""

import pytest
import contextlib

from diagnostic_msgs.msg import DiagnosticArray

from harness import Harness
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.system.processes import NodeGroup, node_arguments

pytestmark = pytest.mark.ros

DURATION_S = 0.5  # simulated: 50 ticks, 5 s of wall time at 0.1x
FACTOR = 0.1
TIMEOUT_S = 0.05
STALE = ("stale_odom", "stale_reference")


def _watchdog_states(diagnostics: list) -> list[str]:
    return [kv.value for d in diagnostics for s in d.status for kv in s.values if kv.key == "watchdog"]


@pytest.mark.slow
def test_a_slow_lockstep_loop_under_sim_time_is_never_stale_and_on_steady_time_it_is(tmp_path):
    runs = {"sim": True, "steady": False}
    with Harness("slow_sim_test") as h, contextlib.ExitStack() as stack:
        diagnostics = {name: h.collect(f"/slow_{name}/diagnostics", DiagnosticArray) for name in runs}
        plants = {}
        for name, sim_time in runs.items():
            group = stack.enter_context(NodeGroup(log_dir=tmp_path / name))
            clock_readers = 2 if sim_time else 1  # the trajectory, and the controller's time source
            args = node_arguments(
                "paper-circle", default_params_file(), DURATION_S, True, namespace=f"slow_{name}",
                wait_for=["odom:1", f"/clock:{clock_readers}", "reference_preview:1", "diagnostics:1"],
                overrides={"plant_node": {"lockstep_max_realtime_factor": FACTOR},
                           "controller_node": {"use_sim_time": sim_time, "odom_timeout_s": TIMEOUT_S,
                                               "reference_timeout_s": TIMEOUT_S}})
            started = {executable: group.start(executable, argv) for executable, argv in args.items()
                       if executable != "robot_description_publisher"}
            plants[name] = (group, started["plant_node"])
        for name, (group, plant) in plants.items():
            assert h.spin_until(lambda: plant.popen.poll() is not None, 240.0), plant.stderr_tail()
            assert plant.popen.returncode == 0, plant.stderr_tail()
        h.spin_for(0.5)
    sim, steady = (_watchdog_states(diagnostics[name]) for name in runs)
    ticks = round(DURATION_S / 0.01)
    assert len(sim) >= ticks and len(steady) >= ticks, (len(sim), len(steady))
    assert not set(sim) & set(STALE), sorted(set(sim))
    assert set(steady) & set(STALE), sorted(set(steady))
