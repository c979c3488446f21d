"""Generate every results table and figure of the documentation from the committed result files.

One script, so that the README, the docs and the data never disagree:

* the README's results table (between ``<!-- results:begin -->`` and ``<!-- results:end -->``),
* ``docs/results.md`` (every results table, each with the command that reproduces it and the file it comes from),
* ``benchmarks/results/README.md`` (an index of the current result files) and
  ``benchmarks/results/archive/README.md`` (an index of the superseded ones),
* with ``--figures``, the figures under ``docs/figures/results/`` (drawn from the JSON files; needs matplotlib and,
  for the RL curves and the robust figure, the benchmark modules).

Usage::

    python scripts/make_results.py              # rewrite the README block, docs/results.md and the indexes
    python scripts/make_results.py --figures    # ... and redraw the figures
    python scripts/make_results.py --check      # exit 1 if any generated text differs from what is committed

The tables and figures are made in ``scripts/results_docs/``, one module per part: ``controllers``, ``dmc``,
``robust``, ``figures``, the result files' index (``files``) and the shared helpers (``common``); this script
assembles the pages and writes them.

The test suite runs ``--check``: editing a number by hand in a generated file, or changing a result file without
regenerating, fails the tests.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from results_docs.common import ARCHIVE, BEGIN, END, GENERATED, RESULTS, ROOT, load, load_sentence, table
from results_docs.controllers import (
    BASELINE_HEADER,
    baseline_rows,
    horizon_summary,
    section_baselines,
    section_controllers,
    section_rl,
    section_sample_efficiency,
    section_speed,
    section_success_per_solve,
)
from results_docs.dmc import readme_dmc, section_dmc
from results_docs.figures import draw_figures
from results_docs.files import archive_index, results_index
from results_docs.robust import readme_robust, section_robust


def readme_block() -> str:
    base = load("baselines.json")
    rows = []
    for task in ("acrobot", "glider"):
        b = base[task]
        rows.append([f"*{task} ({b['grid_starts']} grid starts, {b['heldout_starts']} held-out)*"]
                    + [""] * (len(BASELINE_HEADER) - 1))
        rows += baseline_rows(task)
    return "\n".join([
        GENERATED,
        table(BASELINE_HEADER, rows),
        "",
        horizon_summary("acrobot"),
        "",
        horizon_summary("glider"),
        "",
        "Success is the task's own rule on starts never trained on (@ 0.1 to 0.5: the rule's tolerance scaled to "
        "that distance); the final distance is over the whole state (the glider's includes its speeds, which its "
        "rule allows up to 2 m/s). Source: `benchmarks/results/baselines.json`, every row measured in one run "
        "([all results, with the commands](docs/results.md))." + load_sentence(base.get("machine")),
        "",
        readme_dmc(),
        "",
        readme_robust(),
    ])


def results_page() -> str:
    sections = [section_baselines(), section_controllers(), section_success_per_solve(), section_robust(), section_rl(),
                section_dmc(), section_sample_efficiency(), section_speed()]
    intro = (
        "# Results\n\n" + GENERATED + "\n\n"
        "Every number on this page is read from a committed file under `benchmarks/results/` by "
        "`scripts/make_results.py`; each section names the command that reproduces it. Success is the task's own "
        "rule (the acrobot within 0.05 of upright; the glider inside the perch box) on starts no method trained on. "
        "Timings come from 2-core machines: the median and 95th percentile of the time per closed-loop step."
    )
    return "\n\n".join([intro, *sections]) + "\n"


def with_block(readme: str, block: str) -> str:
    if readme.count(BEGIN) != 1 or readme.count(END) != 1:
        raise SystemExit(f"make_results: README.md must hold {BEGIN} and {END} once each")
    head, rest = readme.split(BEGIN)
    _, tail = rest.split(END)
    return f"{head}{BEGIN}\n{block}\n{END}{tail}"


def outputs() -> dict[Path, Callable[[str], str]]:
    """Each generated file and how to make its new text from its current one."""
    block = readme_block()
    page, index, archive = results_page(), results_index(), archive_index()
    return {
        ROOT / "README.md": lambda old: with_block(old, block),
        ROOT / "docs" / "results.md": lambda _old: page,
        RESULTS / "README.md": lambda _old: index,
        ARCHIVE / "README.md": lambda _old: archive,
    }


def _shown(path: Path) -> str:
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="fail if a generated file is not up to date")
    parser.add_argument("--figures", action="store_true", help="also redraw docs/figures/results/*.png")
    args = parser.parse_args(argv)
    stale = []
    for path, make in outputs().items():
        old = path.read_text() if path.exists() else ""
        new = make(old)
        if new != old:
            stale.append(_shown(path))
            if not args.check:
                path.write_text(new)
    if args.check:
        if stale:
            print("out of date (run python scripts/make_results.py): " + ", ".join(map(str, stale)), file=sys.stderr)
            return 1
        return 0
    if args.figures:
        for path in draw_figures():
            print(f"drew {_shown(path)}")
    for path in stale:
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
