"""A Hydra launcher for many short jobs: a pool of long-lived worker processes, forked from
the sweep's process once it has imported everything a job needs (`hydra/launcher=pool`,
the presets' default; `hydra/launcher=joblib` is Hydra's joblib launcher as before).

Each job gets the run dir Hydra's launchers give it (SWEEP_DIR/<job number>/, with .hydra/,
its log, status.json, artefacts and metrics.json) and runs through Hydra's own `run_job`;
what it saves is the start-up of each worker (a fresh interpreter importing Hydra, numpy,
scipy and the stages: ~1 s per worker) and the second composition of each job's config:
Hydra's sweeper composes every job once to check the batch before launching it, and the
workers, forked after that, take those configs instead of composing them again (0.1-0.3 s
per job). Measured on `make sweep EXP=quick` (pipeline/tools/bench.py startup).

The worker processes are forked (POSIX), so nothing is pickled to them but the job's
number; a job's result (Hydra's JobReturn) comes back pickled. A failing job fails alone
(pipeline.__main__ writes its status.json and returns NaN); a signal (Ctrl-C, SIGTERM)
stops the sweep: running jobs record `interrupted`, the pool is terminated and the command
says so in one line.
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
        self.composed: dict[tuple[int, tuple[str, ...]], DictConfig] = {}

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction,
              config: DictConfig) -> None:
        self.config, self.task_function, self.hydra_context = config, task_function, hydra_context
        remember_composed(hydra_context, self.composed)

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
            return [_execute(idx) for idx, _ in jobs]
        for stage in STAGES:  # imported once here, shared by every forked worker
            importlib.import_module(f"pipeline.stages.{stage}")
        with ProcessPoolExecutor(n_workers, mp_context=multiprocessing.get_context("fork"),
                                 initializer=_worker_started) as pool:
            futures = [pool.submit(_execute, idx) for idx, _ in jobs]
            try:
                return [f.result() for f in futures]
            except BaseException:  # Ctrl-C: the running jobs record it; no new one starts
                pool.shutdown(wait=True, cancel_futures=True)
                raise

    def execute(self, idx: int, overrides: list[str]) -> JobReturn:
        """One job, as Hydra's launchers run it: its config (composed when the sweeper
        checked the batch, else now), hydra.job.id/num, then `run_job` in its run dir."""
        assert self.config is not None and self.hydra_context is not None
        setup_globals()
        sweep_config = self.composed.pop((id(self.config), tuple(overrides)), None)
        if sweep_config is None:
            loader = self.hydra_context.config_loader
            sweep_config = type(loader).load_sweep_config(loader, self.config, overrides)
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


def _execute(idx: int) -> JobReturn:
    launcher = _Current.launcher
    assert launcher is not None
    return launcher.execute(idx, _Current.jobs[idx])


def remember_composed(hydra_context: HydraContext,
                      composed: dict[tuple[int, tuple[str, ...]], DictConfig]) -> None:
    """Keep the job configs the sweeper composes to check a batch (Hydra's
    `validate_batch_is_legal`), so the job does not compose its config a second time."""
    loader = hydra_context.config_loader
    compose = type(loader).load_sweep_config

    def load_sweep_config(master_config: DictConfig, sweep_overrides: list[str]) -> DictConfig:
        cfg = compose(loader, master_config, sweep_overrides)
        composed[(id(master_config), tuple(sweep_overrides))] = cfg  # checked, then unused
        return cfg

    loader.load_sweep_config = load_sweep_config  # type: ignore[method-assign]
