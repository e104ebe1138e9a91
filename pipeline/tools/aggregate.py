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

from pipeline.app.figure_style import COLOURS, PAGE_IN, new_figure, paper_style, save_figure
from pipeline.app.rundir import is_locked, sweep_finished, sweep_jobs, sweep_stopped_why
from pipeline.app.summary import is_metric, missing_value, summary_csv, summary_rows
from pipeline.artefacts.store import write_text_atomic
from pipeline.artefacts.topics import ARTEFACT_FILE
from pipeline.errors import PipelineError, existing_dir, os_error_reason
from pipeline.tools import run_tool

# A table as the sweep's jobs give it: plain rows (dicts; a row lacks what its job did not
# write). pandas is left out of the tables' path: its import alone (0.3-0.5 s) would be most
# of the aggregation's time; the figures, which load matplotlib anyway, use it.
Row = dict


def varies(column: str, rows: list[Row]) -> bool:
    """Whether the column's value (or its absence) differs between rows."""
    return len({None if missing_value(r.get(column)) else r[column] for r in rows}) > 1


def swept_columns(columns: list[str], rows: list[Row]) -> list[str]:
    """Swept settings other than the seed, among `columns`: each combination of their
    values is one curve or table row."""
    meta = {"job", "status", "error", "seed"}
    return [c for c in columns if c not in meta and not is_metric(c) and varies(c, rows)]


def group_rows(rows: list[Row], groups: list[str]) -> list[tuple[tuple, list[Row]]]:
    """The rows per combination of the `groups` columns' values, ordered by those values
    (missing last), as pandas' groupby(sort=True, dropna=False); one group of every row
    when there are no groups."""
    parts: dict[tuple, list[Row]] = {}
    for row in rows:
        key = tuple(None if missing_value(row.get(g)) else row[g] for g in groups)
        parts.setdefault(key, []).append(row)
    return sorted(parts.items(), key=lambda item: [_in_order(v) for v in item[0]])


def _in_order(value: object) -> tuple:
    """Sort key of a setting's value: numbers by value (an override's 12.5 after 2.3, not
    before it as text), then other values as text, missing last."""
    if value is None:
        return (2, 0.0, "")
    try:
        return (0, float(str(value)), "")
    except ValueError:
        return (1, 0.0, str(value))


SUMMARY_FILE = "summary.csv"
# Names as in the paper and the README, for legends and table headers.
METHOD_NAMES = {"map": "BIRL-G (MAP)", "mcmc": "BIRL-G (MCMC)", "policywalk": "PolicyWalk",
                "maxent": "MaxEnt", "fixed": "fixed weights"}
SETTING_NAMES = {"birl": "method", "expert.beta": "β_E", "expert.n_starts": "demos",
                 "expert": "expert", "reward": "reward", "scene": "scene", "birl.beta": "β"}
METRIC_NAMES = {"policy_loss_norm": "normalised policy loss", "policy_loss_ref":
                "policy loss (roadmap)", "policy_loss": "policy loss (graph)",
                "relation_crossings": "link crossings", "success": "success rate",
                "heldout_frechet_m": "held-out Fréchet (m)",
                "heldout_log_likelihood": "held-out log likelihood"}
# The results table's metrics, where the sweep has them: the policy loss where a true
# reward is known, how held-out demonstrations are predicted where some were held out.
TABLE_METRICS = ("policy_loss_norm", "policy_loss_ref", "relation_crossings", "success",
                 "heldout_frechet_m", "heldout_log_likelihood")


def setting_label(key: str, value) -> str:
    value = METHOD_NAMES.get(str(value), value) if key == "birl" else value
    return f"{SETTING_NAMES.get(key, key)} {value}"


