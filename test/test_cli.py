"""The command's dispatcher: every verb is reachable, documented, and loads only its own module."""

import subprocess
import sys

import pytest

from robotino_geom_mpc.cli import VERBS, main

pytestmark = pytest.mark.ros


def test_top_level_help_lists_every_verb_without_importing_them():
    code = (
        "import sys\n"
        "from robotino_geom_mpc.cli import main\n"
        "try:\n"
        "    main(['--help'])\n"
        "except SystemExit:\n"
        "    pass\n"
        "print('LOADED', sorted(m for m in sys.modules if m.startswith('robotino_geom_mpc.cli.')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    for verb in VERBS:
        assert verb in out
    assert "LOADED []" in out


@pytest.mark.parametrize("verb", sorted(VERBS))
def test_each_verb_has_help(verb, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([verb, "--help"])
    assert exit_info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert f"robotino-geom-mpc {verb}" in text


def test_unknown_verb_exits_2(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["no-such-verb"])
    assert exit_info.value.code == 2
    assert "invalid choice" in capsys.readouterr().err
