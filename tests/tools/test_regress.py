"""The metric regression check of pipeline/tools/regress.py on small hand-made baselines:
which differences are regressions (|current - baseline| <= abs + rel * |baseline|, the
first matching pattern's tolerance), a lost or a new metric, what the command prints and
exits with, and a damaged baseline as one line. The runs are reused from --work (as
`--reuse` does), so no experiment runs; tests/cli/test_sweeps.py runs a real one (slow)."""

import json
from pathlib import Path

import pytest

from pipeline.errors import PipelineError
from pipeline.tools.regress import compare, load_tolerances, main

TOLERANCES = """\
default: {abs: 1.0e-6}
patterns:
  "time_*": ignore
  "policy_loss_norm": {abs: 0.5}   # before policy_loss*: the first match wins
  "policy_loss*": {abs: 0.25, rel: 0.125}
  "weight_*": {rel: 0.5}
"""


def tolerances(tmp_path: Path, text: str = TOLERANCES) -> list:
    (tmp_path / "tolerances.yaml").write_text(text)
    return load_tolerances(tmp_path)


def ok(rows: list[dict]) -> dict[str, bool]:
    return {row["metric"]: row["ok"] for row in rows}


def test_a_difference_is_a_regression_only_beyond_abs_plus_rel_of_the_baseline(tmp_path):
    """policy_loss: 0.25 + 0.125 * |-2.0| = 0.5 either way (up or down, of a negative
    baseline; numbers exact in binary); exactly at the tolerance still passes; the default
    holds for other keys."""
    tol = tolerances(tmp_path)
    baseline = {"policy_loss": -2.0, "policy_loss_ref": -2.0, "policy_loss_iter_01": -2.0,
                "policy_loss_iter_02": -2.0, "success": 1.0, "path_length": 9.5}
    current = {"policy_loss": -1.5, "policy_loss_ref": -2.5, "policy_loss_iter_01": -1.49,
               "policy_loss_iter_02": -2.51, "success": 1.0, "path_length": 9.5 + 2e-6}
    rows = compare("exp", baseline, current, tol)
    assert ok(rows) == {"policy_loss": True, "policy_loss_ref": True,
                        "policy_loss_iter_01": False, "policy_loss_iter_02": False,
                        "success": True, "path_length": False}
    row = {r["metric"]: r for r in rows}["policy_loss_iter_02"]
    assert row["experiment"] == "exp" and row["baseline"] == -2.0
    assert row["diff"] == pytest.approx(-0.51) and row["tolerance"] == 0.5


def test_the_first_matching_pattern_decides_and_ignored_metrics_are_no_rows(tmp_path):
    """policy_loss_norm matches two patterns: the first (abs 0.5) holds, not policy_loss*'s
    (0.25 + 12.5 %); time_* is wall-clock and never compared, even when one run lacks it."""
    tol = tolerances(tmp_path)
    rows = compare("exp", {"policy_loss_norm": 0.1, "time_total_s": 1.0, "weight_a": 2.0},
                   {"policy_loss_norm": 0.5, "time_birl_s": 9.0, "weight_a": 2.9}, tol)
    assert ok(rows) == {"policy_loss_norm": True, "weight_a": True}
    rows = compare("exp", {"weight_a": 2.0}, {"weight_a": 3.1}, tol)  # rel 0.5 of 2.0 = 1.0
    assert ok(rows) == {"weight_a": False}


def test_a_lost_metric_is_a_regression_and_a_new_one_is_not(tmp_path):
    tol = tolerances(tmp_path)
    rows = compare("exp", {"success": 1.0, "lost": 0.5}, {"success": 1.0, "new": 0.5}, tol)
    assert ok(rows) == {"lost": False, "new": True, "success": True}
    lost = {r["metric"]: r for r in rows}["lost"]
    assert (lost["baseline"], lost["current"], lost["diff"]) == (0.5, None, None)


# ---------------------------------------------------------------------------------------------
# The command, on a baseline of two experiments whose runs are reused from --work