def plot_policy_loss(summary_csv: Path, path: Path) -> bool:
    """Policy loss against BIRL iteration on the adaptive graph and on the reference roadmap,
    one colour per swept setting, from a sweep's summary.csv: the median over seeds, and the
    range over seeds as thin lines (bands of several settings would overlap and mix). False,
    and no figure, when no job has the curves."""
    import pandas as pd
    from matplotlib.lines import Line2D
    from matplotlib.ticker import MaxNLocator

    table = pd.read_csv(summary_csv)
    columns = list(table.columns)
    ok = table[table.status == "ok"].to_dict("records")
    groups = swept_columns(columns, ok)
    with paper_style():
        fig = new_figure(PAGE_IN, 2.8)
        axes = fig.subplots(1, 2, sharex=True, sharey=True)
        handles = []
        for key, part in group_rows(ok, groups):
            label = ", ".join(setting_label(g, v)
                              for g, v in zip(groups, key, strict=True)) or "all jobs"
            colour = COLOURS[len(handles) % len(COLOURS)]
            for ax, prefix in ((axes[0], "policy_loss_iter_"), (axes[1], "policy_loss_ref_iter_")):
                curves = np.array([[row[c] for c in sorted(c for c in columns
                                                          if c.startswith(prefix))]
                                   for row in part], dtype=float)
                if curves.size == 0 or np.isnan(curves).all():
                    continue
                # iterations some job of the group has (methods of other lengths: NaN)
                x = np.flatnonzero(~np.isnan(curves).all(axis=0))
                curves = curves[:, x]
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
    from pipeline.app.figures import draw_scene

    with paper_style():
        fig = new_figure(PAGE_IN, PAGE_IN)  # resized to the room by draw_scene
        draw_scene(fig.subplots(), job, fit_figure=True)
        save_figure(fig, path)


def results_table(columns: list[str], rows: list[Row]) -> tuple[list[Row], list[Row]]:
    """Main results, one row per swept setting: mean ± std over seeds of the headline
    metrics (the table a paper or a README shows); and the means, for marking the best.
    Settings whose jobs failed are rows too: with a `failed` column counting them, and
    without values where no job of the setting ran (none when no job of the sweep ran)."""
    if not any(r.get("status") == "ok" for r in rows):
        return [], []
    # the jobs whose settings are known (a job whose dir is gone has none)
    known = [r for r in rows if any(k not in ("job", "status", "error") and not is_metric(k)
                                    for k in r)]
    groups = swept_columns(columns, known)
    metrics = [m for m in TABLE_METRICS if m in columns]
    any_failed = any(r.get("status") != "ok" for r in known)
    results, means = [], []
    for key, part in group_rows(known, groups):
        ok = [r for r in part if r.get("status") == "ok"]
        row: Row = {SETTING_NAMES.get(g, g): (METHOD_NAMES.get(str(v), v) if g == "birl" else v)
                    for g, v in zip(groups, key, strict=True)}
        row["seeds"] = len(ok)
        if any_failed:
            row["failed"] = len(part) - len(ok)
        means.append({})
        for m in metrics:
            values = np.array([np.nan if missing_value(r.get(m)) else r[m] for r in ok],
                              dtype=float)
            # over the jobs that report it (no policy loss without true weights, say)
            values = values[~np.isnan(values)]
            row[METRIC_NAMES.get(m, m)] = mean_std(values)
            means[-1][METRIC_NAMES.get(m, m)] = float(np.mean(values)) if len(values) else np.nan
        results.append(row)
    return results, means


# Higher is better for these; lower for every other metric of the table.
HIGHER_IS_BETTER = {METRIC_NAMES["success"], METRIC_NAMES["heldout_log_likelihood"]}


def mean_std(values: np.ndarray) -> str:
    """'mean ± std' over seeds, the sample std (ddof = 1; only the mean for one seed); counts
    (every value a whole number) as whole numbers where the mean is one, else to 0.1; empty
    for no values."""
    if len(values) == 0:
        return ""
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


