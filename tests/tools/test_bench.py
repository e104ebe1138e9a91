"""The benchmark command's own input checks (the measurements run in `make bench`)."""

import pandas as pd
import pytest

from pipeline.app.context import PROJECT_ROOT
from pipeline.tools.bench import _parser, main


@pytest.mark.parametrize("suite", ["startup", "bigroom", "mapscenes"])
def test_an_old_checkout_that_is_none_is_refused_in_one_line(suite, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([suite, "--old", str(tmp_path / "no-such-checkout")])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "--old" in err[-1] and "no-such-checkout" in err[-1] and "not a checkout" in err[-1]


def test_an_old_checkout_is_taken_as_its_resolved_directory():
    args = _parser().parse_args(["mapscenes", "--old", str(PROJECT_ROOT / "pipeline" / "..")])
    assert args.old == PROJECT_ROOT.resolve()


@pytest.mark.parametrize("argv, says", [
    (["experiment", "--repeats", "0"], "argument --repeats: 0 is not >= 1"),
    (["graph-once", "-5"], "argument nodes: -5 is not >= 1"),
    (["graph", "--sizes", "100", "--seed", "-1"], "argument --seed: -1 is not >= 0"),
    (["graph-io-once", "10", "--repeats", "x"], "argument --repeats: 'x' is not an integer"),
    # each ran scene, demos and graph first, or ended in a KeyError or ValueError traceback
    (["irl", "--methods", "bogus"], "argument --methods: invalid choice: 'bogus'"),
    (["irl", "--scenes", "bogus"], "argument --scenes: invalid choice: 'bogus'"),
    (["imperfect", "--conditions", "bogus"], "argument --conditions: invalid choice"),
    (["posterior", "--likelihoods", "bogus"], "argument --likelihoods: invalid choice"),
    (["bigroom", "--sides", "nan"], "argument --sides: nan is not a finite number > 0"),
    (["bigroom", "--sides", "-5"], "argument --sides: -5.0 is not a finite number > 0"),
])
def test_bench_counts_and_seeds_are_checked_before_anything_runs(argv, says, capsys):
    """--repeats 0 wrote an empty table over the committed experiment.csv; -5 nodes and
    --repeats 0 in the measuring subprocesses were tracebacks."""
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2 and says in capsys.readouterr().err


def test_graph_growth_times_its_gaussian_process_apart():
    """graph_scaling's gp_s: the share of growth spent in scikit-learn's GP, one call per
    expansion that kept a candidate; the GP is restored afterwards."""
    import pipeline.core.adaptive_graph as adaptive_graph
    from pipeline.tools.bench import _graph_once

    estimate = adaptive_graph.gp_value_estimate
    row = _graph_once(300, 0)
    assert adaptive_graph.gp_value_estimate is estimate
    assert row["nodes"] == 300 and 0 < row["gp_calls"] <= row["iterations"]
    assert 0 < row["gp_s"] < row["seconds"]


def test_a_run_stopped_inside_a_tool_is_one_line_and_the_shells_exit_status(capsys):
    """The benchmarks and the docs tool run the pipeline in-process: its Ctrl-C arrives as
    the pipeline's Interrupted, which a tool says as a stopped run does."""
    import signal

    from pipeline.app.rundir import Interrupted
    from pipeline.tools import run_tool

    def stopped() -> None:
        raise Interrupted(signal.SIGINT, "graph")
    with pytest.raises(SystemExit) as stop:
        run_tool(stopped)
    assert stop.value.code == 130
    assert capsys.readouterr().err == "interrupted by the user at stage graph\n"
    signal.signal(signal.SIGINT, signal.default_int_handler)  # run_tool ignores it after


@pytest.mark.parametrize("argv, says", [
    (["--table", "../elsewhere/x"], "--table '../elsewhere/x' must be a plain name"),
    (["--seeds", "-1"], "argument --seeds: -1 is not >= 0"),
])
def test_bench_learning_refuses_what_would_fail_after_its_runs(argv, says, capsys):
    """A --table path with a missing directory failed after the whole benchmark (its
    results lost); a negative seed was the pipeline's traceback at the first case."""
    from pipeline.tools import bench_learning
    with pytest.raises(SystemExit) as exit_:
        bench_learning.main(argv)
    assert exit_.value.code == 2 and says in capsys.readouterr().err


def test_an_out_dir_that_cannot_be_written_is_refused_before_any_run(tmp_path, capsys):
    import argparse

    from pipeline.tools import output_directory
    (tmp_path / "file").write_text("")
    with pytest.raises(SystemExit):
        output_directory(argparse.ArgumentParser(), tmp_path / "file" / "out")
    assert "cannot be written" in capsys.readouterr().err


def test_a_quick_scaling_run_leaves_the_committed_tables_alone(tmp_path, monkeypatch):
    """`bench_scaling --quick` (the 10 m room only) wrote its partial grid over the committed
    scaling tables; it now writes them to a scratch dir unless --out names a place."""
    from pipeline.tools import bench_scaling
    committed = {p.name: p.read_bytes() for p in bench_scaling.RESULTS.glob("scaling*")}
    monkeypatch.setattr(bench_scaling, "QUICK_OUT", tmp_path / "quick")
    bench_scaling.main(["--quick", "--methods", "map", "--max-nodes", "460"])
    table = pd.read_csv(tmp_path / "quick" / "scaling.csv")
    assert table[["room_m", "graph_nodes", "method"]].values.tolist() == [[10, 460, "map"]]
    assert (tmp_path / "quick" / "scaling_growth.csv").exists()
    assert {p.name: p.read_bytes() for p in bench_scaling.RESULTS.glob("scaling*")} == committed
