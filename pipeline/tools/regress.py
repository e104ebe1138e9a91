"""Metric regression tests against results/baseline/ (`make regress`).

    python -m pipeline.tools.regress                       # run every reference experiment, compare
    python -m pipeline.tools.regress --only metropolis_polite_s0
    python -m pipeline.tools.regress --update              # accept the current metrics as baseline

results/baseline/experiments.yaml names the reference experiments (Hydra overrides each),
results/baseline/<name>.json holds their metrics, results/baseline/tolerances.yaml says how
far each metric may move. Any metric outside its tolerance, or missing, fails the run.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import pandas as pd
import yaml

from pipeline.app.context import PROJECT_ROOT
from pipeline.app.rundir import METRICS_FILE
from pipeline.app.summary import Unreadable, read_metrics
from pipeline.artefacts.store import write_text_atomic
from pipeline.errors import PipelineError, first_line, os_error_reason
from pipeline.tools import dir_override, run_tool

BASELINE = PROJECT_ROOT / "results" / "baseline"


def _load(path: Path, kind: type):
    """A YAML file that must hold a `kind` (dict or list), or one line saying why not."""
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, ValueError, yaml.YAMLError) as e:
        raise PipelineError(f"{path} cannot be read ({first_line(e)})") from None
    if not isinstance(data, kind) or not data:
        raise PipelineError(f"{path} does not hold a non-empty {kind.__name__}")
    return data


def load_tolerances(baseline: Path) -> list[tuple[str, dict | str]]:
    spec = _load(baseline / "tolerances.yaml", dict)
    if not isinstance(spec.get("patterns"), dict) or "default" not in spec:
        raise PipelineError(f"{baseline / 'tolerances.yaml'} needs 'patterns' (a mapping) and "
                            "'default'")
    tolerances = list(spec["patterns"].items()) + [("*", spec["default"])]
    for pattern, tol in tolerances:
        where = "default" if pattern == "*" else f"patterns[{pattern!r}]"
        if tol == "ignore":
            continue
        if not (isinstance(tol, dict) and tol and set(tol) <= {"abs", "rel"} and
                all(isinstance(v, int | float) and not isinstance(v, bool) and v >= 0
                    for v in tol.values())):
            raise PipelineError(f"{baseline / 'tolerances.yaml'}: {where} must be 'ignore' or "
                                f"a mapping of abs and/or rel to numbers >= 0, not {tol!r}")
    return tolerances


def tolerance_for(metric: str, tolerances) -> dict | str:
    return next(tol for pattern, tol in tolerances if fnmatch.fnmatch(metric, pattern))


def read_baseline(path: Path) -> dict:
    try:
        baseline = read_metrics(path)  # numbers only, as a run's metrics.json
    except Unreadable as e:
        raise PipelineError(f"{path.parent}: {e}") from None
    if not baseline:
        raise PipelineError(f"{path} holds no metrics")
    return baseline


def run_experiment(name: str, overrides: list[str], work: Path, reuse: bool) -> dict:
    run_dir = work / name
    if not (reuse and (run_dir / METRICS_FILE).exists()):
        result = subprocess.run([sys.executable, "-m", "pipeline",
                                 dir_override("hydra.run.dir", run_dir), *overrides],
                                cwd=PROJECT_ROOT, capture_output=True, text=True)
        if result.returncode != 0:
            last = (result.stderr.strip().splitlines() or ["no message"])[-1]
            raise PipelineError(f"reference experiment {name} failed: {last}")
    try:
        metrics = read_metrics(run_dir / METRICS_FILE)  # the check aggregate makes
    except Unreadable as e:
        raise PipelineError(f"{run_dir}: {e}") from None
    if not metrics:
        raise PipelineError(f"{run_dir / 'metrics.json'} holds no metrics")
    return metrics


COLUMNS = ["experiment", "metric", "baseline", "current", "diff", "tolerance", "ok"]


def compare(name: str, baseline: dict, current: dict, tolerances) -> list[dict]:
    rows = []
    for metric in sorted(set(baseline) | set(current)):
        tol = tolerance_for(metric, tolerances)
        if tol == "ignore":
            continue
        old, new = baseline.get(metric), current.get(metric)
        for value, where in ((old, "baseline"), (new, "current run")):
            if isinstance(value, list):  # read_metrics allows them (aggregate's tables)
                raise PipelineError(f"{name}: {metric} is a list in the {where}, not a number")
        if old is None or new is None:
            ok, diff, allowed = old is None, None, None  # a new metric is fine, a lost one not
        else:
            diff = new - old
            allowed = tol.get("abs", 0.0) + tol.get("rel", 0.0) * abs(old)
            ok = abs(diff) <= allowed
        rows.append({"experiment": name, "metric": metric, "baseline": old, "current": new,
                     "diff": diff, "tolerance": allowed, "ok": ok})
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pipeline.tools.regress", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", nargs="+", help="reference experiments to run (default: all)")
    parser.add_argument("--baseline", type=Path, default=BASELINE)
    parser.add_argument("--work", type=Path, help="where the runs go (default: a temp dir)")
    parser.add_argument("--reuse", action="store_true", help="reuse runs already in --work")
    parser.add_argument("--update", action="store_true", help="write current metrics as baseline")
    parser.add_argument("--all-rows", action="store_true",
                        help="print every metric, not only failures")
    args = parser.parse_args(argv)
    try:
        return _regress(args)
    except PipelineError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


def _regress(args: argparse.Namespace) -> int:
    if not args.baseline.is_dir():
        raise PipelineError(f"--baseline {args.baseline} is not a directory")
    if args.work is not None and args.work.exists() and not args.work.is_dir():
        raise PipelineError(f"--work {args.work} is a file, not a directory")
    experiments = _load(args.baseline / "experiments.yaml", dict)
    bad = [n for n, o in experiments.items()
           if not isinstance(o, list) or not all(isinstance(x, str) for x in o)]
    if bad:
        raise PipelineError(f"{args.baseline / 'experiments.yaml'}: {bad[0]} must be a list of "
                            "overrides (strings)")
    names = args.only or list(experiments)
    unknown = [n for n in names if n not in experiments]
    if unknown:
        print(f"error: unknown reference experiment(s) {unknown}; known: {list(experiments)}",
              file=sys.stderr)
        return 2
    tolerances = load_tolerances(args.baseline)
    baselines = {}  # read before any experiment runs: a missing or damaged one is said at once
    for name in [] if args.update else names:
        path = args.baseline / f"{name}.json"
        if not path.exists():
            print(f"error: no baseline {path}; create it with --update", file=sys.stderr)
            return 2
        baselines[name] = read_baseline(path)
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        rows, updated = [], {}
        for name in names:
            print(f"running {name}: {' '.join(experiments[name]) or '(defaults)'}", flush=True)
            current = run_experiment(name, experiments[name], work, args.reuse)
            if args.update:
                updated[args.baseline / f"{name}.json"] = {
                    k: v for k, v in current.items() if tolerance_for(k, tolerances) != "ignore"}
                continue
            rows += compare(name, baselines[name], current, tolerances)
    if args.update:  # only once every experiment ran: a stop leaves the baseline as it was
        written: list[str] = []
        for path, kept in updated.items():
            try:
                write_text_atomic(path, json.dumps(kept, indent=1, sort_keys=True) + "\n")
            except OSError as e:
                raise PipelineError(f"cannot write {path}: {os_error_reason(e)}"
                                    + (f" (already updated: {', '.join(written)})" if written
                                       else "")) from None
            written.append(path.name)
        print(f"baseline updated for {names}")
        return 0
    table = pd.DataFrame(rows, columns=COLUMNS)  # the columns also when every metric is ignored
    failed = table[~table.ok.astype(bool)]
    shown = table if args.all_rows else failed
    if len(shown):
        print(shown.to_string(index=False, float_format=lambda v: f"{v:.6g}"))
    print(f"{len(table) - len(failed)} of {len(table)} metrics within tolerance "
          f"({len(names)} experiments); {len(failed)} regressions")
    return 1 if len(failed) else 0


if __name__ == "__main__":
    run_tool(main)
