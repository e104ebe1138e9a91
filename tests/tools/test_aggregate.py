"""The sweep tables of pipeline/tools/aggregate.py: mean ± sample std per setting, counts as
whole numbers, the best value of each metric in bold in the LaTeX table."""

import os

import numpy as np
import pandas as pd
import pytest

from pipeline.app.summary import Unreadable, read_metrics
from pipeline.tools.aggregate import (
    group_rows,
    latex_table,
    markdown_table,
    mean_std,
    results_table,
    setting_label,
    varies,
    write_summary_csv,
    write_tables,
)


def test_mean_std_by_hand():
    # sample std (ddof = 1): values 0.1, 0.3 -> mean 0.2, std sqrt(0.02) = 0.1414
    assert mean_std(np.array([0.1, 0.3])) == "0.2000 ± 0.1414"
    assert mean_std(np.array([9.0, 9.0, 9.0])) == "9 ± 0.0"  # counts as whole numbers
    assert mean_std(np.array([1.0, 2.0])) == "1.5 ± 0.7"
    assert mean_std(np.array([0.25])) == "0.2500"  # one seed: no spread to show


def sweep_table() -> tuple[list[str], list[dict]]:
    """Columns and rows as summary_rows gives them: jobs out of order of their settings."""
    table = pd.DataFrame({
        "job": [0, 1, 2, 3], "status": ["ok"] * 4, "error": [None] * 4, "seed": [0, 0, 1, 1],
        "reward": ["rude", "polite", "polite", "rude"],
        "policy_loss_norm": [0.2, 0.01, 0.03, 0.4], "relation_crossings": [9.0, 0.0, 0.0, 8.0],
        "success": [0.5, 1.0, 1.0, 1.0]})
    return list(table.columns), table.to_dict("records")


def test_the_results_table_groups_seeds_per_setting():
    results, _ = results_table(*sweep_table())
    table = pd.DataFrame(results)
    assert list(table["reward"]) == ["polite", "rude"]
    assert list(table["seeds"]) == [2, 2]
    assert list(table["normalised policy loss"]) == ["0.0200 ± 0.0141", "0.3000 ± 0.1414"]
    assert list(table["link crossings"]) == ["0 ± 0.0", "8.5 ± 0.7"]
    assert list(table["success rate"]) == ["1 ± 0.0", "0.7500 ± 0.3536"]


def test_a_metric_some_jobs_do_not_report_is_averaged_over_those_that_do():
    """Jobs without true weights write no policy loss: their cells said `nan ± nan`."""
    columns, rows = sweep_table()
    for row in rows:
        if row["reward"] == "rude":
            del row["policy_loss_norm"]  # e.g. expert=file: no policy loss
    rows[1]["success"] = float("nan")  # one polite job without it
    results, means = results_table(columns, rows)
    table = pd.DataFrame(results)
    assert list(table["normalised policy loss"]) == ["0.0200 ± 0.0141", ""]
    assert list(table["success rate"]) == ["1", "0.7500 ± 0.3536"]  # over the one that has it
    assert np.isnan(means[1]["normalised policy loss"]) and means[0]["success rate"] == 1.0
    assert mean_std(np.array([])) == ""


def test_a_failed_job_is_left_out_of_the_results_and_is_an_empty_cell_in_the_csv(tmp_path):
    columns, rows = sweep_table()
    rows[3] = {"job": 3, "status": "failed", "error": "stage birl: boom", "seed": 1,
               "reward": "rude"}  # no metrics
    results, _ = results_table(columns, rows)
    assert [r["seeds"] for r in results] == [2, 1] and [r["failed"] for r in results] == [0, 1]
    write_summary_csv(columns, rows, tmp_path / "summary.csv")
    table = pd.read_csv(tmp_path / "summary.csv")
    assert list(table.columns) == columns
    assert table.policy_loss_norm.isna().tolist() == [False, False, False, True]
    assert table.error.isna().tolist() == [True, True, True, False]
    assert table.policy_loss_norm[1] == 0.01  # floats written in full