def make_baseline(tmp_path: Path, metrics: dict[str, dict], current: dict[str, dict],
                  tolerances_text: str = TOLERANCES) -> tuple[Path, Path]:
    """A baseline dir with the experiments `metrics` names (their metrics as the baseline)
    and a --work dir with their runs' metrics.json (`current`)."""
    baseline, work = tmp_path / "baseline", tmp_path / "work"
    baseline.mkdir()
    (baseline / "experiments.yaml").write_text(
        "".join(f"{name}: [seed={k}]\n" for k, name in enumerate(metrics)))
    (baseline / "tolerances.yaml").write_text(tolerances_text)
    for name, values in metrics.items():
        (baseline / f"{name}.json").write_text(json.dumps(values))
    for name, values in current.items():
        (work / name).mkdir(parents=True)
        (work / name / "metrics.json").write_text(json.dumps(values))
    return baseline, work


def regress(capsys, baseline: Path, work: Path, *args: str) -> tuple[int, str, str]:
    code = main(["--baseline", str(baseline), "--work", str(work), "--reuse", *args])
    out, err = capsys.readouterr()
    return code, out, err


BASE = {"a": {"policy_loss": 0.5, "success": 1.0, "time_total_s": 3.0},
        "b": {"policy_loss": 0.2, "success": 1.0}}


def test_a_regression_is_listed_and_fails_the_command(tmp_path, capsys):
    """Only the failing metrics are printed (every one with --all-rows), the last line
    counts them over all experiments, and the exit status is 1; the same runs within
    tolerance exit 0."""
    current = {"a": {"policy_loss": 0.5, "success": 1.0, "time_total_s": 99.0},
               "b": {"policy_loss": 0.2, "success": 0.0}}
    baseline, work = make_baseline(tmp_path, BASE, current)
    code, out, err = regress(capsys, baseline, work)
    assert code == 1, err
    lines = out.splitlines()
    assert lines[:2] == ["running a: seed=0", "running b: seed=1"]
    assert lines[-1] == "3 of 4 metrics within tolerance (2 experiments); 1 regressions"
    table = lines[2:-1]
    assert table[0].split() == ["experiment", "metric", "baseline", "current", "diff",
                                "tolerance", "ok"]
    assert [row.split() for row in table[1:]] == [["b", "success", "1", "0", "-1", "1e-06",
                                                   "False"]]
    code, out, _ = regress(capsys, baseline, work, "--all-rows")
    assert code == 1 and len(out.splitlines()) == 2 + 1 + 4 + 1
    code, out, _ = regress(capsys, baseline, work, "--only", "a")
    assert code == 0
    assert out.splitlines() == ["running a: seed=0",
                                "2 of 2 metrics within tolerance (1 experiments); 0 regressions"]


def test_a_run_that_lost_a_metric_fails(tmp_path, capsys):
    current = {"a": {"policy_loss": 0.5, "time_total_s": 1.0}, "b": BASE["b"]}
    baseline, work = make_baseline(tmp_path, BASE, current)
    code, out, _ = regress(capsys, baseline, work)
    assert code == 1
    assert [row.split()[:2] for row in out.splitlines()[3:-1]] == [["a", "success"]]
    assert out.splitlines()[-1].endswith("; 1 regressions")


def test_experiments_whose_metrics_are_all_ignored_compare_to_nothing(tmp_path, capsys):
    """Every metric matches an `ignore` pattern (here: only timings): no row to compare,
    which is no regression, not a KeyError traceback from the empty table."""
    only_timings = {"a": {"time_total_s": 1.0}, "b": {"time_total_s": 2.0}}
    baseline, work = make_baseline(tmp_path, only_timings, only_timings)
    code, out, err = regress(capsys, baseline, work)
    assert (code, err) == (0, "")
    assert out.splitlines()[-1] == "0 of 0 metrics within tolerance (2 experiments); " \
        "0 regressions"


def test_update_then_compare_round_trips_without_the_ignored_metrics(tmp_path, capsys):
    """--update writes each run's metrics as its baseline, less the ignored ones (timings
    would differ every run); comparing the same runs afterwards finds no regression."""
    current = {"a": {"policy_loss": 0.7, "success": 0.0, "time_total_s": 5.0},
               "b": {"policy_loss": 0.1, "new": 2.0}}
    baseline, work = make_baseline(tmp_path, BASE, current)
    code, out, _ = regress(capsys, baseline, work, "--update")
    assert code == 0 and out.splitlines()[-1] == "baseline updated for ['a', 'b']"
    assert json.loads((baseline / "a.json").read_text()) == {"policy_loss": 0.7, "success": 0.0}
    assert json.loads((baseline / "b.json").read_text()) == {"policy_loss": 0.1, "new": 2.0}
    code, out, _ = regress(capsys, baseline, work)
    assert code == 0 and out.splitlines()[-1].endswith("; 0 regressions")


