"""Hydra callbacks the tests add to a real run (`+hydra.callbacks.NAME._target_=...`)."""

from __future__ import annotations

import os
from typing import Any

from hydra.experimental.callback import Callback


class SignalAtJobStart(Callback):
    """Sends the job's own process `signum` when Hydra starts the job: after it has written
    the job's .hydra/ files, before the task function (the pipeline) begins."""

    def __init__(self, signum: int) -> None:
        self.signum = signum

    def on_job_start(self, config: Any, **kwargs: Any) -> None:
        os.kill(os.getpid(), self.signum)


class SignalAtRunStart(SignalAtJobStart):
    """Sends `signum` when Hydra starts a single run, before it writes anything to its dir."""

    def on_run_start(self, config: Any, **kwargs: Any) -> None:
        os.kill(os.getpid(), self.signum)

    def on_job_start(self, config: Any, **kwargs: Any) -> None:
        pass
