"""`python -m pipeline [overrides]`: the Hydra app that runs the BIRL-G pipeline stages.

Errors are one line and exit status 2: our own (PipelineError), Hydra's (a typo, a wrong
type, a bad override: Hydra's wording, first line only) and anything unexpected.
`HYDRA_FULL_ERROR=1` shows the full traceback instead.
"""

from __future__ import annotations

import json
import logging
import os
import sys
from contextlib import nullcontext
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from pipeline.app.config import register_configs
from pipeline.app.rundir import SweepOutcome, locked, write_status_if_missing
from pipeline.errors import PipelineError, os_error_reason
from pipeline.stages import run_pipeline

register_configs()


CONF_DIR = str(Path(__file__).resolve().parent / "conf")  # the package's conf/ (see context)


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
def main(cfg: DictConfig) -> float | None:
    hydra_cfg = HydraConfig.get()
    run_dir = Path(hydra_cfg.runtime.output_dir)
    if hydra_cfg.mode != RunMode.MULTIRUN:
        try:
            run_pipeline(cfg, run_dir)
        except Exception as e:  # noqa: BLE001 - SystemExit passes through Hydra untouched
            exit_with_one_line(e)
        return None
    # In a sweep a failing job must not stop the others: its status.json (written by the
    # run dir, or here when the job failed before it had one) says failed, and `make
    # aggregate` reports it in its table and exit status.
    try:
        run_pipeline(cfg, run_dir)
    except Exception as e:  # noqa: BLE001 - any failure of one job, reported per job
        error = str(e) if isinstance(e, PipelineError) else f"{type(e).__name__}: {e}"
        logging.getLogger("pipeline").error("job failed: %s", error,
                                            exc_info=not isinstance(e, PipelineError))
        write_status_if_missing(run_dir, error)
        return float("nan")
    return objective_value(run_dir, cfg.objective)


def objective_value(run_dir: Path, key: str) -> float:
    """The job's metric for a sweeper that optimises (Optuna); NaN marks a failed trial."""
    metrics_path = run_dir / "metrics.json"
    metrics = json.loads(metrics_path.read_text()) if metrics_path.exists() else {}
    return float(metrics.get(key, float("nan")))


def one_line(e: BaseException) -> str:
    """Hydra's and OmegaConf's messages run over several lines (the key, the object type,
    a hint); the first line of the error and of its cause say what went wrong."""
    def first(x: BaseException) -> str:
        lines = [ln.strip() for ln in str(x).splitlines() if ln.strip()]
        return lines[0] if lines else type(x).__name__

    line = first(e)
    if isinstance(getattr(e, "override", None), str):  # Hydra's override parse errors
        line = f"cannot parse override '{e.override}': {line}"  # type: ignore[attr-defined]
    if e.__cause__ is not None and first(e.__cause__) not in line:
        line += f" ({first(e.__cause__)})"
    return line


def explicit_run_dir(argv: list[str]) -> Path | None:
    """The run dir given on the command line (hydra.run.dir=, also with + or ++), for a
    single run; None for sweeps and default dirs (those carry microseconds)."""
    if "-m" in argv or "--multirun" in argv:
        return None
    for arg in argv:
        key, _, value = arg.lstrip("+").partition("=")
        if key == "hydra.run.dir" and value:
            return Path(value)
    return None


def exit_with_one_line(e: Exception) -> None:
    if _show_tracebacks[0]:
        raise e
    if isinstance(e, PipelineError):
        message = str(e)
    elif type(e).__module__.startswith(("hydra", "omegaconf")):
        message = one_line(e)
    elif isinstance(e, OSError):  # e.g. Hydra creating a run dir where a file is
        message = f"cannot create or write files: {os_error_reason(e)}"
    else:  # a bug, not bad input: still one line, with the way to the traceback
        message = f"{type(e).__name__}: {one_line(e)} (HYDRA_FULL_ERROR=1 shows the traceback)"
    print(f"error: {message}", file=sys.stderr)
    sys.exit(2)


_show_tracebacks = [False]  # HYDRA_FULL_ERROR=1 as the user set it


def cli() -> None:
    user_setting = os.environ.get("HYDRA_FULL_ERROR")
    _show_tracebacks[0] = user_setting == "1"
    os.environ["HYDRA_FULL_ERROR"] = "1"  # Hydra raises instead of printing; we print one line
    SweepOutcome.failed.clear()
    run_dir = explicit_run_dir(sys.argv[1:])
    try:
        # Held from before Hydra writes its .hydra/ files until the run ends: a second run
        # into the dir is refused before it touches anything.
        with locked(run_dir) if run_dir is not None else nullcontext():
            main()
    except Exception as e:  # noqa: BLE001 - Hydra's errors, ours before the job, bugs
        exit_with_one_line(e)
    finally:
        if user_setting is None:
            os.environ.pop("HYDRA_FULL_ERROR", None)
        else:
            os.environ["HYDRA_FULL_ERROR"] = user_setting
    if SweepOutcome.failed:
        print(f"error: {len(SweepOutcome.failed)} sweep job(s) failed, first "
              f"{SweepOutcome.failed[0]} (its status.json says why; make aggregate lists all)",
              file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    cli()