@pytest.mark.parametrize("text, says", [
    ("{bad", "a.json cannot be read"),
    ("{}", "a.json holds no metrics"),
    ('{"success": "yes"}', 'a.json: success="yes" is not a number'),
    ("[1.0]", "a.json is not an object of metrics"),
    ('{"success": [1.0, 1.0]}', "a: success is a list in the baseline, not a number"),
])
def test_a_damaged_baseline_file_is_one_line(tmp_path, capsys, text, says):
    baseline, work = make_baseline(tmp_path, BASE, BASE)
    (baseline / "a.json").write_text(text)
    code, _, err = regress(capsys, baseline, work)
    assert code == 2 and err.count("\n") == 1 and err.startswith("error: "), err
    assert says in err, err


def test_a_run_with_a_list_for_a_metric_is_one_line(tmp_path, capsys):
    """A metrics.json may hold lists (aggregate reads them); one difference of two lists
    was a TypeError traceback."""
    baseline, work = make_baseline(tmp_path, BASE, {**BASE, "b": {"policy_loss": [0.2]}})
    code, _, err = regress(capsys, baseline, work)
    assert code == 2 and err == "error: b: policy_loss is a list in the current run, not a " \
        "number\n"


def test_an_experiment_without_baseline_or_unknown_is_refused(tmp_path, capsys):
    baseline, work = make_baseline(tmp_path, BASE, BASE)
    (baseline / "b.json").unlink()
    code, out, err = regress(capsys, baseline, work)
    assert code == 2 and err == f"error: no baseline {baseline / 'b.json'}; create it with " \
        "--update\n"
    assert out == ""  # said before experiment a (~20 s on real ones) runs
    code, out, err = regress(capsys, baseline, work, "--only", "a", "c")
    assert code == 2 and out == ""  # refused before anything runs
    assert err == "error: unknown reference experiment(s) ['c']; known: ['a', 'b']\n"
    (tmp_path / "file").write_text("")
    code, _, err = regress(capsys, baseline, tmp_path / "file")
    assert code == 2 and err == f"error: --work {tmp_path / 'file'} is a file, not a directory\n"


@pytest.mark.parametrize("tol", ["{abs: -0.1}", "{abs: true}", "{abs: 0.1, tol: 0.2}", "{}",
                                 "0.1", "{rel: .nan}"])
def test_a_tolerance_that_is_no_bound_is_refused(tmp_path, tol):
    """A negative, boolean, NaN or unnamed bound would pass or fail everything silently."""
    with pytest.raises(PipelineError, match=r"patterns\['x\*'\] must be 'ignore' or a mapping"):
        tolerances(tmp_path, f"default: {{abs: 0}}\npatterns:\n  'x*': {tol}\n")


@pytest.mark.parametrize("path", ["/tmp/a=b", "/tmp/it's", "/tmp/a b,c [d]", "/tmp/ü~#",
                                  "/tmp/x\\'y", "/tmp/end\\", "/tmp/\"q\""])
def test_a_run_dir_override_reads_back_as_its_path(path):
    """Hydra's override grammar refuses such paths unquoted; quoted, each reads back as it is."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    from pipeline.tools import dir_override

    parsed = OverridesParser.create().parse_overrides([dir_override("hydra.run.dir", path)])
    assert parsed[0].value() == path


def test_an_experiment_runs_in_a_work_dir_whose_path_hydra_would_refuse_unquoted(tmp_path,
                                                                                   capsys):
    """--work with `=`, a quote and a space in its path: the experiment runs there (compared
    on a metric it cannot have, so each of its own is new and one is lost)."""
    baseline, _ = make_baseline(tmp_path, {"a": {"no_such_metric": 1.0}}, {})
    work = tmp_path / "w=1 it's"
    code = main(["--baseline", str(baseline), "--work", str(work)])
    out, err = capsys.readouterr()
    assert code == 1 and "no_such_metric" in out, err
    assert json.loads((work / "a" / "metrics.json").read_text())["policy_loss"] >= 0
