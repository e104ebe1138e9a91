"""Redraw every committed figure under results/ from its committed table, in the shared style
(pipeline/app/figure_style.py), without re-running a benchmark or a sweep:

    python -m pipeline.tools.redraw            (also: make figures)

Each figure (PNG and PDF) records the SHA-256 digest of the table it was drawn from;
tests/tools/test_figures.py fails when a table changed and its figure was not redrawn.
results/figures/scene.png is no table's figure but a run's: `make sweep EXP=seeds_demos` draws
it (the sweep dir's scene.png), with the table of results/figures/seeds_demos.csv.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

from pipeline.app.context import PROJECT_ROOT
from pipeline.errors import PipelineError, first_line, report
from pipeline.tools import DAMAGED_TABLE, aggregate, bench, bench_learning, bench_scaling, run_tool

# figure -> (its table, the function drawing the figure from the table), under the project root
FIGURES: dict[str, tuple[str, Callable[[Path, Path], object]]] = {
    "results/bench/scaling.png": ("results/bench/scaling.csv", bench_scaling.plot),
    "results/bench/imperfect.png": ("results/bench/imperfect_summary.csv", bench.plot_imperfect),
    "results/bench/irl_methods.png": ("results/bench/irl_methods_curves.csv",
                                      bench.plot_loss_vs_time),
    "results/bench/learning.png": ("results/bench/learning.csv", bench_learning.plot),
    "results/figures/policy_loss.png": ("results/figures/seeds_demos.csv",
                                        aggregate.plot_policy_loss),
}
# figure -> where it comes from, for the committed figures drawn from a run, not a table
RUN_FIGURES = {"results/figures/scene.png": "job 0 of `make sweep EXP=seeds_demos` "
               "(the sweep dir's scene.png)"}


def redraw(root: Path = PROJECT_ROOT) -> list[Path]:
    """Every figure of FIGURES drawn again from its table; the figures written."""
    written = []
    for figure, (table, draw) in FIGURES.items():
        if not (root / table).is_file():
            raise PipelineError(f"{table} not found: `make bench` (or the sweep its figure "
                                "names) writes it")
        try:
            draw(root / table, root / figure)
        except DAMAGED_TABLE as e:
            raise PipelineError(f"{table} cannot be drawn from: {first_line(e)} (missing or "
                                "damaged columns?)") from None
        written.append(root / figure)
    return written


def main(argv: list[str] | None = None) -> int:
    argparse.ArgumentParser(prog="python -m pipeline.tools.redraw",
                            description=__doc__.split("\n")[0]).parse_args(argv)
    try:
        written = redraw()
    except (PipelineError, OSError) as e:
        return report(e, "a figure")
    for path in written:
        print(f"wrote {path.relative_to(PROJECT_ROOT)} (and .pdf)")
    for figure, source in RUN_FIGURES.items():
        print(f"not redrawn: {figure}, from a run: {source}")
    return 0


if __name__ == "__main__":
    run_tool(main)
