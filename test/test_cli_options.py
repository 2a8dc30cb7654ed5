"""The command line's options: --chain implies cmd_vel, link options checked in the unit typed, help names only
the verb's own options, counts refused as positive integers (in-process parsing and the verbs' first checks).
"""

from __future__ import annotations

import re

import pytest

from robotino_geom_mpc.cli import VERBS, build_parser, main
from robotino_geom_mpc.network.link import MAX_DELAY_S
from robotino_geom_mpc.offline.results import load_run

pytestmark = pytest.mark.unit

SHORT = ["--scenario", "paper-circle", "--duration", "0.2", "--no-plots"]


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


def test_chain_implies_the_cmd_vel_interface(tmp_path, capsys):
    out = tmp_path / "chain"
    assert main(["simulate", *SHORT, "--no-progress", "--chain", "robocup-logistics", "--out", str(out)]) == 0
    run = load_run(out / "run.npz")
    assert run.meta["command_interface"] == "cmd_vel" and run.meta["mode"] == "chain"
    assert "through the robocup-logistics chain" in capsys.readouterr().out
    # without --chain the default stays the wheel voltages
    assert main(["simulate", *SHORT, "--no-progress", "--out", str(tmp_path / "plain")]) == 0
    assert load_run(tmp_path / "plain" / "run.npz").meta["command_interface"] == "voltages"


@pytest.mark.parametrize("verb, extra", [("simulate", ["--no-progress"]), ("run", ["--realtime"])])
def test_chain_with_explicit_voltages_is_refused(tmp_path, capsys, verb, extra):
    argv = [verb, *SHORT, *extra, "--chain", "robocup-logistics", "--command-interface", "voltages",
            "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    line = _one_error_line(capsys)
    assert "--command-interface voltages" in line and "--chain implies --command-interface cmd_vel" in line
    assert not (tmp_path / "o").exists()  # refused before anything ran


def test_run_chain_needs_realtime_only(tmp_path, capsys):
    assert main(["run", *SHORT, "--chain", "robocup-logistics", "--out", str(tmp_path / "o")]) == 2
    line = _one_error_line(capsys)
    assert "--realtime" in line and "--command-interface" not in line


@pytest.mark.parametrize("args, expected", [
    (["--link-delay-ms", "-5"], f"--link-delay-ms must be in [0, {1e3 * MAX_DELAY_S:g}] ms, got -5"),
    (["--link-jitter-ms", "20000"], f"--link-jitter-ms must be in [0, {1e3 * MAX_DELAY_S:g}] ms, got 20000"),
    (["--link-loss", "1"], "--link-loss must be in [0, 1), got 1"),
    (["--link-burst", "0.5", "--link-loss", "0.1"], "--link-burst must be >= 1 packet, got 0.5"),
    (["--link-loss", "0.6"], "--link-loss 0.6 needs --link-burst >= 1.5"),
])
@pytest.mark.parametrize("verb", ["simulate", "study", "run"])
def test_link_options_are_checked_in_the_unit_typed(tmp_path, capsys, verb, args, expected):
    extra = {"simulate": ["--no-progress"], "study": ["--samples", "1", "--no-progress"], "run": []}[verb]
    argv = [verb, "--scenario", "paper-circle", "--duration", "0.1", *extra, "--out", str(tmp_path / "o"), *args]
    assert main(argv) == 2
    line = _one_error_line(capsys)
    assert expected in line and not (tmp_path / "o").exists()  # refused before any output
    assert "link.delay_s" not in line and "link.jitter_s" not in line  # no second-based field names


def test_link_options_in_range_give_the_link_in_seconds():
    from robotino_geom_mpc.cli.simulate import link_from_args

    args = build_parser("simulate").parse_args(["simulate", "--scenario", "paper-circle", "--link-delay-ms", "20",
                                                "--link-jitter-ms", "5", "--link-loss", "0.6", "--link-burst", "2"])
    link = link_from_args(args)
    assert (link.delay_s, link.jitter_s, link.loss, link.burst_length) == pytest.approx((0.020, 0.005, 0.6, 2.0))
    args = build_parser("simulate").parse_args(["simulate", "--scenario", "paper-circle"])
    assert link_from_args(args) is None


@pytest.mark.parametrize("value", ["-3", "0", "x"])
def test_samples_must_be_positive(capsys, value):
    with pytest.raises(SystemExit) as exc:
        main(["study", "--scenario", "paper-circle", "--out", "unused", "--samples", value])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"--samples: must be a positive integer (1 or more), got '{value}'" in err and "non-negative" not in err


def _help(verb: str, capsys) -> str:
    with pytest.raises(SystemExit):
        main([verb, "--help"])
    return " ".join(capsys.readouterr().out.split())


@pytest.mark.parametrize("verb", sorted(VERBS))
def test_help_names_only_the_verbs_own_options(verb, capsys):
    parser = build_parser(verb)
    sub = next(a for a in parser._actions if a.dest == "verb").choices[verb]
    own = {o for a in sub._actions for o in a.option_strings}
    named = set(re.findall(r"(?<![\w-])--[a-z][a-z-]*[a-z]", _help(verb, capsys)))
    assert named <= own, f"{verb} --help names options it does not have: {sorted(named - own)}"


def test_run_help_says_where_the_link_runs(capsys):
    text = _help("run", capsys)
    assert "offline" not in text and "the loop over DDS (the plant node emulates the link) over the link" in text
    assert "any of these options runs the offline loop over the link" in _help("simulate", capsys)
