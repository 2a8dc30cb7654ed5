"""Goal files (`reference.goal_file`) in-process: the example file plans like the reference the trajectory node
builds from it on receipt, bad files are refused naming the item, and `run` refuses goals outside the goals scenario.
"""

import numpy as np
import pytest

from robotino_geom_mpc.params.presets import default_params_file

pytestmark = pytest.mark.unit


def test_example_goal_file_has_three_goals_and_a_path_and_plans_like_the_reference(tmp_path):
    from robotino_geom_mpc.reference.goal_file import LIMIT_DEFAULTS, load_goal_file, motion_limits, planned_end_s
    from robotino_geom_mpc.reference.goals import GoalReference
    from robotino_geom_mpc.params.files import read_parameter_file
    from robotino_geom_mpc.params.presets import config_file

    items = load_goal_file(config_file("goals_example.yaml"))
    assert [i.is_path for i in items] == [False, False, False, True]
    limits = motion_limits({**read_parameter_file(default_params_file()), **LIMIT_DEFAULTS})
    ref = GoalReference(hold_s=0.0)
    for item in items:  # independently: each motion planned at its time, as the node does on receipt
        (ref.follow if item.is_path else ref.go_to)(item.t, np.array(item.poses if item.is_path else item.poses[0]),
                                                     limits)
        assert ref.duration_s <= item.t + 20.0
    assert planned_end_s(items, limits) == pytest.approx(ref.duration_s)
    assert limits.rim_speed_mps == pytest.approx(0.9424777960769379)


@pytest.mark.parametrize("text, match", [
    ("items: []", "non-empty list"),
    ("items: [{t: 1.0}]", "one of 'goal' or 'path'"),
    ("items: [{t: -1.0, goal: [0, 0, 0]}]", "time >= 0"),
    ("items: [{t: 1.0, goal: [0, .nan, 0]}]", "finite poses"),
    ("items: [{t: 1.0, path: []}]", "finite poses"),
    ("items: [{t: 1.0, goal: [0, 0, 0], path: [[0, 0, 0]]}]", "one of"),
    ("{", "cannot read"),
])
def test_bad_goal_files_are_refused_naming_the_item(tmp_path, text, match):
    from robotino_geom_mpc.reference.goal_file import load_goal_file
    from robotino_geom_mpc.reference.goal_motion import GoalError

    path = tmp_path / "goals.yaml"
    path.write_text(text)
    with pytest.raises(GoalError, match=match):
        load_goal_file(path)


def test_run_refuses_goals_outside_the_goals_scenario_and_bad_files(tmp_path, capsys):
    from robotino_geom_mpc.cli import main

    bad = tmp_path / "bad.yaml"
    bad.write_text("items: []")
    assert main(["run", "--scenario", "paper-circle", "--goals", str(bad), "--out", str(tmp_path / "a")]) == 2
    assert "--goals needs --scenario goals" in capsys.readouterr().err
    assert main(["run", "--scenario", "goals", "--goals", str(bad), "--out", str(tmp_path / "b")]) == 2
    assert "non-empty list" in capsys.readouterr().err
