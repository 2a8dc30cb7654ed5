"""The scenario table of README.md, generated from the registry (`robotino_geom_mpc.scenarios.SCENARIOS`).

    python tools/scenario_table.py            # print the table
    python tools/scenario_table.py --write F  # replace the table between the markers in F
    python tools/scenario_table.py --check F  # exit 1 if F's table is not the registry's

The table sits between ``<!-- scenarios:begin -->`` and ``<!-- scenarios:end -->``.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

BEGIN, END = "<!-- scenarios:begin -->", "<!-- scenarios:end -->"
_BLOCK = re.compile(re.escape(BEGIN) + r"\n.*?" + re.escape(END), re.S)


def table() -> str:
    """The markdown table: one row per scenario, its name and description."""
    from robotino_geom_mpc.scenarios import SCENARIOS

    rows = ["| scenario | what it runs |", "| --- | --- |"]
    rows += [f"| `{name}` | {s.description} |" for name, s in SCENARIOS.items()]
    return "\n".join(rows)


def with_table(text: str) -> str:
    """`text` with the block between the markers replaced by the current table (ValueError without markers)."""
    if not _BLOCK.search(text):
        raise ValueError(f"no {BEGIN} ... {END} block")
    return _BLOCK.sub(lambda _: f"{BEGIN}\n{table()}\n{END}", text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--write", type=Path, metavar="FILE")
    group.add_argument("--check", type=Path, metavar="FILE")
    args = parser.parse_args(argv)
    if args.write:
        args.write.write_text(with_table(args.write.read_text()))
    elif args.check:
        text = args.check.read_text()
        if with_table(text) != text:
            print(f"{args.check}: the scenario table is not the registry's; run tools/scenario_table.py --write",
                  file=sys.stderr)
            return 1
    else:
        print(table())
    return 0


if __name__ == "__main__":
    sys.exit(main())
