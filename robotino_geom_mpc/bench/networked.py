"""Benchmark ``networked``: the realtime loop over DDS with plans beside the uncompensated controller.

The command's time of action is known with plans; both sides run in the same benchmark, interleaved
(`NETWORKED_RUNS` repeats, medians):

* ``wifi_compensated_rms_m``: ``run --scenario wifi --realtime`` (the plant's emulated WiFi link each way, the
  controller's delay-compensated plans), the RMS position error after settling from the bag's ground truth;
* its peer ``wifi_uncompensated_rms_m``: the same with ``--no-compensation`` (plain commands acting on arrival);
* ``local_plans_rms_m``: ``run --scenario paper-circle --realtime --plans`` on one host without a link (plans:
  each command acts at the time its plan gives, on the plant's grid);
* its peer ``local_plain_rms_m``: the same without ``--plans`` (today's loop: a command acts when it arrives);
* ``two_hosts_wifi_compensated_rms_m`` and its peer ``two_hosts_wifi_uncompensated_rms_m``: the wifi sides
  across two network namespaces (`system.netns`: the plant on one host, the trajectory, controller and
  recorder on the other, DDS over UDP through a veth; the nodes' arguments those of ``run``), read from the bag
  (`bench.two_hosts`); skipped (`BenchmarkSkipped`'s reason on stderr, the other sides still run) without root
  or ``ip netns``;
* ``wifi_compensation_gain``, ``two_hosts_wifi_compensation_gain`` and ``local_plans_gain``: uncompensated /
  compensated RMS (> 1: better with plans).

The realtime figures depend on the machine keeping the loop's deadlines (a loaded 2-core machine misses ticks):
the run's missed ticks come as ``*_missed`` (the plant's timing report) so a figure can be read with them.
"""

from __future__ import annotations

import json
import statistics
import sys
import tempfile
from contextlib import ExitStack
from pathlib import Path

from robotino_geom_mpc.bench.end_to_end import run_verb
from robotino_geom_mpc.bench.registry import BenchmarkError, BenchmarkSkipped, benchmark
from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.system.netns import Hosts, NetnsUnavailable, two_hosts

__all__ = ["NETWORKED_RUNS", "RUN_DURATION_S", "bench_networked", "open_hosts", "realtime_run", "two_hosts_side"]

NETWORKED_RUNS = 3  # quick: 1
RUN_DURATION_S = 12.0
_SIDES = {  # figure prefix: run arguments
    "wifi_compensated": ["--scenario", "wifi"],
    "wifi_uncompensated": ["--scenario", "wifi", "--no-compensation"],
    "local_plans": ["--scenario", "paper-circle", "--plans"],
    "local_plain": ["--scenario", "paper-circle"],
}
_TWO_HOSTS_SIDES = {  # figure prefix: node_arguments' plans (None: the wifi link's default, plans)
    "two_hosts_wifi_compensated": None,
    "two_hosts_wifi_uncompensated": False,
}


def realtime_run(out: Path, arguments: list[str], duration_s: float = RUN_DURATION_S) -> dict[str, float]:
    """One ``run --realtime`` with `arguments` in a subprocess: its RMS position error [m] and missed ticks."""
    from robotino_geom_mpc.system.processes import TIMING_REPORT

    run_verb(out, [*arguments, "--realtime"], duration_s)
    metrics = json.loads((out / "metrics.json").read_text())
    timing = json.loads((out / "logs" / TIMING_REPORT).read_text())
    return {"rms_m": metrics["rms_position_error_m"], "missed": timing.get("missed", 0)}


def open_hosts(stack: ExitStack) -> Hosts:
    """Two network namespaces (`system.netns.two_hosts`) held open by `stack`.

    Raises
    ------
    BenchmarkSkipped
        Without root, ``ip`` or the kernel's consent, with the reason.
    """
    try:
        return stack.enter_context(two_hosts())
    except NetnsUnavailable as exc:
        raise BenchmarkSkipped(f"the two_hosts_* sides need network namespaces: {exc}") from None


def two_hosts_side(hosts: Hosts, out: Path, plans: bool | None,
                   duration_s: float = RUN_DURATION_S) -> dict[str, float]:
    """One realtime wifi run across `hosts` (`bench.two_hosts`; `plans` False: ``--no-compensation``): its RMS
    position error after settling from the bag's ground truth [m] and the plant's missed ticks.
    """
    from robotino_geom_mpc.bench.two_hosts import two_hosts_run
    from robotino_geom_mpc.offline.results import compute_metrics

    try:
        done = two_hosts_run(hosts, out, "wifi", duration_s, lockstep=False, plans=plans)
    except BenchmarkError:  # no valid timing report
        raise
    except RobotinoError as exc:  # a node failed, the run did not end, a bag without a run
        raise BenchmarkError(f"wifi run across two hosts (plans {plans}): {exc}") from None
    return {"rms_m": compute_metrics(done.run)["rms_position_error_m"], "missed": done.timing["missed"]}


@benchmark("networked", "realtime run over the wifi link (on one host and across two network namespaces) and on "
           "one host, with plans beside the uncompensated controller (RMS position error from the bag's ground "
           "truth)")
def bench_networked(quick: bool) -> dict[str, float]:
    """Medians over `NETWORKED_RUNS` interleaved repeats of each side (one with `quick`); see the module docstring."""
    try:
        import rclpy  # noqa: F401  (the nodes need it)
    except ImportError as exc:
        raise BenchmarkSkipped(f"ROS 2 not available: {exc}") from None
    samples: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory(prefix="robotino_networked_") as tmp, ExitStack() as stack:
        try:
            hosts: Hosts | None = open_hosts(stack)
        except BenchmarkSkipped as exc:
            print(f"bench networked: skipped {', '.join(_TWO_HOSTS_SIDES)} ({exc})", file=sys.stderr, flush=True)
            hosts = None
        for k in range(1 if quick else NETWORKED_RUNS):
            runs = [(side, lambda out, a=arguments: realtime_run(out, a)) for side, arguments in _SIDES.items()]
            if hosts is not None:
                runs += [(side, lambda out, p=plans: two_hosts_side(hosts, out, p))
                         for side, plans in _TWO_HOSTS_SIDES.items()]
            for side, run_side in runs:
                figures = run_side(Path(tmp) / f"{side}{k}")
                samples.setdefault(f"{side}_rms_m", []).append(figures["rms_m"])
                samples.setdefault(f"{side}_missed", []).append(figures["missed"])
    out = {key: statistics.median(values) for key, values in samples.items()}
    out["wifi_compensation_gain"] = out["wifi_uncompensated_rms_m"] / out["wifi_compensated_rms_m"]
    out["local_plans_gain"] = out["local_plain_rms_m"] / out["local_plans_rms_m"]
    if hosts is not None:
        out["two_hosts_wifi_compensation_gain"] = (out["two_hosts_wifi_uncompensated_rms_m"]
                                                   / out["two_hosts_wifi_compensated_rms_m"])
    return out