def test_a_setting_whose_jobs_all_failed_is_a_row_without_values(tmp_path):
    """It was no row at all: the table hid that graph.max_nodes=20 failed. A job whose dir
    is gone (no settings known) makes no setting of its own."""
    columns, rows = sweep_table()
    columns.insert(4, "graph.max_nodes")
    rows = [dict(r, **{"graph.max_nodes": "200"}) for r in rows] + \
        [{"job": 4 + k, "status": "failed", "error": "too few", "seed": k, "reward": "rude",
          "graph.max_nodes": "20"} for k in (0, 1)] + \
        [{"job": 6, "status": "failed", "error": "its job dir is gone"}]
    results, means = results_table(columns, rows)
    table = pd.DataFrame(results)
    assert table[["graph.max_nodes", "reward", "seeds", "failed"]].values.tolist() == [
        ["20", "rude", 0, 2], ["200", "polite", 2, 0], ["200", "rude", 2, 0]]
    assert table["normalised policy loss"].tolist() == ["", "0.0200 ± 0.0141",
                                                       "0.3000 ± 0.1414"]
    write_tables(columns, rows, tmp_path)  # the best of the settings that ran is bold
    polite = next(line for line in (tmp_path / "table.tex").read_text().splitlines()
                  if line.startswith("200 & polite"))
    assert polite.count("\\textbf{") == 3 and np.isnan(means[0]["normalised policy loss"])
    # no job ran: no table
    assert results_table(columns, [dict(r, status="failed") for r in rows]) == ([], [])


def test_the_best_value_of_each_metric_is_bold_in_latex(tmp_path):
    write_tables(*sweep_table(), tmp_path)
    tex = (tmp_path / "table.tex").read_text()
    polite = next(line for line in tex.splitlines() if line.startswith("polite"))
    rude = next(line for line in tex.splitlines() if line.startswith("rude"))
    # lower loss and fewer crossings are better, a higher success rate is
    assert polite.count("\\textbf{") == 3 and "\\textbf" not in rude
    assert "\\textbf{0.0200 $\\pm$ 0.0141}" in polite
    assert "BEST" not in tex and "TSEB" not in tex
    assert "BEST" not in (tmp_path / "table.md").read_text()


def test_the_latex_table_is_what_pandas_writes():
    """latex_table (written by hand to skip pandas' Styler) against DataFrame.to_latex, with
    every character LaTeX treats specially."""
    results = pd.DataFrame({"method": ["BIRL-G (MAP)", "a_b & 50% #1 {x} $y ~z ^w \\v"],
                            "seeds": [3, 10], "β": ["0.1 ± 0.0", "2"]})
    pandas = results.to_latex(index=False, escape=True).replace("±", "$\\pm$") \
        .replace("β", "$\\beta$")
    assert latex_table(results.to_dict("records"), {}) == pandas
    bold = latex_table(results.to_dict("records"), {"seeds": {1}})
    assert bold.splitlines()[5].split(" & ")[1] == "\\textbf{10}"


def test_the_markdown_table_is_what_pandas_writes():
    results = pd.DataFrame({"method": ["BIRL-G (MAP)", "PolicyWalk"], "seeds": [3, 10],
                            "normalised policy loss": ["0.0100 ± 0.0020", "0.2"]})
    assert markdown_table(results.to_dict("records")) == results.to_markdown(index=False)


def test_held_out_metrics_join_the_results_where_the_sweep_has_them(tmp_path):
    """Demonstrations without a true reward: no policy loss, but how held-out ones are
    predicted; a higher log likelihood is the better one (bold)."""
    columns = ["job", "status", "error", "seed", "birl", "heldout_frechet_m",
               "heldout_log_likelihood"]
    rows = [{"job": str(k), "status": "ok", "error": "", "seed": str(k % 2), "birl": method,
             "heldout_frechet_m": fr, "heldout_log_likelihood": ll}
            for k, (method, fr, ll) in enumerate([("map", 0.4, 37.5), ("map", 0.6, 39.5),
                                                  ("policywalk", 0.5, 30.5),
                                                  ("policywalk", 0.7, 32.5)])]
    results, _ = results_table(columns, rows)
    assert [r["method"] for r in results] == ["BIRL-G (MAP)", "PolicyWalk"]
    assert [r["held-out log likelihood"] for r in results] == ["38.5000 ± 1.4142",
                                                              "31.5000 ± 1.4142"]
    write_tables(columns, rows, tmp_path)
    tex = (tmp_path / "table.tex").read_text().splitlines()
    birl = next(line for line in tex if line.startswith("BIRL-G"))
    assert "\\textbf{38.5000" in birl and "\\textbf{0.5000" in birl  # best of both


