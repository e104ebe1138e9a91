"""The Python API (pipeline/api.py): a run started from Python, its artefacts read as tables."""

import pytest


def test_python_api_runs_and_reads_tables(tmp_path):
    from pipeline import api

    metrics = api.run(["graph=small", "birl.n_iterations=3", "stages=[scene,demos,graph,birl,"
                       "evaluate]"], run_dir=tmp_path)
    assert metrics["policy_loss_norm"] >= 0
    curve = api.messages(tmp_path, "evaluate", "/eval/policy_loss")
    assert len(curve) == 4 and {"iteration", "weights", "ref"} <= set(curve.columns)
    assert list(curve["iteration"]) == [0, 1, 2, 3]
    persons = api.messages(tmp_path, "scene", "/scene")["persons"].iloc[0]
    assert len(persons) == 12  # metropolis
    with pytest.raises(ValueError, match="unknown stage"):
        api.artefact(tmp_path, "nope")
    assert api.run(["stages=[scene]"], run_dir=tmp_path / "only_scene") == {}
