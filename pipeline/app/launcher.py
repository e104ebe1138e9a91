"""A Hydra launcher for many short jobs: a pool of long-lived worker processes, forked from
the sweep's process once it has imported everything a job needs (`hydra/launcher=pool`,
the presets' default; `hydra/launcher=joblib` is Hydra's joblib launcher as before).

Each job gets the run dir Hydra's launchers give it (SWEEP_DIR/<job number>/, with .hydra/,
its log, status.json, artefacts and metrics.json) and runs through Hydra's own `run_job`;
what it saves is the start-up of each worker (a fresh interpreter importing Hydra, numpy,
scipy and the stages: ~1 s per worker) and time composing configs: Hydra's sweeper
composes every job's config to check the batch before launching it (0.1-0.2 s per job, one
after another), and a launcher composes each again to run it. Here the workers compose each
job's config once, in parallel, all before any job runs (so a batch that does not compose
still fails before anything runs, as with Hydra's check), and the job runs on that config.
Measured on `make sweep EXP=quick` (pipeline/tools/bench.py startup).

The worker processes are forked (POSIX): a job's number goes to a worker, its composed
config comes back and goes out again pickled, and so does its result (Hydra's JobReturn).
A failing job fails alone (pipeline.__main__ writes its status.json and returns NaN); a
signal (Ctrl-C, SIGTERM) stops the sweep: running jobs record `interrupted`, the pool is
terminated and the command says so in one line.
"""

from __future__ import annotations

import importlib
import logging
import multiprocessing
import os
import signal
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from hydra.core.hydra_config import HydraConfig
from hydra.core.utils import JobReturn, configure_log, filter_overrides, run_job, setup_globals
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, open_dict

from pipeline.artefacts.topics import STAGES
from pipeline.errors import PipelineError

log = logging.getLogger(__name__)


class PoolLauncher(Launcher):
    """`n_jobs` forked workers (-1 or 0: one per CPU), each taking the next job when done."""

    def __init__(self, n_jobs: int = 2, **_: Any) -> None:
        if isinstance(n_jobs, bool) or not isinstance(n_jobs, int) or n_jobs < -1:
            raise PipelineError(f"config error: hydra.launcher.n_jobs={n_jobs!r} is not allowed "
                                "(allowed: an integer >= 1, or -1 or 0 for one per CPU)")
        self.n_jobs = n_jobs
        self.config: DictConfig | None = None
        self.task_function: TaskFunction | None = None
        self.hydra_context: HydraContext | None = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction,
              config: DictConfig) -> None:
        self.config, self.task_function, self.hydra_context = config, task_function, hydra_context
        defer_batch_check(hydra_context)

    def launch(self, job_overrides: Sequence[Sequence[str]],
               initial_job_idx: int) -> Sequence[JobReturn]:
        assert self.config is not None and self.hydra_context is not None
        setup_globals()
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        sweep_dir = Path(str(self.config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        n_workers = max(1, min(self.n_jobs if self.n_jobs > 0 else os.cpu_count() or 1,
                               len(job_overrides)))
        log.info("Pool of %d worker(s) is launching %d jobs", n_workers, len(job_overrides))
        log.info("Launching jobs, sweep output dir : %s", sweep_dir)
        jobs = [(initial_job_idx + k, list(o)) for k, o in enumerate(job_overrides)]
        for idx, overrides in jobs:
            log.info("\t#%d : %s", idx, " ".join(filter_overrides(overrides)))
        _Current.launcher, _Current.jobs = self, dict(jobs)
        if n_workers == 1:
            configs = [self.compose(overrides) for _, overrides in jobs]
            return [self.execute(idx, cfg) for (idx, _), cfg in zip(jobs, configs, strict=True)]
        for stage in STAGES:  # imported once here, shared by every forked worker
            importlib.import_module(f"pipeline.stages.{stage}")
        with ProcessPoolExecutor(n_workers, mp_context=multiprocessing.get_context("fork"),
                                 initializer=_worker_started) as pool:
            try:
                composed = list(pool.map(_compose, [idx for idx, _ in jobs]))
                for (_, overrides), cfg in zip(jobs, composed, strict=True):
                    if cfg is None:  # compose it here: its error, as Hydra's check raises it
                        self.compose(overrides)
                futures = [pool.submit(_execute, idx, cfg)
                           for (idx, _), cfg in zip(jobs, composed, strict=True)]
                return [f.result() for f in futures]
            except BaseException:  # Ctrl-C: the running jobs record it; no new one starts
                pool.shutdown(wait=True, cancel_futures=True)
                raise

    def compose(self, overrides: list[str]) -> DictConfig:
        """A job's config, as Hydra's launchers compose it."""
        assert self.config is not None and self.hydra_context is not None
        loader = self.hydra_context.config_loader
        return type(loader).load_sweep_config(loader, self.config, overrides)

    def execute(self, idx: int, sweep_config: DictConfig) -> JobReturn:
        """One job, as Hydra's launchers run it: hydra.job.id/num of its composed config,
        then `run_job` in its run dir."""
        assert self.config is not None and self.hydra_context is not None
        setup_globals()
        with open_dict(sweep_config):
            sweep_config.hydra.job.id = f"{sweep_config.hydra.job.name}_{idx}"
            sweep_config.hydra.job.num = idx
        HydraConfig.instance().set_config(sweep_config)
        assert self.task_function is not None
        return run_job(hydra_context=self.hydra_context, config=sweep_config,
                       task_function=self.task_function, job_dir_key="hydra.sweep.dir",
                       job_subdir_key="hydra.sweep.subdir")


class _Current:
    """The launching launcher and its jobs, for the forked workers (nothing is pickled)."""

    launcher: PoolLauncher | None = None
    jobs: dict[int, list[str]] = {}


def _worker_started() -> None:
    # Ctrl-C reaches the whole process group: the sweep's process stops the pool, and a
    # worker between jobs must not die with a traceback of its own. (A running job's stages
    # install their own handler and record `interrupted`.)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # (the fork copied Hydra's singletons)


def _compose(idx: int) -> DictConfig | None:
    """Job idx's config, or None if it does not compose (the parent composes it again to
    raise the error: some of Hydra's exceptions do not survive pickling)."""
    launcher = _Current.launcher
    assert launcher is not None
    try:
        return launcher.compose(_Current.jobs[idx])
    except Exception:
        return None


def _execute(idx: int, sweep_config: DictConfig) -> JobReturn:
    launcher = _Current.launcher
    assert launcher is not None
    return launcher.execute(idx, sweep_config)


def defer_batch_check(hydra_context: HydraContext) -> None:
    """Hydra's sweeper composes every job's config one after another to check a batch
    (`validate_batch_is_legal`, which uses nothing but the errors). The pool launcher
    composes them in its workers, in parallel, before any job runs: so the sweeper's
    composing is turned into a no-op on this loader (launchers compose through the
    class's method)."""
    loader = hydra_context.config_loader

    def checked_by_the_launcher(master_config: DictConfig,
                                sweep_overrides: list[str]) -> None:
        return None

    loader.load_sweep_config = checked_by_the_launcher  # type: ignore[method-assign]
