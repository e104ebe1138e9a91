"""Sweeps with the joblib launcher, aggregation (also of partly failed sweeps), and the
metric regression check against results/baseline/."""

import json
import shutil
import subprocess
import sys

import pandas as pd
import pytest
import yaml

from pipeline.app import rundir
from tests.conftest import ROOT, run_app


def aggregate(sweep_dir):
    return subprocess.run([sys.executable, "-m", "pipeline.tools.aggregate", str(sweep_dir)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)


@pytest.mark.slow  # four jobs; test_failing_job_does_not_stop_the_sweep is the default multirun
def test_two_by_two_multirun_is_aggregated(tmp_path):
    result = run_app("-m", "experiment=quick", f"hydra.sweep.dir={tmp_path}")
    assert result.returncode == 0, result.stderr[-2000:]
    agg = aggregate(tmp_path)
    assert agg.returncode == 0, agg.stderr
    # the console table shows which job is which: the swept settings beside the metrics
    assert agg.stdout.splitlines()[0].split()[:4] == ["job", "status", "seed", "reward"]
    table = pd.read_csv(tmp_path / "summary.csv")
    assert len(table) == 4 and (table.status == "ok").all()
    assert sorted(zip(table.seed, table.reward, strict=True)) == [(0, "polite"), (0, "rude"),
                                                      (1, "polite"), (1, "rude")]
    assert {f"policy_loss_iter_{k:02d}" for k in range(6)} <= set(table.columns)
    for figure in ("policy_loss", "scene"):
        assert (tmp_path / f"{figure}.png").stat().st_size > 10_000
        assert (tmp_path / f"{figure}.pdf").read_bytes().startswith(b"%PDF")
    # Stable column order: the job, its outcome, the seed, the swept keys, then the metrics.
    columns = list(table.columns)
    assert columns[:4] == ["job", "status", "error", "seed"]
    assert columns.index("reward") < columns.index("policy_loss_norm") == \
        columns.index("policy_loss") - 1
    assert table.columns[-1].startswith("time_")
    markdown = (tmp_path / "table.md").read_text().splitlines()
    assert "reward" in markdown[0] and "normalised policy loss" in markdown[0]
    assert len(markdown) == 4 and all(" ± " in line for line in markdown[2:])  # polite, rude
    assert "\\toprule" in (tmp_path / "table.tex").read_text()
    # Polite experts learn to avoid links, rude ones cross them.
    by_reward = table.groupby("reward").relation_crossings.max()
    assert by_reward["polite"] == 0 and by_reward["rude"] > 0


def test_failing_job_does_not_stop_the_sweep(tmp_path):
    # Two jobs; the second has an invalid body radius and fails in validation.
    result = run_app("-m", "experiment=quick", "seed=0", "reward=polite",
                     "scene.body_radius=0.25,-1", f"hydra.sweep.dir={tmp_path}")
    # The other job ran to the end; the sweep's exit status and last line report the failure.
    assert result.returncode == 1, result.stderr[-2000:]
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("error: 1 sweep job(s) failed")
    assert "scene.body_radius=-1" in last  # the failed job's error names the bad value
    statuses = {p.parent.name: json.loads(p.read_text())["state"]
                for p in tmp_path.glob("*/status.json")}
    assert statuses == {"0": "complete", "1": "failed"}
    agg = aggregate(tmp_path)
    assert agg.returncode == 1  # something failed, and the exit status says so
    assert "scene.body_radius" in agg.stdout.splitlines()[0]  # which job is which
    assert "FAILED 1: config error: scene.body_radius=-1" in agg.stderr
    table = pd.read_csv(tmp_path / "summary.csv")
    assert list(table.status) == ["ok", "failed"]
    assert table.policy_loss.notna().tolist() == [True, False]
    assert (tmp_path / "policy_loss.png").exists()
    # The same sweep again, with a demonstration file that is not there: every job fails
    # before its stages, and job 0's dir no longer says complete beside its old artefacts
    # (Hydra has replaced its config), so aggregation does not report the old metrics as ok.
    again = run_app("-m", "experiment=quick", "seed=0", "reward=polite",
                    "scene.body_radius=0.25,-1", "expert=file", "expert.path=/nowhere.json",
                    f"hydra.sweep.dir={tmp_path}")
    assert again.returncode == 1
    assert {p.parent.name: json.loads(p.read_text())["state"]
            for p in tmp_path.glob("*/status.json")} == {"0": "failed", "1": "failed"}
    agg = aggregate(tmp_path)
    assert agg.stdout.strip().splitlines()[-1] == f"0 of 2 jobs ok; wrote {tmp_path}/summary.csv"
    # nothing ran, so nothing is drawn: the earlier table and figures are gone, not stale
    assert not [p for p in tmp_path.iterdir() if p.suffix in (".png", ".pdf", ".md", ".tex")]
    agg = aggregate(tmp_path / "0")  # one job's dir is no sweep
    assert agg.returncode == 2 and "is a run dir (it has .hydra/overrides.yaml)" in agg.stderr


def test_a_sweep_again_into_its_dir_counts_only_its_own_jobs(tmp_path):
    """A re-run with fewer jobs: the dirs the earlier sweep left (here its failed job 2) are
    neither in its exit status nor in the table; a job that fails its config check says its
    own error, not the one the dir held; a job dir another job would share is refused."""
    first = run_app("-m", "experiment=quick", "seed=0", "reward=polite",
                    "birl.beta=20,30,-1", f"hydra.sweep.dir={tmp_path}")
    assert first.returncode == 1 and "birl.beta=-1" in first.stderr, first.stderr[-2000:]
    again = run_app("-m", "experiment=quick", "seed=0", "reward=polite", "birl.beta=20,-2",
                    f"hydra.sweep.dir={tmp_path}")
    assert again.returncode == 1
    assert lines_of(again.stderr)[-1].startswith(f"error: 1 sweep job(s) failed, first "
                                                 f"{tmp_path / '1'}: config error: birl.beta=-2")
    agg = aggregate(tmp_path)
    assert agg.returncode == 1
    assert agg.stdout.strip().splitlines()[-1].startswith("1 of 2 jobs ok")
    assert "note: left out 1 job dir(s) an earlier sweep into this dir left there (2)" \
        in agg.stderr
    assert "FAILED 1: config error: birl.beta=-2" in agg.stderr
    assert list(pd.read_csv(tmp_path / "summary.csv").job) == [0, 1]
    fine = run_app("-m", "experiment=quick", "seed=0", "reward=polite", "birl.beta=20",
                   f"hydra.sweep.dir={tmp_path}")
    assert fine.returncode == 0, fine.stderr[-2000:]
    assert aggregate(tmp_path).returncode == 0
    shared = run_app("-m", "experiment=quick", "seed=0,1", "reward=polite",
                     "hydra.sweep.subdir=same", f"hydra.sweep.dir={tmp_path / 'shared'}")
    assert shared.returncode == 2
    assert "jobs #0 and #1 of the sweep would share the run dir" in shared.stderr
    assert not (tmp_path / "shared" / "same").exists()
    for subdir in ("../outside_${hydra.job.num}", f"{tmp_path}/abs_${{hydra.job.num}}", "."):
        scattered = run_app("-m", "experiment=quick", "seed=0,1", "reward=polite",
                            f"hydra.sweep.subdir={subdir}", f"hydra.sweep.dir={tmp_path / 'sc'}")
        assert scattered.returncode == 2, scattered.stderr[-2000:]
        assert "is not inside the sweep dir" in scattered.stderr
    assert not list(tmp_path.glob("outside_*")) and not list(tmp_path.glob("abs_*"))


def test_aggregate_of_a_sweep_that_did_not_finish_says_so(tmp_path):
    """A stopped sweep's table lacks the jobs it never started: the exit status says so.
    Figures of an earlier aggregation go with it, also under --no-figures; a job that ran
    but lost its scene leaves the scene figure to the next job."""
    assert run_app("-m", "experiment=quick", "seed=0", f"hydra.sweep.dir={tmp_path}",
                   ).returncode == 0
    assert aggregate(tmp_path).returncode == 0 and (tmp_path / "scene.png").exists()
    (tmp_path / "0" / "scene.mcap").unlink()
    agg = aggregate(tmp_path)
    assert agg.returncode == 0, agg.stderr
    assert (tmp_path / "scene.png").exists()  # drawn from job 1
    # a damaged scene artefact is no figure and a note, not a failed aggregation (it ended
    # it, before any table line)
    scene_1 = (tmp_path / "1" / "scene.mcap").read_bytes()
    (tmp_path / "1" / "scene.mcap").write_bytes(scene_1[:len(scene_1) // 2])
    agg = aggregate(tmp_path)
    assert agg.returncode == 0, agg.stderr
    assert "note: no scene figure from job 1: artefact " in agg.stderr
    assert not (tmp_path / "scene.png").exists() and (tmp_path / "summary.csv").exists()
    (tmp_path / "1" / "scene.mcap").write_bytes(scene_1)
    no_figures = subprocess.run([sys.executable, "-m", "pipeline.tools.aggregate",
                                 str(tmp_path), "--no-figures"], cwd=ROOT,
                                capture_output=True, text=True, timeout=300)
    assert no_figures.returncode == 0
    assert not [p for p in tmp_path.iterdir() if p.suffix in (".png", ".pdf")]
    record = json.loads((tmp_path / "sweep.json").read_text())
    assert record == {"sweep": 1, "finished": True, "jobs": ["0", "1"]}
    (tmp_path / "sweep.json").write_text(json.dumps({"sweep": 1, "finished": False}))
    agg = aggregate(tmp_path)
    assert agg.returncode == 1
    assert lines_of(agg.stderr)[-1] == ("error: the sweep did not finish (it was stopped): "
                                        "jobs it had not started are in no row")
    with rundir.locked(tmp_path):  # as a running sweep holds its dir
        agg = aggregate(tmp_path)
        assert lines_of(agg.stderr)[-1] == ("error: the sweep did not finish (it still runs): "
                                            "jobs it had not started are in no row")
        # what the dir says of an earlier sweep (finished) is not this one's: it still runs
        (tmp_path / "sweep.json").write_text(json.dumps(record))
        agg = aggregate(tmp_path)
        assert agg.returncode == 1 and lines_of(agg.stderr)[-1] == (
            "error: the sweep did not finish (it still runs): jobs it had not started are in "
            "no row")
        second = run_app("-m", "experiment=quick", "seed=0", f"hydra.sweep.dir={tmp_path}")
        assert second.returncode == 2
        assert lines_of(second.stderr) == [f"error: sweep dir {tmp_path} is in use by another "
                                           "sweep; wait for it to finish, or choose another "
                                           "hydra.sweep.dir"]
    assert json.loads((tmp_path / "sweep.json").read_text())["sweep"] == 1


@pytest.mark.parametrize("subdir, says", [
    ("same", "is one run dir that every job of the sweep would share"),
    ("../outside_${hydra.job.num}", "outside the sweep dir"),
    (".", "outside the sweep dir"),
])
def test_plain_multirun_refuses_shared_or_scattered_job_dirs(tmp_path, subdir, says):
    """Hydra's basic launcher (`birlg -m` without a preset) ran both jobs into one dir, the
    second replacing the first, or outside the sweep dir, exit 0: now refused before any
    job, as the pool launcher refuses them."""
    sweep = tmp_path / "sweep"
    proc = run_app("-m", "seed=0,1", "stages=[scene]", f"hydra.sweep.subdir={subdir}",
                   f"hydra.sweep.dir={sweep}")
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert says in lines_of(proc.stderr)[-1] and "hydra.sweep.subdir" in proc.stderr
    assert not list(tmp_path.glob("outside_*")) and not (sweep / "same").exists()
    assert not (sweep / ".hydra").exists()


def test_a_sweep_of_early_stages_does_not_warn_of_its_objective(tmp_path):
    """Jobs without the evaluate stage write no metrics: each logged 'objective
    policy_loss_norm: the run wrote no such metric ... a failed trial' for a sweep that
    optimises nothing."""
    proc = run_app("-m", "seed=0,1", "stages=[scene]", f"hydra.sweep.dir={tmp_path}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = proc.stdout + proc.stderr
    assert "objective" not in out and "WARNING" not in out
    assert (tmp_path / "1" / "scene.mcap").is_file()


def lines_of(text):
    return [ln for ln in text.splitlines() if ln.strip()]


def _job(sweep, name, overrides, metrics):
    job = sweep / name
    (job / ".hydra").mkdir(parents=True)
    (job / ".hydra" / "overrides.yaml").write_text(overrides)
    (job / "status.json").write_text('{"state": "complete"}')
    (job / "metrics.json").write_text(metrics)


def test_a_damaged_job_is_one_failed_row(tmp_path):
    _job(tmp_path, "0", "- seed=0\n", '{"policy_loss": 0.5, "policy_loss_norm": NaN}')
    _job(tmp_path, "1", "- seed=1\n", "{bad")
    _job(tmp_path, "2", "- seed=2\n", '{"policy_loss": "abc"}')
    _job(tmp_path, "3", "- seed=3\n", "[1, 2]")
    _job(tmp_path, "extra", "[unclosed\n", '{"policy_loss": 0.1}')  # not numbered, and damaged
    # cut short: its setting would read as seed=4 alone, another setting
    _job(tmp_path, "4", "- seed=4\n- rew\n", '{"policy_loss": 0.1}')
    agg = subprocess.run([sys.executable, "-m", "pipeline.tools.aggregate", str(tmp_path),
                          "--no-figures"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert agg.returncode == 1 and "Traceback" not in agg.stderr
    assert agg.stdout.strip().splitlines()[-1].startswith("1 of 6 jobs ok")
    assert 'FAILED 4: overrides.yaml: "rew" is not an override (key=value)' in agg.stderr
    assert "FAILED 1: metrics.json cannot be read" in agg.stderr
    assert 'FAILED 2: metrics.json: policy_loss="abc" is not a number' in agg.stderr
    assert "FAILED 3: metrics.json is not an object of metrics" in agg.stderr
    assert "FAILED extra: overrides.yaml cannot be read" in agg.stderr
    assert list(pd.read_csv(tmp_path / "summary.csv").job) == ["0", "1", "2", "3", "4", "extra"]
    (tmp_path / "table.md").unlink()
    (tmp_path / "table.md").mkdir()  # where a table goes: one line, and a whole summary.csv
    agg = aggregate(tmp_path)
    assert agg.returncode == 2 and agg.stderr.startswith("error: cannot write the tables into")
    assert len(pd.read_csv(tmp_path / "summary.csv")) == 6


def test_aggregate_rejects_a_dir_without_jobs(tmp_path):
    agg = aggregate(tmp_path)
    assert agg.returncode == 2 and "holds no Hydra jobs" in agg.stderr


@pytest.fixture(scope="module")
def regress_work(tmp_path_factory):
    return tmp_path_factory.mktemp("regress")


def regress(*args):
    return subprocess.run([sys.executable, "-m", "pipeline.tools.regress", *map(str, args)],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)


@pytest.mark.slow  # `make regress` runs the full check
def test_regression_subset_passes(regress_work):
    result = regress("--only", "metropolis_polite_s0", "--work", regress_work)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 regressions" in result.stdout


@pytest.mark.slow
def test_metric_beyond_tolerance_fails(tmp_path, regress_work):
    baseline = tmp_path / "baseline"
    shutil.copytree(ROOT / "results" / "baseline", baseline)
    path = baseline / "metropolis_polite_s0.json"
    metrics = json.loads(path.read_text())
    metrics["policy_loss_ref"] += 0.2
    path.write_text(json.dumps(metrics))
    result = regress("--only", "metropolis_polite_s0", "--baseline", baseline, "--work",
                     regress_work, "--reuse")
    assert result.returncode == 1
    assert "policy_loss_ref" in result.stdout and "1 regressions" in result.stdout
    # Within tolerance is not a regression.
    metrics["policy_loss_ref"] -= 0.2 - 0.001
    path.write_text(json.dumps(metrics))
    assert regress("--only", "metropolis_polite_s0", "--baseline", baseline, "--work",
                   regress_work, "--reuse").returncode == 0


def test_a_damaged_baseline_is_one_line(tmp_path):
    """Each of these was a traceback (yaml, KeyError, TypeError)."""
    baseline = tmp_path / "baseline"
    shutil.copytree(ROOT / "results" / "baseline", baseline)
    cases = [("experiments.yaml", "x: [\n", "experiments.yaml cannot be read"),
             ("experiments.yaml", "- a\n", "experiments.yaml does not hold a non-empty dict"),
             ("experiments.yaml", "a: 3\n", "a must be a list of overrides"),
             ("tolerances.yaml", "default: {abs: 0}\n", "tolerances.yaml needs 'patterns'"),
             ("tolerances.yaml", "patterns: {'weight_*': 0.05}\ndefault: {abs: 0}\n",
              "patterns['weight_*'] must be 'ignore' or a mapping"),
             ("tolerances.yaml", "patterns: {}\ndefault: {abs: '0.05'}\n",
              "default must be 'ignore' or a mapping")]
    for name, text, says in cases:
        kept = (baseline / name).read_text()
        (baseline / name).write_text(text)
        result = regress("--baseline", baseline)
        (baseline / name).write_text(kept)
        assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
        assert says in result.stderr
    result = regress("--baseline", tmp_path / "nope")
    assert result.stderr == f"error: --baseline {tmp_path / 'nope'} is not a directory\n"


def test_an_update_that_stops_leaves_the_whole_baseline_as_it_was(tmp_path):
    """--update writes only once every experiment has run: a failure half-way left the
    experiments before it rewritten and the rest not (a mixed baseline, committed data)."""
    baseline, work = tmp_path / "baseline", tmp_path / "work"
    shutil.copytree(ROOT / "results" / "baseline", baseline)
    first, second = list(yaml.safe_load((baseline / "experiments.yaml").read_text()))[:2]
    for name, text in ((first, '{"policy_loss": 0.5}'), (second, "{bad")):
        (work / name).mkdir(parents=True)
        (work / name / "metrics.json").write_text(text)  # reused: nothing runs
    before = {p.name: p.read_bytes() for p in baseline.iterdir()}
    result = regress("--baseline", baseline, "--work", work, "--reuse", "--update",
                     "--only", first, second)
    assert result.returncode == 2 and f"{second}: metrics.json cannot be read" in result.stderr
    assert {p.name: p.read_bytes() for p in baseline.iterdir()} == before
    result = regress("--baseline", baseline, "--work", work, "--reuse", "--update",
                     "--only", first)
    assert result.returncode == 0, result.stderr
    assert json.loads((baseline / f"{first}.json").read_text()) == {"policy_loss": 0.5}


def test_slurm_launcher_preset_composes():
    from hydra import compose, initialize_config_dir

    from pipeline.app.config import register_configs

    register_configs()
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="config", return_hydra_config=True,
                      overrides=["experiment=scenes", "hydra/launcher=slurm",
                                 "hydra.launcher.partition=cpu"])
    launcher = cfg.hydra.launcher
    assert launcher._target_.endswith("SlurmLauncher")
    assert launcher.partition == "cpu" and launcher.cpus_per_task == 2
    assert "scene" in cfg.hydra.sweeper.params


@pytest.mark.slow
def test_optuna_preset_tunes_against_the_metric(tmp_path):
    result = run_app("-m", "experiment=tune", "hydra.sweeper.n_trials=3",
                     "hydra.sweeper.n_jobs=1", "birl.n_iterations=3",
                     f"hydra.sweep.dir={tmp_path}")
    assert result.returncode == 0, result.stderr[-2000:]
    best = yaml.safe_load((tmp_path / "optimization_results.yaml").read_text())
    assert set(best["best_params"]) == {"reward.rho_personal", "reward.rho_relation"}
    trials = [json.loads((tmp_path / str(k) / "metrics.json").read_text())
              ["heldout_log_likelihood"] for k in range(3)]
    assert len(set(trials)) == 3  # the radii change what the learned reward predicts
    assert best["best_value"] == pytest.approx(max(trials))  # the trial metric went back


def test_a_failing_trial_is_a_failed_trial_not_a_failed_tuning(tmp_path):
    """Optuna records a failed job as a failed trial and tunes on (NaN it refused, and the
    whole sweep died); the command still exits 1 naming the failed jobs; when every trial
    fails, that is the line, not Optuna's complaint."""
    tune = ("-m", "experiment=tune", "hydra/launcher=pool", "hydra.sweeper.n_trials=4",
            "birl.n_iterations=3")
    result = run_app(*tune, "birl.beta=choice(5.0,-1.0)", f"hydra.sweep.dir={tmp_path / 'a'}")
    assert result.returncode == 1, result.stderr[-2000:]
    assert "sweep job(s) failed" in result.stderr.strip().splitlines()[-1]
    # Optuna's own messages are logged like the sweep's other lines, not on stderr
    assert "A new study created" not in result.stderr
    assert "][HYDRA] A new study created in memory with name: birlg_tune" in result.stdout
    best = yaml.safe_load((tmp_path / "a" / "optimization_results.yaml").read_text())
    assert best["best_params"]["birl.beta"] == 5.0
    result = run_app(*tune, "birl.beta=choice(-1.0,-2.0)", f"hydra.sweep.dir={tmp_path / 'b'}")
    assert result.returncode == 1
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("error: 4 sweep job(s) failed") and "config error: birl.beta=-" \
        in last and last.endswith("(the sweep then stopped: No trials are completed yet.)")
    # the table says why the sweep did not finish (it was "was stopped", as after a Ctrl-C)
    table = subprocess.run([sys.executable, "-m", "pipeline.tools.aggregate",
                            str(tmp_path / "b"), "--no-figures"], cwd=ROOT, capture_output=True,
                           text=True, timeout=120)
    assert table.returncode == 1 and table.stderr.strip().splitlines()[-1].startswith(
        "error: the sweep did not finish (it was stopped: No trials are completed yet.)"), \
        table.stderr


def test_tuning_an_objective_no_job_writes_says_so(tmp_path):
    """Every trial completes without the objective (no policy loss from demonstrations
    without true weights): Optuna's 'No trials are completed yet' was blamed on the launcher
    and sweeper settings."""
    result = run_app("-m", "experiment=tune", "objective=policy_loss_norm",
                     "hydra.sweeper.n_trials=2", "hydra.sweeper.n_jobs=1",
                     "hydra.launcher.n_jobs=1", "birl.n_iterations=2",
                     f"hydra.sweep.dir={tmp_path}")
    last = result.stderr.strip().splitlines()[-1]
    assert result.returncode == 2 and "no policy loss without true weights" in last, last
    assert "objective=heldout_log_likelihood" in last and "hydra.launcher" not in last


@pytest.mark.slow
def test_a_submitit_local_sweep_runs_as_on_a_cluster(tmp_path):
    # The same launcher plugin as Slurm, with local processes: jobs are pickled, run in
    # other processes and their results collected, as on a cluster.
    result = run_app("-m", "hydra/launcher=submitit_local", "seed=0,1", "graph=small",
                     "birl.n_iterations=3", "hydra.launcher.timeout_min=10",
                     f"hydra.sweep.dir={tmp_path}")
    assert result.returncode == 0, result.stderr[-2000:]
    agg = aggregate(tmp_path)
    assert agg.returncode == 0, agg.stderr
    table = pd.read_csv(tmp_path / "summary.csv")
    assert sorted(table.seed) == [0, 1] and (table.status == "ok").all()


def test_figures_are_the_same_bytes_when_saved_again(tmp_path):
    """No wall clock in figures: a PDF carries its creation date unless told not to."""
    import time

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pipeline.app.figure_style import save_figure

    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    save_figure(fig, tmp_path / "a.png")
    time.sleep(1.1)  # PDF dates have seconds
    save_figure(fig, tmp_path / "b.png")
    plt.close(fig)
    for suffix in (".png", ".pdf"):
        assert (tmp_path / f"a{suffix}").read_bytes() == (tmp_path / f"b{suffix}").read_bytes()


@pytest.mark.slow  # 7 s (joblib's fresh workers); the fast suite's sweeps run the pool launcher
def test_pool_launcher_gives_the_joblib_launchers_jobs(tmp_path):
    """The presets' pool launcher (long-lived forked workers) and Hydra's joblib launcher
    (fresh worker processes) make the same job dirs with the same metrics."""
    sweep = ["-m", "experiment=quick", "seed=0", "reward=polite,rude", "birl.n_iterations=3"]
    for launcher in ("pool", "joblib"):
        result = run_app(*sweep, f"hydra/launcher={launcher}", "hydra.launcher.n_jobs=2",
                         f"hydra.sweep.dir={tmp_path / launcher}")
        assert result.returncode == 0, result.stderr[-2000:]
    for job in ("0", "1"):
        pool, joblib = tmp_path / "pool" / job, tmp_path / "joblib" / job
        for name in (".hydra/config.yaml", ".hydra/overrides.yaml"):
            assert (pool / name).read_text() == (joblib / name).read_text()
        assert json.loads((pool / "status.json").read_text())["state"] == "complete"
        metrics = [{k: v for k, v in json.loads((d / "metrics.json").read_text()).items()
                    if not k.startswith("time_")} for d in (pool, joblib)]
        assert metrics[0] == metrics[1]
        assert sorted(p.name for p in pool.glob("*.mcap")) == \
            sorted(p.name for p in joblib.glob("*.mcap"))


REPEATED_SEED = ("-m", "experiment=quick", "seed=0,1,0", "reward=polite",
                 "birl.n_iterations=3")


def sweep_metrics(job):
    return {k: v for k, v in json.loads((job / "metrics.json").read_text()).items()
            if not k.startswith("time_")}


def test_a_worker_that_ran_a_job_gives_the_next_a_fresh_workers_results(tmp_path):
    """The pool's workers live on from job to job: job 2 (seed 0 again) runs in a worker
    that has run job 0 or 1, and must give job 0's metrics, which a fresh worker gave."""
    result = run_app(*REPEATED_SEED, "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={tmp_path}")
    assert result.returncode == 0, result.stderr[-2000:]
    assert "Pool of 2 worker(s) is launching 3 jobs" in result.stdout
    assert sweep_metrics(tmp_path / "2") == sweep_metrics(tmp_path / "0") != \
        sweep_metrics(tmp_path / "1")
    assert "seed=0" in (tmp_path / "2" / ".hydra" / "overrides.yaml").read_text()


@pytest.mark.slow  # 12 s: two sweeps
def test_a_pool_sweep_gives_the_jobs_of_a_sequential_one(tmp_path):
    """hydra.launcher.n_jobs=1 runs the jobs one after another in the sweep's process (no
    fork): the pool's forked workers give every job the same config, overrides and
    metrics."""
    for workers in (1, 2):
        result = run_app(*REPEATED_SEED, f"hydra.launcher.n_jobs={workers}",
                         f"hydra.sweep.dir={tmp_path / str(workers)}")
        assert result.returncode == 0, result.stderr[-2000:]
        assert f"Pool of {workers} worker(s) is launching 3 jobs" in result.stdout
    pool, one = tmp_path / "2", tmp_path / "1"
    for job in ("0", "1", "2"):
        for name in (".hydra/config.yaml", ".hydra/overrides.yaml"):
            assert (pool / job / name).read_text() == (one / job / name).read_text(), (job, name)
        assert sweep_metrics(pool / job) == sweep_metrics(one / job)
        assert json.loads((pool / job / "status.json").read_text())["state"] == "complete"
    assert sweep_metrics(one / "2") == sweep_metrics(one / "0")


@pytest.mark.parametrize("workers", [1, 2])
def test_a_batch_that_does_not_compose_runs_no_job(tmp_path, workers):
    """Every job's config is composed before any job runs (by the pool's workers, in
    parallel): one option that does not exist stops the sweep before the others run, and a
    sweep that ran no job is not numbered (no sweep.json: the dir had none)."""
    result = run_app("-m", "experiment=quick", "seed=0,1", "reward=polite,nope",
                     f"hydra.launcher.n_jobs={workers}", f"hydra.sweep.dir={tmp_path}")
    assert result.returncode == 2 and "reward/nope" in result.stderr, result.stderr[-2000:]
    assert sorted(p.name for p in tmp_path.iterdir()) == [".lock", "multirun.yaml"]


# `python -m pipeline ARGS`, saying after each fork, in the process that forked, how many
# threads it had at the fork: as Python 3.12+ counts them to warn "This process is
# multi-threaded, use of fork() may lead to deadlocks in the child" (after the fork handlers)
# (native threads too, where /proc lists them, less any still listed as it exits; elsewhere
# Python's)
THREADS_AT_FORK = """
import os, runpy, sys, threading
def alive(task):
    try:
        with open(f"/proc/self/task/{task}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] not in "ZX"
    except OSError:
        return False
def count():
    tasks = "/proc/self/task"
    if not os.path.isdir(tasks):
        return threading.active_count()
    return sum(alive(task) for task in os.listdir(tasks))
os.register_at_fork(after_in_parent=lambda: print(
    "threads at fork:", count(), file=sys.stderr, flush=True))
runpy.run_module("pipeline", run_name="__main__", alter_sys=True)
"""


def test_the_pool_forks_its_workers_from_a_process_of_one_thread(tmp_path):
    """The pool launcher forks its workers from the sweep's process: a thread running there
    at a fork (a Python thread holding a lock, an OpenMP pool) can leave a worker waiting
    for ever, and Python 3.12+ warns of any. numpy's and scipy's OpenBLAS start idle thread
    pools on import and stop them in their own fork handlers; nothing else may be left."""
    result = subprocess.run(
        [sys.executable, "-W", "always:This process:DeprecationWarning", "-c",
         THREADS_AT_FORK, "-m", "experiment=quick", "seed=0,1", "reward=polite",
         "stages=[scene]", "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={tmp_path}"],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    counts = [line for line in result.stderr.splitlines() if line.startswith("threads at")]
    assert counts == ["threads at fork: 1"] * 2, result.stderr[-2000:]  # one per worker
    assert "multi-threaded" not in result.stderr  # (Python 3.12+)
    assert sorted(p.parent.name for p in tmp_path.glob("*/scene.mcap")) == ["0", "1"]


@pytest.mark.parametrize("experiment", ["quick", "tune"])
def test_a_misspelt_objective_stops_the_sweep_before_any_job(tmp_path, experiment):
    """Each job would refuse it (and Optuna would log every trial's refusal as a failed,
    non-float return): one line instead, before the sweep dir is made."""
    sweep_dir = tmp_path / "sweep"
    result = run_app("-m", f"experiment={experiment}", "objective=policy_loss_nrom",
                     f"hydra.sweep.dir={sweep_dir}")
    assert result.returncode == 2, result.stderr[-2000:]
    assert result.stderr.strip().splitlines() == [
        "error: config error: objective=policy_loss_nrom is not allowed (allowed: a "
        "metrics.json key, e.g. policy_loss_norm)"]
    assert not sweep_dir.exists() and "Failed experiment" not in result.stdout


def test_a_held_out_objective_without_held_out_demonstrations_stops_the_sweep(tmp_path):
    """experiment=tune optimises a heldout_* metric: with evaluate.holdout=null no job
    writes it, and every trial failed before; one line instead, before any job. A sweep
    that sets evaluate.holdout per job is left to its jobs."""
    sweep_dir = tmp_path / "sweep"
    result = run_app("-m", "experiment=tune", "evaluate.holdout=null",
                     "hydra.sweeper.n_trials=2", f"hydra.sweep.dir={sweep_dir}")
    assert result.returncode == 2, result.stderr[-2000:]
    [line] = result.stderr.strip().splitlines()
    assert line.startswith("error: config error: objective=heldout_") and \
        "evaluate.holdout=0.3" in line
    assert not sweep_dir.exists()
    from omegaconf import OmegaConf

    from pipeline.app.outcome import _sweeps

    def sweep(task, params=None):
        return OmegaConf.create({"hydra": {"overrides": {"task": task},
                                           "sweeper": {"params": params or {}}}})

    assert _sweeps(sweep(["evaluate.holdout=0.2,0.3"]), "evaluate.holdout")
    assert _sweeps(sweep([], {"evaluate.holdout": "interval(0.1, 0.5)"}), "evaluate.holdout")
    assert not _sweeps(sweep(["evaluate.holdout=null", "seed=0,1"]), "evaluate.holdout")