def test_swept_numbers_are_ordered_by_value_not_as_text():
    """Overrides are read as text: β = 12.5 came before 2.26 in the sweep's table."""
    rows = [{"job": k, "status": "ok", "error": None, "seed": 0, "birl.beta": beta,
             "policy_loss_norm": 0.1} for k, beta in enumerate(["12.5", "2.26", "84.6", "1.1"])]
    results, _ = results_table(list(rows[0]), rows)
    assert [r["β"] for r in results] == ["1.1", "2.26", "12.5", "84.6"]


def test_a_value_missing_in_every_row_does_not_vary():
    """Missing is one value whether None, absent or NaN (each NaN read from summary.csv is
    another float object, and NaN != NaN)."""
    assert not varies("x", [{"x": float("nan")}, {"x": float("nan")}, {"x": None}, {}])
    assert varies("x", [{"x": "1"}, {}])
    assert not varies("x", [{"x": "1"}, {"x": "1"}])


def test_groups_are_ordered_by_value_with_missing_last():
    rows = [{"reward": None, "job": 0}, {"reward": "rude", "job": 1},
            {"reward": "polite", "job": 2}, {"job": 3}, {"reward": "polite", "job": 4}]
    groups = group_rows(rows, ["reward"])
    assert [(key, [r["job"] for r in part]) for key, part in groups] == [
        (("polite",), [2, 4]), (("rude",), [1]), ((None,), [0, 3])]


def test_one_setting_has_no_best_value_to_mark(tmp_path):
    columns, rows = sweep_table()
    rows = [r for r in rows if r["reward"] == "polite"]
    write_tables(columns, rows, tmp_path)
    assert "\\textbf" not in (tmp_path / "table.tex").read_text()


def test_settings_tied_for_the_best_value_are_all_bold(tmp_path):
    """polite and rude both succeed every time: both success rates are the best."""
    columns, rows = sweep_table()
    rows = [dict(r, success=1.0) for r in rows]
    write_tables(columns, rows, tmp_path)
    tex = (tmp_path / "table.tex").read_text().splitlines()
    for reward in ("polite", "rude"):
        line = next(line for line in tex if line.startswith(reward))
        assert line.split(" & ")[-1] == "\\textbf{1 $\\pm$ 0.0} \\\\"


def test_a_column_of_numbers_and_text_is_left_aligned_as_pandas_aligns_it():
    results = pd.DataFrame({"β": ["0.1", "2"], "seeds": [3, 10], "demos": [5, "all"]})
    pandas = results.to_latex(index=False, escape=True).replace("β", "$\\beta$")
    assert latex_table(results.to_dict("records"), {}) == pandas
    assert pandas.splitlines()[0] == "\\begin{tabular}{lrl}"


def test_a_methods_legend_label_is_its_name_in_the_paper():
    assert setting_label("birl", "map") == "method BIRL-G (MAP)"
    assert setting_label("birl", "newmethod") == "method newmethod"
    assert setting_label("reward", "polite") == "reward polite"
    assert setting_label("graph.max_nodes", 20) == "graph.max_nodes 20"


def test_a_metrics_file_that_is_no_file_is_refused_before_it_is_opened(tmp_path):
    """A named pipe would wait for a writer for ever; /dev/zero would fill the memory."""
    os.mkfifo(tmp_path / "metrics.json")
    with pytest.raises(Unreadable, match="metrics.json is a named pipe, not a file"):
        read_metrics(tmp_path / "metrics.json")
    (tmp_path / "zero").mkdir()
    (tmp_path / "zero" / "metrics.json").symlink_to("/dev/zero")
    with pytest.raises(Unreadable, match="metrics.json is a character device, not a file"):
        read_metrics(tmp_path / "zero" / "metrics.json")
