"""The full lockstep loop over DDS (three node processes) reproduces the offline loop of `simulate`."""

import math

import numpy as np
import pytest

from robotino_geom_mpc.params.files import load_params
from probe import PROBE_WAIT_FOR, ProbeSpinner
from robotino_geom_mpc.bench.dds import lockstep_nodes
from robotino_geom_mpc.system.processes import NodeGroup
from robotino_geom_mpc.offline.results import compute_metrics
from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario

pytestmark = pytest.mark.ros

DURATION_S = 5.0
WALL_CLOCK_KEYS = ("compute_time",)  # measured, not simulated


def test_lockstep_dds_loop_equals_the_offline_loop(tmp_path):
    robot, control = load_params()
    probe = ProbeSpinner()
    try:
        with NodeGroup(log_dir=tmp_path) as group:
            plant = lockstep_nodes(group, "paper-circle", DURATION_S, wait_for=PROBE_WAIT_FOR)
            assert group.wait(plant, 240.0), plant.stderr_tail()
            assert plant.popen.returncode == 0
        probe.wait_for_ticks(round(DURATION_S / control.period_s))
        dds = probe.probe.run_data("paper-circle")
    finally:
        probe.close()
    offline = run_scenario(RunConfig("paper-circle", robot, control, duration_s=DURATION_S))
    assert dds.n == offline.n == round(DURATION_S / control.period_s)
    for name in ("t", "pose", "reference", "currents", "voltages"):
        np.testing.assert_allclose(getattr(dds, name), getattr(offline, name), rtol=1e-6, atol=1e-9, err_msg=name)
    got, want = compute_metrics(dds), compute_metrics(offline)
    for key, value in want.items():
        if key.startswith(WALL_CLOCK_KEYS) or key not in got:
            continue
        if isinstance(value, float) and math.isfinite(value):
            assert got[key] == pytest.approx(value, rel=1e-6, abs=1e-12), key
        else:
            assert got[key] == value, key
