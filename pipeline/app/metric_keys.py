"""The metrics.json keys (written by the evaluate stage), as patterns: a sweep's `objective`
must name one, and a sweep's table (pipeline.app.summary) tells metrics from settings by
them. Apart from pipeline.app.config so the table needs none of the run's imports."""

from __future__ import annotations

import re

from pipeline.core.social import PATH_METRICS

# Tests check real runs' metrics.json against them (test_transfer, test_learning), so
# the two stay in step.
_PATH = "(" + "|".join(PATH_METRICS) + ")"
METRIC_KEYS = (
    rf"(ref_)?{_PATH}", rf"transfer_.+_(policy_loss(_norm)?|{_PATH})",
    r"policy_loss(_ref)?(_initial|_rude|_iter_\d+)?", r"policy_loss_norm",
    r"weight_((std|rhat|ess)_)?\w+", r"mcmc_(acceptance_rate|ess_min|rhat_max)",
    r"frechet_to_demos(_max)?", r"time_\w+_s", r"graph_demo_node_share",
    r"heldout_(count|(frechet_m|min_distance_error_m)(_shortest)?)",
)


def is_metric_key(key: str) -> bool:
    return any(re.fullmatch(pattern, key) for pattern in METRIC_KEYS)
