"""The Hydra callback that tells the command whether a sweep's jobs all completed (apart from
pipeline.app.rundir, which the sweep's table reads without importing Hydra)."""

from __future__ import annotations

from pathlib import Path

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from pipeline.app.rundir import begin_sweep, end_sweep, read_status, sweep_jobs


class SweepOutcome(Callback):
    """Hydra callback (conf/config.yaml, hydra.callbacks): numbers the sweep in its dir
    before any job runs (so its jobs are told apart from an earlier sweep's there), and
    after it lists this sweep's jobs whose run dir is not complete, so the command exits
    non-zero when any job failed."""

    sweep_dir: Path | None = None  # of the last sweep begun in this process
    failed: list[str] = []  # job dirs of the last sweep in this process, read by cli()

    def on_multirun_start(self, config: DictConfig, **kwargs) -> None:
        SweepOutcome.sweep_dir = Path(config.hydra.sweep.dir)
        try:
            begin_sweep(SweepOutcome.sweep_dir)
        except OSError:  # a sweep dir that cannot be made: the launcher says so in one line
            pass

    def on_multirun_end(self, config: DictConfig, **kwargs) -> None:
        end_sweep(Path(config.hydra.sweep.dir))
        SweepOutcome.failed[:] = failed_jobs(Path(config.hydra.sweep.dir))


def failed_jobs(sweep_dir: Path) -> list[str]:
    """The dirs of the last sweep's jobs in `sweep_dir` that did not complete."""
    return [str(j) for j in sweep_jobs(sweep_dir)[0] if not read_status(j).complete]
