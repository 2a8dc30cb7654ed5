"""~/enable (std_srvs/SetBool) on the controller: disabled = zero volts and holding, enabled again = bumpless.

A lockstep paper-circle (22 s) with real node processes: the controller is disabled mid-circle and enabled
again a second later. The plant's currents, the controller's voltages and the ground truth come from
the loop probe (one sample per tick), the disabled ticks from the controller's diagnostics.
"""

import pytest
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from std_srvs.srv import SetBool

from harness import Harness
from probe import PROBE_WAIT_FOR, ProbeSpinner
from robotino_geom_mpc.bench.dds import lockstep_nodes
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.ros.messages import stamp_to_ns
from robotino_geom_mpc.system.processes import NodeGroup

pytestmark = pytest.mark.ros

DURATION_S = 22.0  # the whole circle
DISABLE_AT_S = 1.5  # simulated time at which the test asks to disable (the service acts a few ticks later)
HOLD_S = 1.0


def _set_enabled(h: Harness, client, value: bool) -> SetBool.Response:
    return h._call(client, SetBool.Request(data=value), 30.0)


def test_disable_holds_at_zero_volts_and_enabling_again_is_bumpless(tmp_path):
    robot, control = load_params()
    probe = ProbeSpinner()
    try:
        with Harness("enable_probe") as h, NodeGroup(log_dir=tmp_path) as group:
            diagnostics = h.collect("diagnostics", DiagnosticArray)
            # paced to real time: unpaced, the loop ran seconds of simulated time ahead of the diagnostics this
            # test reads on a loaded host, so enabling came so late that the tracking had not converged by the end
            lockstep_nodes(group, "paper-circle", DURATION_S, wait_for=[*PROBE_WAIT_FOR, "diagnostics:1"],
                           plant_overrides={"lockstep_max_realtime_factor": 1.0})
            plant = next(n for n in group.nodes if n.name == "plant_node")
            # one client, matched while the plant still settles: a call then takes milliseconds
            client = h.node.create_client(SetBool, "/robotino_controller/enable")
            assert client.wait_for_service(timeout_sec=60.0)

            def reached(t_s: float):
                return lambda: diagnostics and stamp_to_ns(diagnostics[-1].header.stamp) >= t_s * 1e9

            assert h.spin_until(reached(DISABLE_AT_S), 240.0), plant.stderr_tail()
            response = _set_enabled(h, client, False)
            assert response.success and response.message == "disabled"
            assert h.spin_until(lambda: diagnostics[-1].status[0].message == "disabled", 60.0)
            disabled_at = stamp_to_ns(diagnostics[-1].header.stamp) * 1e-9
            assert h.spin_until(reached(disabled_at + HOLD_S), 240.0)
            assert _set_enabled(h, client, True).message == "enabled"
            assert h.spin_until(lambda: plant.popen.poll() is not None, 240.0), plant.stderr_tail()
            assert plant.popen.returncode == 0
            h.spin_for(0.3)
            plant_log = plant.stderr_tail(30)
        ticks = round(DURATION_S / control.period_s)
        deadline = time.monotonic() + 120.0  # the probe (another thread) may lag behind: let it take every sample
        while min(len(probe.probe.truth), len(probe.probe.currents), len(probe.probe.voltages)) < ticks and \
                time.monotonic() < deadline:
            time.sleep(0.1)
        run = probe.probe.run_data("paper-circle")
    finally:
        probe.close()
    period_ns = round(control.period_s * 1e9)
    messages = {}
    for msg in diagnostics:
        messages.setdefault(stamp_to_ns(msg.header.stamp), []).append(msg.status[0].message)
    disabled = sorted(s // period_ns for s, m in messages.items() if "disabled" in m)
    assert run.n == ticks, plant_log
    # one contiguous stretch of at least the hold time, all at exactly zero volts
    assert len(disabled) >= HOLD_S / control.period_s
    assert disabled == list(range(disabled[0], disabled[-1] + 1))
    assert np.all(run.voltages[disabled] == 0.0)
    assert np.abs(run.voltages[disabled[0] - 1]).max() > 0.5  # it was driving the circle before
    # the robot stopped while held: it fell well behind the reference
    error = np.hypot(*(run.pose[:, :2] - run.reference[:, :2]).T)
    assert error[disabled[-1]] > 0.05
    # re-enabled: no current step beyond the limit, and the tracking error back at micrometres. (Held at zero
    # volts the motors brake by their back-EMF: that current, up to Km omega / R, is the drives' own.)
    assert disabled[-1] < ticks - round(2.0 / control.period_s), "enabled again too late in the run to judge"
    braking = np.abs(run.currents[disabled]).max()
    peak = np.abs(run.currents[disabled[-1] + 1:]).max()
    assert peak <= 1.02 * control.current_limit_a, peak
    tail = error[-round(1.0 / control.period_s):]
    assert tail.max() < 1e-5, tail.max()
    print(f"disabled ticks {len(disabled)}, error at re-enable {error[disabled[-1]]:.4f} m, peak current after "
          f"{peak:.4f} A (braking while held {braking:.4f} A), error over the last second max {tail.max():.3g} m")
