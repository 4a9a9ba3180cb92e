"""A shipped policy's card tables, in Markdown, from a ``tools/ship_perceptive.sh`` output folder.

A lab tool, not a ``tron1`` command: reads Table I (student, teacher, blind flat, beside the
paper's row), the climb probe, Fig. 5, Fig. 6 and deploy-sim's figures from the JSON the shipping
run wrote, prints them and writes them to DIR/tables.md. Runs no policy; parts not run yet are
named as such.

    python tools/card_tables.py policies/perceptive
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tron1cli.fileio import write_file
from tron1cli.viz.card_tables import ship_tables


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir", type=Path, help="the shipping run's output folder")
    args = ap.parse_args()
    if not args.dir.is_dir():
        sys.exit(f"error: {args.dir}: no such folder")
    try:
        text = ship_tables(args.dir)
    except ValueError as e:
        sys.exit(f"error: {e}")
    write_file(args.dir / "tables.md", text)
    print(text, end="")


if __name__ == "__main__":
    main()
