"""The table of a sweep dir (pipeline/app/summary.py): one row per job of the last sweep,
read from job dirs written by hand as Hydra and the pipeline write them; the columns in
their documented order; a missing value an empty cell of summary.csv."""

import json
import math

import pytest

from pipeline.app import rundir
from pipeline.app.summary import (
    Unreadable,
    column_order,
    parse_overrides,
    read_metrics,
    summary_csv,
    summary_rows,
)


def _job(sweep, name, overrides, status, metrics=None):
    job = sweep / name
    (job / ".hydra").mkdir(parents=True)
    (job / ".hydra" / "overrides.yaml").write_text("".join(f"- {o}\n" for o in overrides))
    (job / "status.json").write_text(json.dumps(status))
    if metrics is not None:
        (job / "metrics.json").write_text(metrics)
    return job


def test_an_override_whose_value_holds_an_equals_sign_keeps_it(tmp_path):
    job = _job(tmp_path, "0", ["seed=0", "+expert.path=/data/a=b.csv"], {"state": "complete"})
    assert parse_overrides(job) == {"seed": "0", "+expert.path": "/data/a=b.csv"}


def test_a_boolean_metric_is_no_number(tmp_path):
    path = tmp_path / "metrics.json"
    path.write_text('{"policy_loss": 0.5, "success": true}')
    with pytest.raises(Unreadable, match="success=true is not a number"):
        read_metrics(path)
    path.write_text('{"policy_loss": 0.5, "success": null, "curve": [1, NaN]}')
    assert read_metrics(path)["success"] is None


def test_each_job_is_one_row_with_its_outcome(tmp_path):
    """Complete with metrics: ok and its metrics; failed: the stage and error its
    status.json names; complete without metrics.json: failed (evaluate was not run)."""
    _job(tmp_path, "0", ["seed=0"], {"state": "complete"}, '{"policy_loss": 0.25}')
    _job(tmp_path, "1", ["seed=1"], {"state": "failed", "stage": "birl", "error": "boom"})
    _job(tmp_path, "2", ["seed=2"], {"state": "complete"})
    columns, rows = summary_rows(tmp_path)
    assert columns == ["job", "status", "error", "seed", "policy_loss"]
    assert rows == [
        {"job": "0", "seed": "0", "status": "ok", "error": "", "policy_loss": 0.25},
        {"job": "1", "seed": "1", "status": "failed", "error": "stage birl: boom"},
        {"job": "2", "seed": "2", "status": "failed",
         "error": "no metrics.json (stage evaluate was not run)"}]


@pytest.mark.parametrize("key", ["status", "error", "job", "seed"])
def test_a_metrics_key_naming_a_column_of_the_table_fails_its_row(tmp_path, key):
    """A hand-edited or foreign metrics.json whose key is a column of the table (the job,
    its outcome, an override) overwrote that column: `"status": 1` made an ok job count
    as failed, and an override's value was lost."""
    _job(tmp_path, "0", ["seed=0"], {"state": "complete"},
         json.dumps({"policy_loss": 0.25, key: 1}))
    _, [row] = summary_rows(tmp_path)
    assert row["status"] == "failed" and row["seed"] == "0" and row["job"] == "0"
    assert f"key '{key}' is a column of the table" in row["error"]


def test_a_job_the_sweep_record_also_names_is_one_row(tmp_path):
    """end_sweep records failed jobs no status.json of the sweep names; one that has a dir
    and a row of its own is not listed twice. A recorded job whose dir is gone is a row."""
    number, _ = rundir.begin_sweep(tmp_path)
    _job(tmp_path, "0", ["seed=0"], {"state": "complete", "sweep": number}, '{"success": 1}')
    _job(tmp_path, "1", ["seed=1"], {"state": "failed", "error": "boom", "sweep": number})
    _job(tmp_path, "2", ["seed=2"], {"state": "complete", "sweep": number}, '{"success": 1}')
    rundir.end_sweep(tmp_path, {str(tmp_path / "1"): "could not start"})
    (tmp_path / "2" / ".hydra" / "overrides.yaml").unlink()
    _, rows = summary_rows(tmp_path)
    assert [(r["job"], r["status"]) for r in rows] == [("0", "ok"), ("1", "failed"),
                                                        ("2", "failed")]
    assert rows[1]["error"] == "boom"
    assert rows[2]["error"] == "its .hydra/overrides.yaml is gone (deleted after the sweep)"


def test_columns_are_in_the_documented_order():
    """The job and its outcome, the seed, the swept keys (alphabetically), the headline
    metrics, the social metrics (graph, then roadmap), the weights, everything else, the
    per-iteration curves, the timings (docs/outputs.md, "Sweeps")."""
    want = ["job", "status", "error", "seed", "birl.beta", "reward",
            "policy_loss_norm", "policy_loss", "policy_loss_ref",
            "relation_crossings", "success", "ref_relation_crossings", "ref_success",
            "weight_relation", "weight_social", "frechet_m",
            "policy_loss_iter_00", "policy_loss_ref_iter_00", "time_birl", "time_total"]
    shuffled = want[::-1][1::2] + want[::-1][::2]
    assert sorted(shuffled) == sorted(want)
    assert column_order(shuffled) == want


def test_a_missing_value_is_an_empty_cell():
    rows = [{"job": "0", "a": 1.5, "b": math.nan}, {"job": "1", "a": None}]
    assert summary_csv(["job", "a", "b"], rows) == "job,a,b\n0,1.5,\n1,,\n"
