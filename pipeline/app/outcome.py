"""The Hydra callback that tells the command whether a sweep's jobs all completed (apart from
pipeline.app.rundir, which the sweep's table reads without importing Hydra)."""

from __future__ import annotations

from pathlib import Path

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from pipeline.app.rundir import job_dirs, read_status


class SweepOutcome(Callback):
    """Hydra callback (conf/config.yaml, hydra.callbacks): after a sweep, the jobs whose run
    dir is not complete, so the command exits non-zero when any job failed."""

    failed: list[str] = []  # job dirs of the last sweep in this process, read by cli()

    def on_multirun_end(self, config: DictConfig, **kwargs) -> None:
        jobs = job_dirs(Path(config.hydra.sweep.dir))
        SweepOutcome.failed[:] = [str(j) for j in jobs if not read_status(j).complete]
