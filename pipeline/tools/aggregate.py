"""Aggregate a Hydra sweep: one table row per job, figures, and an exit status that says
whether any job failed.

    python -m pipeline.tools.aggregate multirun/<sweep dir>      (also: make aggregate SWEEP=...)

Writes into the sweep dir: `summary.csv` (overrides, status and every metric of every job,
columns in the order of `column_order`: pipeline/app/summary.py, which `api.sweep` shares),
`table.md` and `table.tex` (main results per swept setting, mean ± std over seeds),
`policy_loss.png/.pdf` (policy loss against BIRL iteration, median and range across seeds:
the paper's Fig. 1 right) and `scene.png/.pdf` (scene, graph nodes, social links,
demonstrations and learned paths of one job: Fig. 1 left; pipeline/app/figures.py). Jobs
that failed, or never wrote metrics, stay in the table with their error; the exit status is
1 if there were any.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.app.figure_style import COLOURS, PAGE_IN, new_figure, paper_style, save_figure
from pipeline.app.summary import is_metric, summary_table
from pipeline.errors import PipelineError


def _group_columns(table: pd.DataFrame) -> list[str]:
    """Swept settings other than the seed: each combination is one curve."""
    meta = {"job", "status", "error", "seed"}
    return [c for c in table.columns if c not in meta and not is_metric(c)
            and table[c].nunique(dropna=False) > 1]


SUMMARY_FILE = "summary.csv"
# Names as in the paper and the README, for legends and table headers.
METHOD_NAMES = {"map": "BIRL-G (MAP)", "mcmc": "BIRL-G (MCMC)", "policywalk": "PolicyWalk",
                "maxent": "MaxEnt", "fixed": "fixed weights"}
SETTING_NAMES = {"birl": "method", "expert.beta": "β_E", "expert.n_starts": "demos",
                 "expert": "expert", "reward": "reward", "scene": "scene", "birl.beta": "β"}
METRIC_NAMES = {"policy_loss_norm": "normalised policy loss", "policy_loss_ref":
                "policy loss (roadmap)", "policy_loss": "policy loss (graph)",
                "relation_crossings": "link crossings", "success": "success rate"}


def setting_label(key: str, value) -> str:
    value = METHOD_NAMES.get(str(value), value) if key == "birl" else value
    return f"{SETTING_NAMES.get(key, key)} {value}"


def plot_policy_loss(summary_csv: Path, path: Path) -> bool:
    """Policy loss against BIRL iteration on the adaptive graph and on the reference roadmap,
    one colour per swept setting, from a sweep's summary.csv: the median over seeds, and the
    range over seeds as thin lines (bands of several settings would overlap and mix). False,
    and no figure, when no job has the curves."""
    from matplotlib.lines import Line2D
    from matplotlib.ticker import MaxNLocator

    table = pd.read_csv(summary_csv)
    ok = table[table.status == "ok"]
    groups = _group_columns(ok)
    with paper_style():
        fig = new_figure(PAGE_IN, 2.8)
        axes = fig.subplots(1, 2, sharex=True, sharey=True)
        handles = []
        for key, part in (ok.groupby(groups, dropna=False) if groups else [("all", ok)]):
            label = ", ".join(setting_label(g, v) for g, v in
                              zip(groups, np.atleast_1d(key), strict=False)) or "all jobs"
            colour = COLOURS[len(handles) % len(COLOURS)]
            for ax, prefix in ((axes[0], "policy_loss_iter_"), (axes[1], "policy_loss_ref_iter_")):
                curves = part[sorted(c for c in part.columns if c.startswith(prefix))] \
                    .to_numpy(dtype=float)
                if curves.size == 0 or np.isnan(curves).all():
                    continue
                x = np.arange(curves.shape[1])
                # Median and the full range over seeds: never below 0, honest with 2-3 seeds.
                ax.plot(x, np.nanmedian(curves, axis=0), color=colour)
                for bound in (np.nanmin(curves, axis=0), np.nanmax(curves, axis=0)):
                    ax.plot(x, bound, color=colour, lw=0.5, ls=(0, (2, 2)))
            handles.append(Line2D([], [], color=colour, label=f"{label} (n={len(part)})"))
        if not any(ax.lines for ax in axes):
            return False
        for ax, title in zip(axes, ("adaptive graph", "reference roadmap"), strict=True):
            ax.set_title(f"policy loss on the {title}")
            ax.set_xlabel("BIRL-G iteration")
            ax.set_yscale("symlog", linthresh=1e-4)  # spans 1 to 1e-4, and exact zeros
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
            ax.grid(which="major")
        axes[0].set_ylabel("policy loss")
        handles += [Line2D([], [], color="k", label="median over seeds"),
                    Line2D([], [], color="k", lw=0.5, ls=(0, (2, 2)), label="min and max")]
        fig.legend(handles=handles, loc="outside lower center", ncol=3)
        save_figure(fig, path, [summary_csv])
    return True


def plot_scene(job: Path, path: Path) -> None:
    # the artefact readers: only for this figure
    from pipeline.app.figures import SCENE_SIZE_IN, draw_scene

    with paper_style():
        fig = new_figure(*SCENE_SIZE_IN)
        draw_scene(fig.subplots(), job)
        save_figure(fig, path)


def results_table(table: pd.DataFrame) -> pd.DataFrame:
    """Main results, one row per swept setting: mean ± std over seeds of the headline
    metrics (the table a paper or a README shows)."""
    ok = table[table.status == "ok"]
    groups = _group_columns(ok)
    metrics = [m for m in ("policy_loss_norm", "policy_loss_ref", "relation_crossings",
                           "success") if m in ok.columns]
    rows, means = [], []
    for key, part in (ok.groupby(groups, dropna=False) if groups else [("all", ok)]):
        row = {SETTING_NAMES.get(g, g): (METHOD_NAMES.get(str(v), v) if g == "birl" else v)
               for g, v in zip(groups, np.atleast_1d(key), strict=False)}
        row["seeds"] = len(part)
        means.append({})
        for m in metrics:
            values = part[m].astype(float).to_numpy()
            row[METRIC_NAMES.get(m, m)] = mean_std(values)
            means[-1][METRIC_NAMES.get(m, m)] = float(np.mean(values))
        rows.append(row)
    table = pd.DataFrame(rows)
    table.attrs["means"] = pd.DataFrame(means)  # for marking the best value
    return table


# Higher is better for these; lower for every other metric of the table.
HIGHER_IS_BETTER = {METRIC_NAMES.get("success", "success")}


def mean_std(values: np.ndarray) -> str:
    """'mean ± std' over seeds, the sample std (ddof = 1; only the mean for one seed); counts
    (every value a whole number) as whole numbers where the mean is one, else to 0.1."""
    counts = bool(np.all(values == np.round(values)))
    mean = float(np.mean(values))
    if counts:
        text = f"{mean:.0f}" if mean == round(mean) else f"{mean:.1f}"
    else:
        text = f"{mean:.4f}"
    if len(values) < 2:
        return text
    std = float(np.std(values, ddof=1))
    return f"{text} ± {std:.1f}" if counts else f"{text} ± {std:.4f}"


def best_rows(means: pd.DataFrame) -> dict[str, set[int]]:
    """Per metric column, the rows with the best mean (ties: all of them)."""
    best = {}
    for col in means.columns:
        target = means[col].max() if col in HIGHER_IS_BETTER else means[col].min()
        best[col] = set(np.flatnonzero(np.isclose(means[col], target, rtol=0, atol=1e-12)))
    return best


# LaTeX's special characters, escaped as pandas' to_latex(escape=True) does; ± and β in math.
_LATEX_ESCAPES = {"\\": r"\textbackslash ", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#",
                  "_": r"\_", "{": r"\{", "}": r"\}", "~": r"\textasciitilde ",
                  "^": r"\textasciicircum ", "±": r"$\pm$", "β": r"$\beta$"}
_LATEX_SPECIAL = re.compile("|".join(re.escape(k) for k in _LATEX_ESCAPES))


def latex_cell(value) -> str:
    return _LATEX_SPECIAL.sub(lambda m: _LATEX_ESCAPES[m.group()], str(value))


def latex_table(results: pd.DataFrame, bold: dict[str, set[int]]) -> str:
    """A booktabs tabular of the results, the cells of `bold` (column -> rows) in bold.
    Written here rather than by DataFrame.to_latex, whose Styler and jinja2 templates take
    longer to load than the rest of the aggregation."""
    align = "".join("r" if pd.api.types.is_numeric_dtype(results[c]) else "l"
                    for c in results.columns)
    lines = [rf"\begin{{tabular}}{{{align}}}", r"\toprule",
             " & ".join(latex_cell(c) for c in results.columns) + r" \\", r"\midrule"]
    for i, row in enumerate(results.itertuples(index=False)):
        cells = [latex_cell(v) for v in row]
        cells = [rf"\textbf{{{c}}}" if i in bold.get(col, ()) else c
                 for col, c in zip(results.columns, cells, strict=True)]
        lines.append(" & ".join(cells) + r" \\")
    return "\n".join([*lines, r"\bottomrule", r"\end{tabular}", ""])


def write_tables(table: pd.DataFrame, sweep_dir: Path) -> None:
    results = results_table(table)
    if results.empty:
        return
    (sweep_dir / "table.md").write_text(results.to_markdown(index=False) + "\n")
    # the best value of each metric in bold, where there is more than one row to compare
    bold = best_rows(results.attrs["means"]) if len(results) > 1 else {}
    (sweep_dir / "table.tex").write_text(latex_table(results, bold))


def aggregate(sweep_dir: Path, figures: bool = True) -> pd.DataFrame:
    table = summary_table(sweep_dir)
    table.to_csv(sweep_dir / SUMMARY_FILE, index=False)
    write_tables(table, sweep_dir)
    if not figures:  # the table alone: a third of the time (matplotlib, the artefacts)
        return table
    plot_policy_loss(sweep_dir / SUMMARY_FILE, sweep_dir / "policy_loss.png")
    ok = table[table.status == "ok"]
    if len(ok):
        plot_scene(sweep_dir / ok.iloc[0]["job"], sweep_dir / "scene.png")
    return table


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pipeline.tools.aggregate", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sweep_dir", type=Path)
    parser.add_argument("--no-figures", dest="figures", action="store_false",
                        help="write the tables only (summary.csv, table.md, table.tex)")
    args = parser.parse_args(argv)
    try:
        if not args.sweep_dir.is_dir():
            raise PipelineError(f"sweep dir {args.sweep_dir} not found")
        table = aggregate(args.sweep_dir, figures=args.figures)
    except PipelineError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    failed = table[table.status != "ok"]
    swept = [c for c in ("seed", *_group_columns(table)) if c in table.columns
             and table[c].nunique(dropna=False) > 1]  # which job is which
    cols = [c for c in ("job", "status", *swept, "policy_loss", "policy_loss_ref",
                        "policy_loss_norm", "relation_crossings") if c in table.columns]
    print(table[cols].to_string(index=False))
    print(f"{len(table) - len(failed)} of {len(table)} jobs ok; wrote "
          f"{args.sweep_dir / SUMMARY_FILE}{' and figures' if args.figures else ''}")
    for _, row in failed.iterrows():
        print(f"FAILED {row['job']}: {row['error']}", file=sys.stderr)
    return 1 if len(failed) else 0


if __name__ == "__main__":
    sys.exit(main())
