"""Helper of the regress tests: the ``regress`` verb run once, with the result it printed."""

from __future__ import annotations

from pathlib import Path

from robotino_geom_mpc.cli import main
from robotino_geom_mpc.recording import regress


def regress_verb(bag: Path, monkeypatch) -> tuple[int, regress.RegressionResult]:
    """The exit status of ``robotino-geom-mpc regress BAG`` and the `regress.regress_bag` result it printed (kept by
    a spy: the recording replayed once, for the verb and the test).
    """
    results = []
    real = regress.regress_bag

    def keep(*args, **kwargs):
        results.append(real(*args, **kwargs))
        return results[-1]

    monkeypatch.setattr(regress, "regress_bag", keep)
    status = main(["regress", str(bag)])
    assert len(results) == 1
    return status, results[0]
