"""Start-up and sweep benchmark (`python -m pipeline.tools.bench startup`): wall seconds of
the default run beside two floors, `python -c "import numpy, scipy.sparse"` and the libraries a
run imports (Hydra, numpy, scipy, mcap, scikit-learn's GP), a 40 m room refused for too few
graph nodes (the refusal must come before the room's work), jobs per minute of
the `quick` preset swept over 8 seeds x 2 rewards (16 jobs) with 2 workers, and seconds of
aggregating that sweep. Measurements are interleaved (floor, run, old run, ... in each
repetition) and reported as medians, so a machine's changing load hits every variant alike;
with `--old DIR` (a checkout of an earlier commit, e.g. `git worktree add /tmp/old HEAD~5`)
the same commands run from there too.

Each command runs from the checkout it measures, as a user would (`python -m pipeline`), with
the checkout's bytecode compiled first (a warm checkout: Python reads .pyc files even where
PYTHONDONTWRITEBYTECODE keeps it from writing them).
"""

from __future__ import annotations

import compileall
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

from pipeline.tools import dir_override

SWEEP = ["-m", "experiment=quick", "seed=range(8)", "reward=polite,rude"]
N_SWEEP_JOBS = 16
FLOOR = [sys.executable, "-c", "import numpy, scipy.sparse"]
# What a run cannot do without: the libraries it imports (Hydra, numpy, scipy, mcap and
# scikit-learn's GP, which DESIGN §7 names), imported as the run imports them (scikit-learn
# through pipeline.core.adaptive_graph, which keeps pandas and scipy.stats out of it).
LIBRARIES = [sys.executable, "-c",
             "import hydra.main, hydra.compose, omegaconf, numpy, scipy.sparse, scipy.spatial, "
             "scipy.optimize, mcap.reader, mcap.writer; "
             "from pipeline.core.adaptive_graph import _import_sklearn_gp; _import_sklearn_gp()"]
# The rows of startup.csv that pipeline.tools.targets reads, by their `measurement`
FLOOR_ROW = "floor (import numpy, scipy.sparse)"
LIBRARIES_ROW = "floor (the libraries a run imports)"
RUN_ROW, REFUSED_ROW = "run new", "run new, 40 m room refused for too few nodes"
POOL_SWEEP_ROW = "sweep new (pool launcher)"
AGGREGATE_ROW, TABLES_ONLY_ROW = "aggregate new", "aggregate new --no-figures"
FLOORS = {FLOOR_ROW: FLOOR, LIBRARIES_ROW: LIBRARIES}


# A 40 m room (the density of persons of big_rooms) with the default room's graph size:
# refused for too few nodes, which must come before any of the room's work.
REFUSED = ["scene=random", "scene.width=40", "scene.height=40", "scene.n_singles=48",
           "scene.n_groups=48", "graph.max_nodes=460"]
REFUSAL = "too few for scene"  # what its one line says


def timed(cmd: list[str], cwd: Path, refused: str | None = None) -> float:
    """Wall seconds of `cmd`, which must succeed, or (`refused`) exit 2 with that text in
    its last line."""
    t0 = time.perf_counter()
    done = subprocess.run(cmd, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                          text=True)
    seconds = time.perf_counter() - t0
    last = (done.stderr.strip().splitlines() or [""])[-1]
    if done.returncode != (0 if refused is None else 2) or (refused or "") not in last:
        raise RuntimeError(f"{' '.join(cmd)} ended with {done.returncode} in {cwd}: "
                           f"{done.stderr[-500:]}")
    return seconds


def variants(root: Path, old: Path | None, jobs: int) -> dict[str, tuple[Path, list]]:
    """name -> (checkout, the measurement's arguments after `python -m`)."""
    sweep = [*SWEEP, f"hydra.launcher.n_jobs={jobs}"]
    found: dict[str, tuple[Path, list]] = {
        RUN_ROW: (root, ["pipeline"]),
        REFUSED_ROW: (root, ["pipeline", *REFUSED]),
        POOL_SWEEP_ROW: (root, ["pipeline", *sweep]),
        "sweep new (joblib launcher)": (root, ["pipeline", *sweep, "hydra/launcher=joblib"]),
        AGGREGATE_ROW: (root, ["pipeline.tools.aggregate"]),
        TABLES_ONLY_ROW: (root, ["pipeline.tools.aggregate", "--no-figures"]),
    }
    if old is not None:
        found.update({"run old": (old, ["pipeline"]),
                      "sweep old (its default launcher)": (old, ["pipeline", *sweep]),
                      "aggregate old": (old, ["pipeline.tools.aggregate"]),
                      "aggregate old --no-figures": (old, ["pipeline.tools.aggregate",
                                                           "--no-figures"])})
    return found


def measure_once(name: str, checkout: Path, args: list, work: Path, rep: int) -> float:
    out = work / f"{re.sub(r'[^a-z-]+', '_', name)}-{rep}"
    if name.startswith("run"):
        return timed([sys.executable, "-m", *args, dir_override("hydra.run.dir", out)], checkout,
                     REFUSAL if name == REFUSED_ROW else None)
    if name.startswith("sweep"):
        return timed([sys.executable, "-m", *args, dir_override("hydra.sweep.dir", out)], checkout)
    sweep = work / "sweep-for-aggregation"  # one sweep (made once), aggregated each time
    if not sweep.exists():
        timed([sys.executable, "-m", "pipeline", *SWEEP, dir_override("hydra.sweep.dir", sweep)],
              checkout)
    return timed([sys.executable, "-m", *args, str(sweep)], checkout)


def startup_table(root: Path, old: Path | None, repeats: int, jobs: int) -> pd.DataFrame:
    for checkout in [root] + ([old] if old else []):
        compileall.compile_dir(checkout / "pipeline", quiet=2)
    work = Path(tempfile.mkdtemp(prefix="bench-startup-"))
    measured: dict[str, list[float]] = {name: [] for name in FLOORS}
    todo = variants(root, old, jobs)
    try:
        for rep in range(repeats):
            for name, cmd in FLOORS.items():
                measured[name].append(timed(cmd, root))
            for name, (checkout, args) in todo.items():
                seconds = measure_once(name, checkout, args, work, rep)
                measured.setdefault(name, []).append(seconds)
                print(f"  {name}: {seconds:.2f} s", flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    floor = statistics.median(measured[FLOOR_ROW])
    rows = []
    for name, times in measured.items():
        median = statistics.median(times)
        rows.append({"measurement": name, "median_s": round(median, 3),
                     "runs_s": " ".join(f"{t:.3f}" for t in times),
                     "x_floor": round(median / floor, 2),
                     "jobs_per_min": round(60 * N_SWEEP_JOBS / median, 1)
                     if name.startswith("sweep") else None,
                     "jobs": N_SWEEP_JOBS if not name.startswith(("run", "floor")) else None,
                     "workers": jobs if name.startswith("sweep") else None})
    return pd.DataFrame(rows)


if __name__ == "__main__":  # measured through the benchmarks' command, which writes its table
    print("error: run this benchmark as `python -m pipeline.tools.bench startup` (see its "
          "--help)", file=sys.stderr)
    sys.exit(2)
