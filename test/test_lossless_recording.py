"""A recorded lockstep run loses nothing while a CPU-bound process holds one core: one message per tick per topic.

The run is `robotino-geom-mpc run` itself (recorder, trajectory, controller, plant, description publisher as
processes, tick 0 one announcement period after the recorder's subscriptions show: `PROFILE_SETTLE_S`); the bag is
counted with `mcap`'s own reader, independent of the package's bag code.
"""

import collections
import multiprocessing
import os
from pathlib import Path

import pytest
from mcap.reader import make_reader

from robotino_geom_mpc.cli import main
from robotino_geom_mpc.params.files import load_params

pytestmark = pytest.mark.ros

DURATION_S = 5.0
LOOP_TOPICS = ("/odom", "/clock", "/ground_truth/odom", "/wheel_currents", "/joint_states", "/reference_preview",
               "/wheel_voltages", "/diagnostics", "/tf")
PER_TICK = {"/tf": 2}  # odom -> base_link (the plant) and the wheels (the description publisher)


def _busy() -> None:
    os.sched_setaffinity(0, {0})
    while True:
        pass


def _count(bag: Path) -> collections.Counter:
    counts: collections.Counter = collections.Counter()
    for path in sorted(bag.glob("*.mcap")):
        with open(path, "rb") as f:
            for _, channel, _ in make_reader(f).iter_messages():
                counts[channel.topic] += 1
    return counts


@pytest.fixture(scope="module")
def counts(tmp_path_factory):
    """Messages per topic of a recorded 5 s lockstep paper-circle run beside a busy core."""
    if len(os.sched_getaffinity(0)) < 2:
        pytest.skip("needs two cores: one busy, one for the loop")
    out = tmp_path_factory.mktemp("lossless")
    busy = multiprocessing.get_context("spawn").Process(target=_busy, daemon=True)
    busy.start()
    try:
        status = main(["run", "--scenario", "paper-circle", "--duration", str(DURATION_S), "--out", str(out),
                       "--no-plots"])
    finally:
        busy.kill()
        busy.join()
    assert status == 0, (out / "logs" / "plant_node.err.log").read_text()
    return _count(out / "bag")


@pytest.mark.parametrize("topic", LOOP_TOPICS)
def test_every_tick_is_recorded(counts, topic):
    ticks = round(DURATION_S / load_params()[1].period_s)
    # the trajectory's previews run one tick ahead: ticks 0 .. n, n + 1 of them
    assert counts[topic] == PER_TICK.get(topic, 1) * ticks + (topic == "/reference_preview"), dict(counts)
