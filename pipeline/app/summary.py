"""The table of a Hydra sweep dir: one row per job, with its overrides, its outcome and every
metric of its metrics.json (`make aggregate` writes it as summary.csv, `api.sweep` returns it).
Rows are plain dicts: `make aggregate` runs without pandas, whose import alone would take
most of its time; `api.sweep` makes them a DataFrame.
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING

import yaml

from pipeline.app.metric_keys import is_metric_key
from pipeline.app.rundir import (
    HYDRA_FILES,
    METRICS_FILE,
    job_dirs,
    missing_jobs,
    read_status,
    sweep_jobs,
    unrecorded_jobs,
)
from pipeline.core.social import OBSTACLE_METRICS, PATH_METRICS
from pipeline.errors import PipelineError, file_kind, first_line

if TYPE_CHECKING:
    import pandas as pd


class Unreadable(Exception):
    """A job's side file that cannot be read as what it should be: its row says so."""


def parse_overrides(job: Path) -> dict[str, str]:
    path = job / HYDRA_FILES[-1]
    try:
        lines = yaml.safe_load(path.read_text()) or []
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as e:
        raise Unreadable(f"{path.name} cannot be read ({first_line(e, 120)})") from None
    if not isinstance(lines, list):
        raise Unreadable(f"{path.name} is not a list of overrides")
    for line in lines:  # a damaged line dropped would make the row another setting
        if not (isinstance(line, str) and "=" in line):
            raise Unreadable(f"{path.name}: {json.dumps(line)[:40]} is not an override "
                             "(key=value)")
    return dict(line.split("=", 1) for line in lines)


def read_metrics(path: Path) -> dict:
    """A job's metrics.json: an object of numbers (NaN and null included) or lists of them."""
    try:
        kind = file_kind(path)  # a named pipe would wait for ever, /dev/zero fill memory
        if kind:
            raise Unreadable(f"{path.name} is {kind}, not a file")
        metrics = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise Unreadable(f"{path.name} cannot be read ({first_line(e, 120)})") from None
    if not isinstance(metrics, dict):
        raise Unreadable(f"{path.name} is not an object of metrics")
    for key, value in metrics.items():
        if not (_number(value) or (isinstance(value, list) and all(map(_number, value)))):
            raise Unreadable(f"{path.name}: {key}={json.dumps(value)[:40]} is not a number")
    return metrics


def _number(v: object) -> bool:
    return v is None or (isinstance(v, int | float) and not isinstance(v, bool))


def job_row(job: Path, sweep_dir: Path) -> dict:
    row: dict = {"job": str(job.relative_to(sweep_dir))}
    try:
        row.update(parse_overrides(job))
        status, metrics_file = read_status(job), job / METRICS_FILE
        if not status.complete:  # failed, killed, still running, or made before status.json
            at = f"stage {status.stage}: " if status.stage else ""
            row.update(status=status.state, error=at + (status.error or status.state))
        elif not metrics_file.exists():
            row.update(status="failed", error="no metrics.json (stage evaluate was not run)")
        else:
            metrics = read_metrics(metrics_file)
            row.update(status="ok", error="")
            if clash := sorted(set(metrics) & set(row)):  # a foreign or hand-edited file
                raise Unreadable(f"{metrics_file}: key '{clash[0]}' is a column of the "
                                 "table (the job, its outcome or an override), not a metric")
            row.update(metrics)
    except Unreadable as e:  # one damaged job is one failed row, not a failed table
        row.update(status="failed", error=str(e))
    return row


def summary_rows(sweep_dir: Path) -> tuple[list[str], list[dict]]:
    """The columns (in `column_order`) and one row per job of the last sweep into
    `sweep_dir` (jobs in natural order; a row lacks the keys its job did not write; job dirs
    an earlier sweep left there are not rows: `sweep_jobs`)."""
    if Path(sweep_dir) in job_dirs(sweep_dir):  # `make aggregate SWEEP=` given one run's dir
        raise PipelineError(f"{sweep_dir} is a run dir (it has .hydra/overrides.yaml), not a "
                            "sweep dir; give the dir that holds the sweep's numbered jobs")
    jobs = sweep_jobs(sweep_dir)[0]
    rows = [job_row(j, sweep_dir) for j in jobs]
    listed = {row["job"] for row in rows}
    # jobs no status.json could say failed, and jobs whose dirs went missing since
    rows += [{"job": job, "status": "failed", "error": error} for job, error in
             {**missing_jobs(sweep_dir), **unrecorded_jobs(sweep_dir)}.items()
             if job not in listed]
    if not rows:
        raise PipelineError(f"sweep dir {sweep_dir} holds no Hydra jobs (.hydra/overrides.yaml)")
    return column_order(list(dict.fromkeys(key for row in rows for key in row))), rows


def summary_table(sweep_dir: Path) -> pd.DataFrame:
    """`summary_rows` as a DataFrame, read as `pd.read_csv` reads summary.csv (numbers as
    numbers, the swept settings' values included; missing values NaN)."""
    import pandas as pd

    return pd.read_csv(io.StringIO(summary_csv(*summary_rows(sweep_dir))))


def summary_csv(columns: list[str], rows: list[dict]) -> str:
    """summary.csv's text: a missing value is an empty cell (as pandas writes NaN and None)."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(columns)
    writer.writerows([["" if missing_value(r.get(c)) else r[c] for c in columns] for r in rows])
    return text.getvalue()


def missing_value(value: object) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value))


# summary.csv column order (docs/outputs.md, "Sweeps"): the job and its outcome,
# the swept settings, the headline metrics, the social metrics (graph, then roadmap), the
# learned weights, everything else, the per-iteration curves, the wall-clock timings.
HEADLINE = ["policy_loss_norm", "policy_loss", "policy_loss_ref"]
SOCIAL = [k for k in PATH_METRICS if k not in OBSTACLE_METRICS]


def column_order(columns: list[str]) -> list[str]:
    def rank(c: str) -> tuple:
        if c in ("job", "status", "error"):
            return (0, ["job", "status", "error"].index(c))
        if not is_metric(c):
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


def is_metric(column: str) -> bool:
    """A metrics.json key (else a swept setting or the job's own columns): the keys the
    evaluate stage writes (is_metric_key), and the prefixes of older runs' keys."""
    return is_metric_key(column) or column in SOCIAL or column.startswith(
        ("policy_loss", "weight", "time_", "ref_", "frechet", "mcmc", "transfer_", "obstacle",
         "min_distance"))
