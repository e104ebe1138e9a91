"""`expert=planner` end to end: demonstrations from the people-aware planner (no true
weights) are learned from and the learned paths are compared with them."""

import numpy as np
import pytest

from pipeline.app.config import load_settings
from pipeline.artefacts import read_artefact
from pipeline.errors import PipelineError
from tests.conftest import METROPOLIS, compose_config, run_in_process
from tests.pipeline.conftest import FAST


def test_planner_expert_runs_without_true_weights(tmp_path, metropolis):
    metrics, stdout = run_in_process(tmp_path, "expert=planner", "expert.n_subjects=2", *FAST)
    demos = read_artefact(tmp_path / "demos.mcap",
                          required_topics=["/demos", "/demos/expert", "/demos/roadmap"])
    expert = demos.one("/demos/expert")
    assert expert["kind"] == "planner"
    assert expert["true_weights"] is None and expert["reward"] is None
    records = demos.all("/demos")
    n = len(metropolis.starts)
    assert [d["subject"] for d in records] == ["s0"] * n + ["s1"] * n
    assert [d["start_index"] for d in records] == list(range(n)) * 2
    for d in records:
        points = np.asarray(d["points"])
        assert np.array_equal(points[0], metropolis.starts[d["start_index"]])
        assert np.array_equal(points[-1], metropolis.goal)
        assert d["reached"] and d["value_true"] is None
    assert demos.one("/demos/roadmap")["true_values"] is None
    # no true reward: no policy loss; the learned paths are compared with the demonstrations
    assert not any(k.startswith("policy_loss") for k in metrics)
    assert metrics["frechet_to_demos"] > 0 and metrics["success"] == 1.0
    assert metrics["frechet_to_demos_max"] >= metrics["frechet_to_demos"]
    assert "vs demos" in stdout


def test_planner_settings_are_checked_with_their_key():
    settings = load_settings(compose_config("expert=planner", f"scene.path={METROPOLIS}"))
    assert settings.expert.kind == "planner" and settings.expert.n_subjects == 1
    with pytest.raises(PipelineError, match=r"^config error: expert.sigma_front=-1"):
        load_settings(compose_config("expert=planner", "expert.sigma_front=-1"))
