"""Aggregate a Hydra sweep: one table row per job, figures, and an exit status that says
whether any job failed.

    python -m pipeline.tools.aggregate multirun/<sweep dir>      (also: make aggregate SWEEP=...)

Writes into the sweep dir: `summary.csv` (overrides, status and every metric of every job,
columns in the order of `column_order`), `table.md` and `table.tex` (main results per swept
setting, mean ± std over seeds), `policy_loss.png/.pdf` (policy loss against BIRL
iteration, median and range across seeds: the paper's Fig. 1 right) and `scene.png/.pdf`
(scene, graph nodes, social links, demonstrations and learned paths of one job: Fig. 1
left). Jobs that failed, or never wrote metrics, stay in the table
with their error; the exit status is 1 if there were any.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from pipeline.app.rundir import job_dirs, read_status
from pipeline.artefacts import codec, read_artefact, topics
from pipeline.core.social import OBSTACLE_METRICS, PATH_METRICS
from pipeline.errors import PipelineError


def parse_overrides(job: Path) -> dict[str, str]:
    lines = yaml.safe_load((job / ".hydra" / "overrides.yaml").read_text()) or []
    return dict(line.split("=", 1) for line in lines if "=" in line)


def job_row(job: Path, sweep_dir: Path) -> dict:
    row = {"job": str(job.relative_to(sweep_dir)), **parse_overrides(job)}
    status, metrics_file = read_status(job), job / "metrics.json"
    if not status.complete:  # failed, killed, still running, or made before status.json
        at = f"stage {status.stage}: " if status.stage else ""
        row.update(status=status.state, error=at + (status.error or status.state))
    elif not metrics_file.exists():
        row.update(status="failed", error="no metrics.json (stage evaluate was not run)")
    else:
        row.update(status="ok", error="")
        row.update(json.loads(metrics_file.read_text()))
    return row


def summary_table(sweep_dir: Path) -> pd.DataFrame:
    jobs = job_dirs(sweep_dir)
    if not jobs:
        raise PipelineError(f"sweep dir {sweep_dir} holds no Hydra jobs (.hydra/overrides.yaml)")
    table = pd.DataFrame([job_row(j, sweep_dir) for j in jobs])
    return table[column_order(list(table.columns))]


# summary.csv column order (README "Sweeps, tables and figures"): the job and its outcome,
# the swept settings, the headline metrics, the social metrics (graph, then roadmap), the
# learned weights, everything else, the per-iteration curves, the wall-clock timings.
HEADLINE = ["policy_loss_norm", "policy_loss", "policy_loss_ref"]
SOCIAL = [k for k in PATH_METRICS if k not in OBSTACLE_METRICS]


def column_order(columns: list[str]) -> list[str]:
    def rank(c: str) -> tuple:
        if c in ("job", "status", "error"):
            return (0, ["job", "status", "error"].index(c))
        if not _is_metric(c):
            return (1, c != "seed", c)  # seed first, then the swept keys alphabetically
        if c in HEADLINE:
            return (2, HEADLINE.index(c))
        for k, prefix in enumerate(("", "ref_")):
            if c.removeprefix(prefix) in SOCIAL and c.startswith(prefix):
                return (3 + k, SOCIAL.index(c.removeprefix(prefix)))
        if c.startswith("weight"):
            return (5, c)
        if c.startswith(("policy_loss_iter_", "policy_loss_ref_iter_")):
            return (7, c)
        if c.startswith("time_"):
            return (8, c)
        return (6, c)

    return sorted(columns, key=rank)


def _group_columns(table: pd.DataFrame) -> list[str]:
    """Swept settings other than the seed: each combination is one curve."""
    meta = {"job", "status", "error", "seed"}
    return [c for c in table.columns if c not in meta and not _is_metric(c)
            and table[c].nunique(dropna=False) > 1]


def _is_metric(column: str) -> bool:
    return column.startswith(("policy_loss", "weight", "time_", "ref_", "frechet", "mcmc",
                              "transfer_", "obstacle", "min_distance")) or column in SOCIAL


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


def save_figure(fig, path: Path) -> None:
    """PNG for the README and slides, PDF (vector) for papers; no creation date in the PDF,
    so the same figure gives the same bytes."""
    fig.savefig(path, dpi=150)
    fig.savefig(path.with_suffix(".pdf"), metadata={"CreationDate": None})


def plot_policy_loss(table: pd.DataFrame, path: Path) -> bool:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    ok = table[table.status == "ok"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharex=True, sharey=True)
    plotted = False
    groups = _group_columns(ok)
    for key, part in (ok.groupby(groups, dropna=False) if groups else [("all", ok)]):
        label = ", ".join(setting_label(g, v) for g, v in
                          zip(groups, np.atleast_1d(key), strict=False)) or "all jobs"
        for ax, prefix, title in ((axes[0], "policy_loss_iter_", "adaptive graph"),
                                  (axes[1], "policy_loss_ref_iter_", "reference roadmap")):
            cols = sorted(c for c in part.columns if c.startswith(prefix))
            curves = part[cols].to_numpy(dtype=float)
            if curves.size == 0 or np.isnan(curves).all():
                continue
            x = np.arange(len(cols))
            # Median and the full range over seeds: never below 0, honest with 2-3 seeds.
            line, = ax.plot(x, np.nanmedian(curves, axis=0), label=f"{label} (n={len(part)})")
            ax.fill_between(x, np.nanmin(curves, axis=0), np.nanmax(curves, axis=0),
                            color=line.get_color(), alpha=0.15, lw=0)
            ax.set_title(f"policy loss on the {title}")
            plotted = True
    for ax in axes:
        ax.set_xlabel("BIRL-G iteration")
        ax.set_yscale("symlog", linthresh=1e-4)  # spans 1 to 1e-4, and exact zeros
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(alpha=0.3, which="both")
    axes[0].set_ylabel("policy loss (median; band: min–max over seeds)")
    if plotted:
        axes[1].legend(fontsize=7, loc="upper right")
        fig.tight_layout()
        save_figure(fig, path)
    plt.close(fig)
    return plotted


def plot_scene(job: Path, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    art = read_artefact(job / "scene.mcap")
    scene = art.one(topics.SCENE)
    fig, ax = plt.subplots(figsize=(7.5, 6))
    obstacles = codec.decode_scene(art).obstacles
    if obstacles is not None:  # the map and polygons under the scene
        x0, y0, x1, y1 = obstacles.grid.extent()
        ax.imshow(obstacles.grid.occupied, origin="lower", extent=(x0, x1, y0, y1),
                  cmap="Greys", vmin=0, vmax=1.5, interpolation="nearest")
    if (job / "graph.mcap").exists():  # the graph's samples, as in the paper's Fig. 1 left
        nodes = codec.decode_nodes(read_artefact(job / "graph.mcap")).positions
        ax.plot(nodes[:, 0], nodes[:, 1], ".", color="0.55", ms=3,
                label=f"graph nodes ({len(nodes)})")
    room = scene["room"]
    ax.plot([room["x_min"], room["x_max"], room["x_max"], room["x_min"], room["x_min"]],
            [room["y_min"], room["y_min"], room["y_max"], room["y_max"], room["y_min"]], "k-")
    pos = {p["id"]: (p["x"], p["y"]) for p in scene["persons"]}
    for i, (a, b) in enumerate(scene["relations"]):
        ax.plot(*zip(pos[a], pos[b], strict=True), color="tab:red", lw=2, alpha=0.6,
                label="social links" if i == 0 else None)
    for i, p in enumerate(scene["persons"]):
        ax.add_patch(Circle((p["x"], p["y"]), 1.2, color="tab:orange", alpha=0.08,
                            label="personal zone (1.2 m)" if i == 0 else None))
        ax.add_patch(Circle((p["x"], p["y"]), scene["body_radius"], color="tab:orange",
                            label="persons" if i == 0 else None))
        ax.arrow(p["x"], p["y"], 0.4 * np.cos(p["theta"]), 0.4 * np.sin(p["theta"]),
                 head_width=0.12, color="k")
    for i, d in enumerate(read_artefact(job / "demos.mcap").all(topics.DEMOS)):
        pts = np.asarray(d["points"])
        ax.plot(pts[:, 0], pts[:, 1], "--", color="tab:green", lw=1.5,
                label="demonstrations" if i == 0 else None)
    if (job / "eval.mcap").exists():
        learned = [p for p in read_artefact(job / "eval.mcap").all(topics.EVAL_PATHS)
                   if p["graph"] == "graph"]
        for i, p in enumerate(learned):
            pts = np.asarray(p["points"])
            ax.plot(pts[:, 0], pts[:, 1], color="tab:blue", lw=1.5,
                    label="learned paths" if i == 0 else None)
    starts = np.asarray(scene["starts"])
    ax.plot(starts[:, 0], starts[:, 1], "s", color="tab:purple", label="starts")
    ax.plot(*scene["goal"], "*", color="gold", ms=18, mec="k", label="goal")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"scene '{scene['name']}': demonstrations and learned paths")
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def results_table(table: pd.DataFrame) -> pd.DataFrame:
    """Main results, one row per swept setting: mean ± std over seeds of the headline
    metrics (the table a paper or a README shows)."""
    ok = table[table.status == "ok"]
    groups = _group_columns(ok)
    metrics = [m for m in ("policy_loss_norm", "policy_loss_ref", "relation_crossings",
                           "success") if m in ok.columns]
    rows = []
    for key, part in (ok.groupby(groups, dropna=False) if groups else [("all", ok)]):
        row = {SETTING_NAMES.get(g, g): (METHOD_NAMES.get(str(v), v) if g == "birl" else v)
               for g, v in zip(groups, np.atleast_1d(key), strict=False)}
        row["seeds"] = len(part)
        for m in metrics:
            values = part[m].astype(float)
            row[METRIC_NAMES.get(m, m)] = f"{values.mean():.4f} ± {values.std(ddof=0):.4f}"
        rows.append(row)
    return pd.DataFrame(rows)


def write_tables(table: pd.DataFrame, sweep_dir: Path) -> None:
    results = results_table(table)
    if results.empty:
        return
    (sweep_dir / "table.md").write_text(results.to_markdown(index=False) + "\n")
    latex = results.to_latex(index=False, escape=True).replace("±", "$\\pm$") \
        .replace("β", "$\\beta$")
    (sweep_dir / "table.tex").write_text(latex)


def aggregate(sweep_dir: Path) -> pd.DataFrame:
    table = summary_table(sweep_dir)
    table.to_csv(sweep_dir / "summary.csv", index=False)
    write_tables(table, sweep_dir)
    plot_policy_loss(table, sweep_dir / "policy_loss.png")
    ok = table[table.status == "ok"]
    if len(ok):
        plot_scene(sweep_dir / ok.iloc[0]["job"], sweep_dir / "scene.png")
    return table


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pipeline.tools.aggregate", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sweep_dir", type=Path)
    args = parser.parse_args(argv)
    try:
        if not args.sweep_dir.is_dir():
            raise PipelineError(f"sweep dir {args.sweep_dir} not found")
        table = aggregate(args.sweep_dir)
    except PipelineError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    failed = table[table.status != "ok"]
    cols = [c for c in ("job", "status", "policy_loss", "policy_loss_ref", "policy_loss_norm",
                        "relation_crossings") if c in table.columns]
    print(table[cols].to_string(index=False))
    print(f"{len(table) - len(failed)} of {len(table)} jobs ok; wrote "
          f"{args.sweep_dir / 'summary.csv'} and figures")
    for _, row in failed.iterrows():
        print(f"FAILED {row['job']}: {row['error']}", file=sys.stderr)
    return 1 if len(failed) else 0


if __name__ == "__main__":
    sys.exit(main())
