"""``run --scenario wifi`` (lockstep, over its link, with plans) recorded: ``regress`` recomputes every recorded
plan from what the controller received, in the order it received it (0 deviation), a changed controller setting
is caught, and ``report`` measures the link against the plant's own link (the same seeds). In realtime too: there
the recorder gets odometry and reports in an order of its own, and the replay takes the reports as the node's
status of each odometry counts them (``reports_received``).
"""

import json
import subprocess
import sys

import pytest

from robotino_geom_mpc.network.link import Link
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.recording.regress import regress_bag
from robotino_geom_mpc.scenarios import get_scenario

pytestmark = pytest.mark.ros

DURATION_S = 2.0


@pytest.fixture(scope="module")
def wifi_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("wifi")
    done = subprocess.run([sys.executable, "-m", "robotino_geom_mpc", "run", "--scenario", "wifi", "--duration",
                           str(DURATION_S), "--out", str(out), "--no-plots"], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    return out


def test_regress_replays_every_plan_of_a_run_over_the_link(wifi_run):
    result = regress_bag(wifi_run / "bag")
    _, control = load_params()
    assert result.command == "wheel_voltage_plan"
    assert result.compared > 0.8 * DURATION_S / control.period_s and result.passed, result


def test_regress_catches_a_controller_that_differs(wifi_run, tmp_path):
    params = tmp_path / "other.yaml"
    text = default_params_file().read_text()
    assert "lead_quantile: 0.99" in text
    params.write_text(text.replace("lead_quantile: 0.99", "lead_quantile: 0.5"))
    result = regress_bag(wifi_run / "bag", params_file=params)
    assert result.compared > 0 and not result.passed


def test_report_measures_the_links_loss(wifi_run):
    metrics = json.loads((wifi_run / "metrics.json").read_text())
    link = metrics["link"]
    _, control = load_params()
    ticks = round(DURATION_S / control.period_s)
    up = Link(get_scenario("wifi").link, 0 + 1)  # the plant's up-link: seed 0 + 1
    lost = sum(not up.transmit(k * control.period_s) for k in range(ticks))
    # the odometries of the last ticks may still be in flight at the end: at most two fewer received
    assert ticks - lost - 2 <= link["odometry_received"] <= ticks - lost
    assert 0.0 < link["round_trip_ms"]["mean"] < 1e3 * 4 * get_scenario("wifi").link.mean_delay_s


@pytest.mark.slow
def test_regress_replays_every_plan_of_a_realtime_run_over_the_link(tmp_path):
    out = tmp_path / "realtime"
    done = subprocess.run([sys.executable, "-m", "robotino_geom_mpc", "run", "--scenario", "wifi", "--realtime",
                           "--duration", "4", "--out", str(out), "--no-plots"], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    result = regress_bag(out / "bag")
    # every plan the recorder holds is found (a basis back from the plan's header is some 100 ns off its odometry
    # stamp at epoch times) and recomputed to the last bit
    assert result.passed and result.compared >= 0.9 * result.ticks, result
