"""Damaged footage: what heightpipe recovers and reports, per container and kind of damage.

    python -m bench.damage_bench            # the corpus table (issue 24, must-show 1 and 2)
    python -m bench.damage_bench fuzz       # bit-flip fuzz, 210 full runs (must-show 4)

The corpus is built by ``tests/damage_corpus.py`` (which also documents the columns); this is
the benchmark-style entry point to it. Results: docs/results.md.
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

CORPUS_SCRIPT = Path(__file__).resolve().parent.parent / "tests" / "damage_corpus.py"


def main() -> None:
    arguments = sys.argv[1:] or ["table"]
    sys.argv = [str(CORPUS_SCRIPT), *arguments]
    runpy.run_path(str(CORPUS_SCRIPT), run_name="__main__")


if __name__ == "__main__":
    main()