def best_rows(means: list[Row]) -> dict[str, set[int]]:
    """Per metric column, the rows with the best mean (ties: all of them)."""
    best = {}
    for col in means[0] if means else ():
        values = np.array([m[col] for m in means])  # NaN: a setting none of whose jobs ran
        if np.isnan(values).all():
            continue
        target = np.nanmax(values) if col in HIGHER_IS_BETTER else np.nanmin(values)
        best[col] = set(np.flatnonzero(np.isclose(values, target, rtol=0, atol=1e-12)))
    return best


# LaTeX's special characters, escaped as pandas' to_latex(escape=True) does; ± and β in math.
_LATEX_ESCAPES = {"\\": r"\textbackslash ", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#",
                  "_": r"\_", "{": r"\{", "}": r"\}", "~": r"\textasciitilde ",
                  "^": r"\textasciicircum ", "±": r"$\pm$", "β": r"$\beta$"}
_LATEX_SPECIAL = re.compile("|".join(re.escape(k) for k in _LATEX_ESCAPES))


def latex_cell(value) -> str:
    return _LATEX_SPECIAL.sub(lambda m: _LATEX_ESCAPES[m.group()], str(value))


def latex_table(results: list[Row], bold: dict[str, set[int]]) -> str:
    """A booktabs tabular of the results, the cells of `bold` (column -> rows) in bold, as
    pandas' DataFrame.to_latex writes it (whose Styler and jinja2 templates would take longer
    to load than the rest of the aggregation)."""
    columns = list(results[0])
    align = "".join("r" if all(_is_number(r[c]) for r in results) else "l" for c in columns)
    lines = [rf"\begin{{tabular}}{{{align}}}", r"\toprule",
             " & ".join(latex_cell(c) for c in columns) + r" \\", r"\midrule"]
    for i, row in enumerate(results):
        cells = [rf"\textbf{{{latex_cell(row[c])}}}" if i in bold.get(c, ())
                 else latex_cell(row[c]) for c in columns]
        lines.append(" & ".join(cells) + r" \\")
    return "\n".join([*lines, r"\bottomrule", r"\end{tabular}", ""])


def _is_number(value) -> bool:
    return isinstance(value, int | float | np.number) and not isinstance(value, bool)


def markdown_table(results: list[Row]) -> str:
    """The results as a Markdown (pipe) table, as pandas' DataFrame.to_markdown writes it."""
    from tabulate import tabulate

    return tabulate(results, headers="keys", tablefmt="pipe", showindex=False)


def write_tables(columns: list[str], rows: list[Row], sweep_dir: Path) -> None:
    results, means = results_table(columns, rows)
    if not results:
        return
    write_text_atomic(sweep_dir / "table.md", markdown_table(results) + "\n")
    # the best value of each metric in bold, where there is more than one row to compare
    bold = best_rows(means) if len(results) > 1 else {}
    write_text_atomic(sweep_dir / "table.tex", latex_table(results, bold))


def write_summary_csv(columns: list[str], rows: list[Row], path: Path) -> None:
    # a full disk leaves the old table, not an empty one
    write_text_atomic(path, summary_csv(columns, rows))


FIGURES = ("policy_loss", "scene")  # each as .png and .pdf


