"""Progress of long work (reading a tracker's file of millions of rows, growing a large
graph): an info line every PROGRESS_SECONDS at most."""

from __future__ import annotations

import logging
import time

log = logging.getLogger(__name__)


# s: long work says how far it is about this often, never more often
PROGRESS_SECONDS = 10.0


class Progress:
    """Info lines on long work: called with how much is done, it says so at most every
    PROGRESS_SECONDS (`what` names the work and what `total` counts), and never on work
    done sooner."""

    def __init__(self, what: str, total: int, logger: logging.Logger = log) -> None:
        self.what, self.total, self.log = what, total, logger
        self.started = self.said = time.perf_counter()

    def __call__(self, done: int) -> None:
        now = time.perf_counter()
        if now - self.said >= PROGRESS_SECONDS:
            self.said = now
            self.log.info("  %s: %d of %d, %.0f s", self.what, done, self.total,
                          now - self.started)