def aggregate(sweep_dir: Path, figures: bool = True) -> tuple[list[str], list[Row]]:
    """Write the sweep's tables (and figures); its columns and rows."""
    columns, rows = summary_rows(sweep_dir)
    # what an earlier aggregation drew must not outlive it beside the new table (a table or
    # figure needs jobs that ran; when none did, there is none)
    stale = ["table.md", "table.tex"] + [f"{name}.{ext}" for name in FIGURES
                                         for ext in ("png", "pdf")]
    for name in stale:
        (sweep_dir / name).unlink(missing_ok=True)
    write_summary_csv(columns, rows, sweep_dir / SUMMARY_FILE)
    write_tables(columns, rows, sweep_dir)
    if not figures:  # the tables alone: a fifth of the time (matplotlib, pandas, artefacts)
        return columns, rows
    plot_policy_loss(sweep_dir / SUMMARY_FILE, sweep_dir / f"{FIGURES[0]}.png")
    # the scene of the first job that ran and kept its scene (a copied or pruned job may not)
    from pipeline.artefacts.store import ArtefactError  # the artefact readers: figures only

    drawn = [sweep_dir / r["job"] for r in rows if r["status"] == "ok"
             and (sweep_dir / r["job"] / ARTEFACT_FILE["scene"]).is_file()]
    for job in drawn:
        try:  # a damaged artefact of one job leaves the figure to the next
            plot_scene(job, sweep_dir / f"{FIGURES[1]}.png")
            break
        except ArtefactError as e:
            print(f"note: no scene figure from job {job.name}: {e}", file=sys.stderr)
    return columns, rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pipeline.tools.aggregate", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sweep_dir", type=Path)
    parser.add_argument("--no-figures", dest="figures", action="store_false",
                        help="write the tables only (summary.csv, table.md, table.tex)")
    args = parser.parse_args(argv)
    # taken before the jobs are read: a sweep that ends meanwhile left rows of running jobs
    running = args.sweep_dir.is_dir() and is_locked(args.sweep_dir)
    try:
        columns, rows = aggregate(existing_dir(args.sweep_dir, "sweep dir"),
                                  figures=args.figures)
    except PipelineError as e:
        print(f"error: {e}" + (" (the sweep still runs: aggregate it when it ends)"
                               if running else ""), file=sys.stderr)
        return 2
    except OSError as e:  # a full disk, a read-only dir, a dir where a table goes
        print(f"error: cannot write the tables into {args.sweep_dir}: {os_error_reason(e)}",
              file=sys.stderr)
        return 2
    from tabulate import tabulate

    failed = [r for r in rows if r["status"] != "ok"]
    # which job is which: the seed where it varies, and the swept settings
    swept = [*(["seed"] if "seed" in columns and varies("seed", rows) else []),
             *swept_columns(columns, rows)]
    cols = [c for c in ("job", "status", *swept, "policy_loss", "policy_loss_ref",
                        "policy_loss_norm", "relation_crossings", "heldout_frechet_m",
                        "heldout_log_likelihood") if c in columns]
    print(tabulate([[r.get(c) for c in cols] for r in rows], headers=cols, tablefmt="plain",
                   missingval="NaN"))
    drawn = args.figures and len(failed) < len(rows)  # the figures need a job that ran
    print(f"{len(rows) - len(failed)} of {len(rows)} jobs ok; wrote "
          f"{args.sweep_dir / SUMMARY_FILE}{' and figures' if drawn else ''}")
    in_rows = {r["job"] for r in rows}  # (a job of this sweep that failed in such a dir)
    earlier = [j for j in sweep_jobs(args.sweep_dir)[1]
               if str(j.relative_to(args.sweep_dir)) not in in_rows]
    if earlier:
        names = ", ".join(str(j.relative_to(args.sweep_dir)) for j in earlier[:10])
        print(f"note: left out {len(earlier)} job dir(s) an earlier sweep into this dir left "
              f"there ({names}{', ...' if len(earlier) > 10 else ''})", file=sys.stderr)
    for row in failed:
        print(f"FAILED {row['job']}: {row['error']}", file=sys.stderr)
    if running or not sweep_finished(args.sweep_dir):
        why = sweep_stopped_why(args.sweep_dir)
        if running:
            how = "still runs" if is_locked(args.sweep_dir) else \
                "still ran when this aggregation began; aggregate it again"
        else:
            how = f"was stopped{f': {why}' if why else ''}"
        print(f"error: the sweep did not finish (it {how}): jobs it had not started are in "
              "no row", file=sys.stderr)
        return 1
    return 1 if failed else 0


if __name__ == "__main__":
    run_tool(main)
