"""Run dirs (pipeline/app/rundir.py) under faults: SIGKILL at random moments, a second run
into a dir in use, two plain runs started together, stale temp files, status.json telling the
truth, and damaged side files.

After every fault a run dir must (a) hold only artefacts that read fully, (b) say in
status.json how far it got (`read_status` reports a dead run as `interrupted`), (c) hold
artefacts that belong together (each artefact's recorded `input_digest.<stage>` is the
content digest of the artefact of that stage beside it, and metrics.json is the one that
came with eval.mcap), and (d) be usable by the next run.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

import pipeline.stages
from pipeline import api
from pipeline.app.rundir import (
    FAILED,
    HYDRA_FILES,
    SWEEP_FILE,
    Interrupted,
    RunDir,
    abandon_sweep,
    begin_sweep,
    check_from_run,
    current_sweep,
    end_sweep,
    is_locked,
    mark_ended_before_stages,
    read_status,
    signals_deferred,
    stopped_by_signals,
    sweep_jobs,
    write_status,
)
from pipeline.artefacts import topics
from pipeline.artefacts.store import read_artefact
from pipeline.artefacts.topics import STAGES
from pipeline.errors import PipelineError
from tests.conftest import ROOT, check_run_dir, run_app, run_in_process

QUICK = ("graph=small", "birl.n_iterations=3")  # a whole run in ~1 s plus imports


# -- helpers ---------------------------------------------------------------------------------


def snapshot(d: Path) -> dict[str, tuple[int, int]]:
    """Every file and dir under d (relative name -> (size, mtime_ns)), to prove it untouched."""
    return {str(p.relative_to(d)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(d.rglob("*"))}


def pipeline_cmd(run_dir: Path, *overrides: str) -> list[str]:
    return [sys.executable, "-m", "pipeline", f"hydra.run.dir={run_dir}", *overrides]


def lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


# -- 1. SIGKILL at random moments ------------------------------------------------------------

# Three kinds of killed runs: a fresh dir; a re-run with another seed into a complete dir
# (every stage may replace its artefact); a re-run of the last three stages with a larger
# graph into a complete dir (graph, birl and eval are replaced, scene and demos kept).
KILL_MODES = {
    "fresh": QUICK,
    "reseed": (*QUICK, "seed=1"),
    "regrow": (*QUICK, "stages=[graph,birl,evaluate]", "graph.max_nodes=180"),
}
N_KILLS = 20


def timed_run(run_dir: Path, overrides: tuple[str, ...]) -> tuple[float, float, float]:
    """One unkilled run: seconds until it took the run dir (wrote status.json), until its
    status said complete, and until it exited. Polls; the times only spread the kills."""
    status = run_dir / "status.json"
    before = status.stat().st_mtime_ns if status.exists() else None
    t0 = time.monotonic()
    proc = subprocess.Popen(pipeline_cmd(run_dir, *overrides), cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    started = completed = None
    while proc.poll() is None:
        if status.exists() and status.stat().st_mtime_ns != before:
            if started is None:
                started = time.monotonic() - t0
            if completed is None and read_status(run_dir).complete:
                completed = time.monotonic() - t0
        time.sleep(0.005)
    exited = time.monotonic() - t0
    assert proc.returncode == 0, proc.stderr.read()
    proc.stderr.close()
    assert read_status(run_dir).complete and check_run_dir(run_dir) == []
    completed = exited if completed is None else completed
    return (completed if started is None else started), completed, exited


@pytest.mark.slow
def test_sigkill_at_random_moments_leaves_sound_truthful_dirs(tmp_path):
    # One unkilled run of each kind: its times spread the kills, the first seeds the re-runs.
    base = tmp_path / "base"
    times = {"fresh": timed_run(base, KILL_MODES["fresh"])}
    for mode in ("reseed", "regrow"):
        shutil.copytree(base, tmp_path / f"measure-{mode}")
        times[mode] = timed_run(tmp_path / f"measure-{mode}", KILL_MODES[mode])

    # Every 4th kill anywhere in the run (imports, Hydra, stages, shutdown): a delay from the
    # start. The others while the stages run, where damage can happen: a delay from the moment
    # the killed run took its dir (status.json written), so a slow start on a busy machine
    # does not shift them, spread over the stages' time in the unkilled run.
    rng = np.random.default_rng(0)
    landed: Counter[str] = Counter()
    per_mode: dict[str, Counter[str]] = {m: Counter() for m in KILL_MODES}
    failures: list[str] = []
    i = 0
    # At least N_KILLS runs, and on until N_KILLS of them were killed (a run on a quiet
    # machine may finish before its kill), at most twice as many.
    while (i < N_KILLS or i - landed["finished"] < N_KILLS) and i < 2 * N_KILLS:
        mode = list(KILL_MODES)[i % len(KILL_MODES)]
        took, completed, exited = times[mode]
        delay = rng.uniform(0.0, 0.95 * exited) if i % 4 == 0 \
            else rng.uniform(0.0, 0.9 * (completed - took))
        d = tmp_path / f"kill{i:02d}-{mode}"
        if mode != "fresh":
            shutil.copytree(base, d)  # copy2: mtimes kept, so an untouched status shows
        status_before = (d / "status.json").stat().st_mtime_ns if mode != "fresh" else None
        log = open(tmp_path / f"kill{i:02d}.log", "w")
        proc = subprocess.Popen(pipeline_cmd(d, *KILL_MODES[mode]), cwd=ROOT, stdout=log,
                                stderr=subprocess.STDOUT)
        if i % 4:  # wait until the run takes its dir (or ends), then the delay
            status_file = d / "status.json"
            while proc.poll() is None and not (
                    status_file.exists() and status_file.stat().st_mtime_ns != status_before):
                time.sleep(0.002)
        try:
            rc = proc.wait(timeout=delay)
            killed = False
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGKILL)
            rc = proc.wait()
            killed = True
        log.close()
        status = read_status(d)
        after = "the start" if i % 4 == 0 else "taking the dir"
        context = f"kill {i} ({mode}, {delay:.2f} s after {after}, {status.describe()})"

        # Where did it land, and does status.json say so?
        if not killed:
            where = "finished"
            if rc != 0 or not status.complete:
                failures.append(f"{context}: unkilled run ended with {rc}")
        elif status.state == "interrupted":
            recorded = json.loads((d / "status.json").read_text())
            if status.stage is None:  # took the dir, killed before its first stage began
                where = "before first stage"
                if recorded["done"]:
                    failures.append(f"{context}: interrupted at no stage after {recorded}")
            else:
                where = status.stage
                if status.stage not in recorded["stages"]:
                    failures.append(f"{context}: interrupted at a stage not of the run")
        elif status.state == "unknown":  # killed before the run took the dir
            where = "startup"
            if mode != "fresh" or list(d.glob("*.mcap")):
                failures.append(f"{context}: no status.json beside artefacts")
        elif status.state == "complete":
            unchanged = status_before == (d / "status.json").stat().st_mtime_ns
            where = "startup" if unchanged else "after complete"
            if not (d / "metrics.json").exists():
                failures.append(f"{context}: complete without metrics.json")
        else:
            where = status.state
            failures.append(f"{context}: a killed run reads as {status.state}")
        landed[where] += 1
        per_mode[mode][where] += 1

        failures += [f"{context}: {p}" for p in check_run_dir(d)] if d.exists() else []

        # The next run into the dir takes it over: stale temp files gone, status complete.
        try:
            run_in_process(d, "stages=[scene]")
        except Exception as e:  # noqa: BLE001 - reported below with the kill's context
            failures.append(f"{context}: next run failed: {type(e).__name__}: {e}")
        else:
            if list(d.glob("*.tmp")) or not read_status(d).complete:
                failures.append(f"{context}: after the next run: {read_status(d).describe()}, "
                                f"temp files {[p.name for p in d.glob('*.tmp')]}")
            failures += [f"{context}, after the next run: {p}" for p in check_run_dir(d)]
        i += 1

    print("\nunkilled runs (took the dir, complete, exited): " + ", ".join(
        f"{m} ({a:.2f} s, {b:.2f} s, {c:.2f} s)" for m, (a, b, c) in times.items()))
    print(f"{i} runs, {i - landed['finished']} killed; landed: {dict(sorted(landed.items()))}")
    for mode, counts in per_mode.items():
        print(f"  {mode}: {dict(sorted(counts.items()))}")
    print(f"  problems: {len(failures)}")
    assert not failures, "\n".join(failures)
    assert i - landed["finished"] >= N_KILLS
    assert sum(landed[s] for s in STAGES) >= 5  # the kills did reach the stages


# A kill at the worst moment: right after a stage renamed its new artefact into place, before
# anything else happened. The pipeline runs under a wrapper that SIGKILLs itself there.
_KILL_AFTER_RENAME = """
import os, runpy, signal, sys
target = sys.argv.pop(1)
_replace = os.replace
def replace(src, dst, *args, **kwargs):
    _replace(src, dst, *args, **kwargs)
    if os.path.basename(str(dst)) == target:
        os.kill(os.getpid(), signal.SIGKILL)
os.replace = replace
runpy.run_module("pipeline", run_name="__main__", alter_sys=True)
"""


@pytest.mark.slow
@pytest.mark.parametrize(("target", "overrides"), [
    # a new graph.mcap beside the old birl.mcap, eval.mcap and metrics.json
    pytest.param("graph.mcap", ("stages=[graph,birl,evaluate]", "graph.max_nodes=180")),
    # a new eval.mcap beside the old metrics.json
    pytest.param("eval.mcap", ("stages=[evaluate]",
                               "evaluate.transfer_scenes=[data/scenes/office.json]")),
])
def test_kill_right_after_an_artefact_is_replaced(tmp_path, target, overrides):
    d = tmp_path / "run"
    run_in_process(d, *QUICK)
    proc = subprocess.run([sys.executable, "-c", _KILL_AFTER_RENAME, target,
                           f"hydra.run.dir={d}", *QUICK, *overrides], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert read_status(d).state == "interrupted"
    run_in_process(d, "stages=[scene]")  # the next run says complete: the dir must be sound
    assert read_status(d).complete
    assert check_run_dir(d) == []


# -- 2. a second run into a dir in use -------------------------------------------------------


@pytest.mark.parametrize("key", [
    "hydra.run.dir",
    "++hydra.run.dir",
])
def test_cli_refuses_a_locked_run_dir_in_one_line_and_touches_nothing(tmp_path, key):
    d = tmp_path / "run"
    run_in_process(d, "stages=[scene]")
    with RunDir(d, ["scene"]):
        assert is_locked(d)
        before = snapshot(d)
        proc = run_app(f"{key}={d}", "stages=[scene]")
        after = snapshot(d)
        assert read_status(d).state == "running"  # the holder's status, not overwritten
    assert proc.returncode != 0
    assert len(lines(proc.stderr)) == 1 and "in use" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    assert after == before
    assert not (d / ".hydra").exists()  # refused before Hydra wrote its files
    assert read_status(d).complete  # the holder's exit, not the refused run's


@pytest.mark.slow
def test_cli_refuses_a_locked_relative_run_dir(tmp_path):
    # hydra.run.dir relative to the cwd, as `make experiment ARGS=hydra.run.dir=...` gives it
    d = tmp_path / "run"
    d.mkdir()
    with RunDir(d, ["scene"]):
        before = snapshot(d)
        proc = run_app("hydra.run.dir=run", "stages=[scene]", cwd=tmp_path)
        assert snapshot(d) == before
    assert proc.returncode != 0 and "in use" in proc.stderr, proc.stderr
    assert len(lines(proc.stderr)) == 1 and "Traceback" not in proc.stderr


@pytest.mark.slow
def test_two_runs_started_together_into_one_dir(tmp_path):
    # One takes the dir, the other refuses in one line (or, when the first was already done,
    # runs after it); either way the dir ends complete and its artefacts belong together.
    d = tmp_path / "run"
    procs = [subprocess.Popen(pipeline_cmd(d, *QUICK, "stages=[scene,demos]", f"seed={seed}"),
                              cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                              text=True) for seed in (0, 1)]
    results = [(p.wait(timeout=600), p.communicate()[1]) for p in procs]
    assert 0 in [rc for rc, _ in results], results
    for rc, err in results:
        assert rc == 0 or (len(lines(err)) == 1 and "in use" in err), err
        assert "Traceback" not in err
    assert read_status(d).complete
    assert not list(d.glob("*.tmp"))
    assert check_run_dir(d) == []


# The CLI takes the run dir's lock before Hydra writes .hydra/ and its log, and holds it to
# the end, so a run that comes second is refused before it touches anything (two runs
# started together). Made deterministic: the CLI pauses right after taking the lock while
# the test tries to take the dir.
_PAUSE_AFTER_LOCK = """
import runpy, sys, time
from pathlib import Path
import pipeline.app.rundir as rundir
taken, go = Path(sys.argv.pop(1)), Path(sys.argv.pop(1))
_acquire = rundir.acquire_lock
def acquire_lock(run_dir):
    fd = _acquire(run_dir)
    taken.touch()
    while not go.exists():
        time.sleep(0.01)
    return fd
rundir.acquire_lock = acquire_lock
runpy.run_module("pipeline", run_name="__main__", alter_sys=True)
"""


def test_the_cli_holds_the_dir_from_before_hydra_writes_into_it(tmp_path):
    d = tmp_path / "run"
    taken, go = tmp_path / "taken", tmp_path / "go"
    proc = subprocess.Popen([sys.executable, "-c", _PAUSE_AFTER_LOCK, str(taken), str(go),
                             f"hydra.run.dir={d}", "stages=[scene]", "seed=1"], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        while not taken.exists() and proc.poll() is None:
            time.sleep(0.01)
        assert not (d / ".hydra").exists()  # Hydra has not started yet
        with pytest.raises(PipelineError, match="in use"):  # a second run comes now
            with RunDir(d, ["scene"]):
                pass
    finally:
        go.touch()
        err = proc.communicate(timeout=600)[1]
    assert proc.returncode == 0, err
    assert read_status(d).complete
    hydra_cfg = (d / ".hydra" / "config.yaml").read_text()
    assert "seed: 1" in hydra_cfg  # the Hydra files describe the run that made the artefacts
    assert "seed: 1" in read_artefact(d / "scene.mcap").config_yaml


def test_in_process_run_into_a_locked_dir_raises(tmp_path):
    d = tmp_path / "run"
    run_in_process(d, "stages=[scene]")
    scene_before = (d / "scene.mcap").stat().st_mtime_ns
    with RunDir(d, ["scene"]):
        with pytest.raises(PipelineError, match="in use"):
            run_in_process(d, "stages=[scene]")
        assert read_status(d).state == "running"
    assert (d / "scene.mcap").stat().st_mtime_ns == scene_before
    assert read_status(d).complete


# -- 3. two plain runs started together ------------------------------------------------------


def test_two_plain_runs_started_together_get_their_own_dirs(tmp_path):
    cmd = [sys.executable, "-m", "pipeline", "stages=[scene]"]
    procs = [subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    results = [(p.wait(timeout=600), *p.communicate()) for p in procs]
    for rc, _, err in results:
        assert rc == 0, err
    dirs = sorted(p.parent for p in (tmp_path / "outputs").rglob("status.json"))
    assert len(dirs) == 2 and dirs[0] != dirs[1], dirs
    for d in dirs:
        assert read_status(d).complete
        assert (d / "scene.mcap").exists() and not list(d.glob("*.tmp"))
        assert check_run_dir(d) == []


# -- 4. stale temp files ---------------------------------------------------------------------


def test_stale_temp_files_of_a_dead_run_are_removed(tmp_path):
    d = tmp_path / "run"
    d.mkdir()
    stale = [d / "scene.mcap.123-abcd.tmp", d / "timings.json.456-ef01.tmp",
             d / "graph.mcap.tmp"]  # the fixed name older versions used
    for p in stale:
        p.write_bytes(b"\x89MCAP0\r\n half a file")
    run_in_process(d, "stages=[scene]")
    assert not [p.name for p in stale if p.exists()]
    assert not list(d.glob("*.tmp"))
    assert read_status(d).complete
    read_artefact(d / "scene.mcap")


# -- 5. status.json tells the truth ----------------------------------------------------------


def test_failed_stage_is_recorded_in_status(tmp_path):
    d = tmp_path / "run"
    far = tmp_path / "far.json"  # found by the demos stage: it begins far from every start
    far.write_text(json.dumps({"trajectories": [[[6.0, 5.0], [5.5, 8.0], [5.5, 9.0]]]}))
    with pytest.raises(PipelineError, match="far.json"):
        run_in_process(d, *QUICK, "expert=file", f"expert.path={far}")
    status = read_status(d)
    assert (status.state, status.stage) == ("failed", "demos"), status
    assert "far.json" in status.error
    assert (d / "scene.mcap").exists() and not (d / "demos.mcap").exists()
    assert check_run_dir(d) == []


def test_a_missing_input_file_is_refused_before_the_run_dir_is_touched(tmp_path):
    d = tmp_path / "run"
    missing = tmp_path / "nonexistent.json"
    with pytest.raises(PipelineError, match="nonexistent.json not found"):
        run_in_process(d, *QUICK, "expert=file", f"expert.path={missing}")
    assert not d.exists()


def _status_running(d: Path, stage: str) -> None:
    d.mkdir(parents=True, exist_ok=True)
    (d / "status.json").write_text(json.dumps({
        "state": "running", "stage": stage, "error": None, "stages": list(STAGES),
        "done": list(STAGES[:STAGES.index(stage)])}))


def test_running_status_without_a_lock_holder_reads_as_interrupted(tmp_path):
    d = tmp_path / "run"
    _status_running(d, "graph")
    status = read_status(d)
    assert (status.state, status.stage) == ("interrupted", "graph")
    (d / ".lock").touch()  # a lock file nobody holds is no lock
    assert read_status(d).state == "interrupted"
    with RunDir(d, ["scene"]):  # held: running, and the writer's stage
        assert read_status(d).state == "running"
    assert read_status(d).complete


def test_from_run_of_an_interrupted_dir_is_refused(tmp_path):
    d = tmp_path / "old"
    run_in_process(d, "stages=[scene]")
    _status_running(d, "demos")  # as a run killed in stage demos leaves it
    with pytest.raises(PipelineError, match="interrupted"):
        run_in_process(tmp_path / "new", "stages=[demos]", f"from_run={d}")
    assert not (tmp_path / "new").exists()
    proc = run_app(f"hydra.run.dir={tmp_path / 'cli'}", "stages=[demos]", f"from_run={d}")
    assert proc.returncode != 0
    assert len(lines(proc.stderr)) == 1 and "interrupted" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout


def test_from_run_of_a_dir_in_use_is_refused(tmp_path):
    d = tmp_path / "old"
    run_in_process(d, "stages=[scene]")
    with RunDir(d, ["scene"]):
        with pytest.raises(PipelineError, match="running"):
            run_in_process(tmp_path / "new", "stages=[demos]", f"from_run={d}")


def test_status_of_a_job_that_failed_before_running(tmp_path):
    mark_ended_before_stages(tmp_path, FAILED, "config error: x", sweep=3)
    status = json.loads((tmp_path / "status.json").read_text())
    assert (status["state"], status["error"], status["sweep"]) == ("failed", "config error: x", 3)


def test_a_signal_while_the_config_is_checked_marks_a_complete_run_dir_interrupted(
        tmp_path, monkeypatch):
    # as a config error there: Hydra has replaced .hydra/ already, so `complete` would lie
    run_in_process(tmp_path, *QUICK)
    checked = pipeline.stages.preflight

    def interrupted_preflight(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)  # a real Ctrl-C, as the run's handler takes it
        return checked(*args, **kwargs)

    monkeypatch.setattr(pipeline.stages, "preflight", interrupted_preflight)
    with pytest.raises(Interrupted):
        run_in_process(tmp_path, *QUICK, "seed=5")
    status = read_status(tmp_path)
    assert (status.state, status.stage, status.done) == ("interrupted", None, ())
    assert status.error == "interrupted by the user before the first stage"


def test_a_run_its_config_refuses_leaves_the_earlier_run_in_the_dir_as_it_was(tmp_path):
    """A re-run into a complete run's dir with a typo (a value, a missing file, the dir
    itself as birl.from_run) is refused before its stages: the earlier run's .hydra/ files
    are put back where Hydra had replaced them, and its status stays `complete` (it said
    `failed` with the typo's error, and the run could no longer be exported)."""
    run_app(*QUICK, f"hydra.run.dir={tmp_path}")
    files = {name: (tmp_path / name).read_bytes() for name in
             (*HYDRA_FILES, "status.json", "metrics.json", *topics.ARTEFACT_FILE.values())}
    assert read_status(tmp_path).state == "complete"
    for typo in ("birl.beta=-1", "expert=file expert.path=/no/such/demos.json",
                 f"birl=fixed birl.from_run={tmp_path}"):
        assert run_app(*typo.split(), f"hydra.run.dir={tmp_path}").returncode == 2
        assert {name: (tmp_path / name).read_bytes() for name in files} == files, typo
    exported = subprocess.run([sys.executable, "-m", "pipeline.tools.export", str(tmp_path)],
                              capture_output=True, text=True)
    assert exported.returncode == 0, exported.stderr
    # an API run writes no .hydra/ files: refused, it leaves the dir alone too
    with pytest.raises(PipelineError):
        api.run([*QUICK, "birl.beta=-1"], run_dir=tmp_path)
    assert {name: (tmp_path / name).read_bytes() for name in files} == files


# -- 6. damaged side files -------------------------------------------------------------------


@pytest.mark.parametrize("content", ["", "{not json", "[1, 2]", "null"])
def test_damaged_timings_json_does_not_break_the_next_run(tmp_path, caplog, content):
    d = tmp_path / "run"
    d.mkdir()
    (d / "timings.json").write_text(content)
    with caplog.at_level(logging.WARNING, logger="pipeline"):
        run_in_process(d, "stages=[scene]")
    assert any(r.levelno == logging.WARNING and "timings.json" in r.getMessage()
               for r in caplog.records), caplog.text
    assert read_status(d).complete
    timings = json.loads((d / "timings.json").read_text())
    assert isinstance(timings, dict) and "time_scene_s" in timings


def test_damaged_status_json_does_not_break_the_next_run(tmp_path):
    d = tmp_path / "run"
    d.mkdir()
    (d / "status.json").write_text("")
    assert read_status(d).state == "unknown"
    run_in_process(d, "stages=[scene]")
    assert read_status(d).complete


def test_no_side_file_is_left_half_written_by_a_run(tmp_path):
    d = tmp_path / "run"
    run_in_process(d, *QUICK)
    for name in ("status.json", "timings.json", "metrics.json"):
        assert isinstance(json.loads((d / name).read_text()), dict), name
    assert not list(d.glob("*.tmp"))
    assert check_run_dir(d) == []


def test_from_run_learning_and_evaluation_keep_this_runs_artefacts(tmp_path):
    # evaluate reads the scene after birl made its artefact: linking the scene must not
    # remove the birl artefact of this very run (make bench's stages=[birl,evaluate])
    run_in_process(tmp_path / "base", *QUICK, "stages=[scene,demos,graph]")
    d = tmp_path / "learn"
    run_in_process(d, *QUICK, "stages=[birl,evaluate]", f"from_run={tmp_path / 'base'}")
    assert (d / "birl.mcap").exists() and (d / "metrics.json").exists()
    assert check_run_dir(d) == []


@pytest.mark.parametrize("status, says", [
    (None, "has no status.json"),
    ("{garbage", "has an unreadable status.json"),
    ("dir", "has an unreadable status.json"),
])
def test_a_from_run_without_a_readable_status_is_one_warning(tmp_path, caplog, status, says):
    run = tmp_path / "copied"
    run.mkdir()
    if status == "dir":
        (run / "status.json").mkdir()
    elif status is not None:
        (run / "status.json").write_text(status)
    with caplog.at_level(logging.WARNING):
        check_from_run(run, str(run))
    [warning] = [r.getMessage() for r in caplog.records]
    assert f"from_run={run} {says}, so whether its run finished is not known" in warning


# -- sweeps numbered in their dir -----------------------------------------------------------


def _sweep_job(sweep_dir: Path, name: str, sweep: int | None) -> Path:
    job = sweep_dir / name
    (job / ".hydra").mkdir(parents=True)
    (job / ".hydra" / "overrides.yaml").write_text(f"- seed={name}\n")
    write_status(job, "complete", None, None, ["scene"], ["scene"], sweep)
    return job


def test_a_sweep_is_numbered_after_the_last_one_that_ran_a_job(tmp_path):
    assert begin_sweep(tmp_path) == (1, {})
    # it ran no job (a launcher's config error): the next sweep takes its number again
    assert begin_sweep(tmp_path) == (1, {"sweep": 1, "finished": False})
    _sweep_job(tmp_path, "0", 1)
    assert begin_sweep(tmp_path)[0] == 2
    _sweep_job(tmp_path, "1", 2)
    # a damaged record: the number goes on from what the jobs recorded, not from 1
    (tmp_path / SWEEP_FILE).write_text("{bad")
    assert begin_sweep(tmp_path) == (3, {})
    assert sweep_jobs(tmp_path) == ([], [tmp_path / "0", tmp_path / "1"])


def test_a_sweep_that_ran_no_job_leaves_the_record_as_it_was(tmp_path):
    number, previous = begin_sweep(tmp_path)
    job = _sweep_job(tmp_path, "0", number)
    (tmp_path / SWEEP_FILE).write_text(json.dumps({"sweep": 1, "finished": True}))
    number, previous = begin_sweep(tmp_path)
    assert number == 2 and sweep_jobs(tmp_path) == ([], [job])
    abandon_sweep(tmp_path, previous)  # stopped before any job began
    assert json.loads((tmp_path / SWEEP_FILE).read_text()) == {"sweep": 1, "finished": True}
    assert sweep_jobs(tmp_path) == ([job], [])
    number, previous = begin_sweep(tmp_path)
    other = _sweep_job(tmp_path, "1", number)
    abandon_sweep(tmp_path, previous)  # one job had begun: the record stays this sweep's
    assert current_sweep(tmp_path) == 2 and sweep_jobs(tmp_path) == ([other], [job])
    fresh = tmp_path / "fresh"
    abandon_sweep(fresh, begin_sweep(fresh)[1])  # no record before: none after
    assert not (fresh / SWEEP_FILE).exists()


def test_a_job_dir_left_damaged_by_an_earlier_sweep_is_not_this_sweeps(tmp_path):
    # its status.json unreadable before the sweep began: it is not this sweep's failed job
    # (a clean re-run exited 1 for it), until this sweep begins a job in it
    begin_sweep(tmp_path)
    kept, damaged = _sweep_job(tmp_path, "0", 1), _sweep_job(tmp_path, "1", 1)
    (damaged / "status.json").write_text("{damaged")
    number = begin_sweep(tmp_path)[0]
    assert number == 2 and sweep_jobs(tmp_path) == ([], [kept, damaged])
    end_sweep(tmp_path)  # the record keeps what it found unreadable
    assert sweep_jobs(tmp_path) == ([], [kept, damaged])
    time.sleep(0.01)
    (damaged / ".hydra" / "overrides.yaml").write_text("- seed=9\n")  # Hydra began a job
    assert sweep_jobs(tmp_path) == ([damaged], [kept])  # killed before its status.json


class _SignalledWhileFinalised:
    """Sends this process SIGINT when it is finalised and lets the handler run there."""

    def __del__(self):
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(1000):  # the handler runs at one of these steps, inside __del__
            pass


def test_a_stop_python_drops_in_a_finaliser_is_raised_at_the_end_of_the_block(capfd):
    # An exception raised inside __del__ is printed ("Exception ignored in") and dropped:
    # the signal must still stop the block, without the printout
    reached_the_end = False
    with pytest.raises(Interrupted) as stopped:
        with stopped_by_signals():
            _SignalledWhileFinalised()
            reached_the_end = True
    assert reached_the_end and stopped.value.signum == signal.SIGINT
    assert capfd.readouterr().err == ""


def test_a_stop_python_drops_in_a_finaliser_stops_the_run_at_the_next_stage(tmp_path):
    with pytest.raises(Interrupted), stopped_by_signals(), RunDir(tmp_path, ["scene", "demos"]) \
            as rundir:
        rundir.start("scene")
        _SignalledWhileFinalised()
        rundir.done("scene")  # the stage's artefact is whole; the next one must not start
        rundir.start("demos")
    status = read_status(tmp_path)
    assert (status.state, status.stage) == ("interrupted", "scene"), status


def test_a_signal_after_an_inner_block_ended_stops_the_outer_one():
    """A sweep worker's block holds a run's block; after the run's block ends, a SIGTERM
    must stop the worker's block with Interrupted. The inner block used to take the
    outer's (equal, empty) list of stops off the stack, and the outer then failed with
    "list.remove(x): x not in list", a traceback instead of one line."""
    with pytest.raises(Interrupted) as stopped:
        with stopped_by_signals():
            with stopped_by_signals():
                pass
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(1000):  # the handler runs at one of these steps
                pass
    assert stopped.value.signum == signal.SIGTERM


def test_a_deferred_signal_stops_the_run_after_the_block_and_only_once():
    """signals_deferred: signals inside the block (three Ctrl-C) change nothing there; after
    it the first one reaches the handler from before, once. From another thread (no signal
    handler runs there) the block runs as it is."""
    steps = []
    with pytest.raises(Interrupted) as stopped:
        with stopped_by_signals():
            with signals_deferred():
                for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGINT):
                    os.kill(os.getpid(), sig)
                    for _ in range(1000):  # a handler would run at one of these steps
                        pass
                steps.append("block ended")
            steps.append("after the block")
    assert steps == ["block ended"] and stopped.value.signum == signal.SIGTERM
    ran: list[bool] = []

    def in_a_thread() -> None:
        with signals_deferred():
            ran.append(True)

    worker = threading.Thread(target=in_a_thread)
    worker.start()
    worker.join()
    assert ran == [True]


def test_a_stop_a_library_turns_into_an_error_of_its_own_is_still_the_stop():
    """A signal whose Interrupted hit a library's try/finally left its state half made, and
    the finally raised an AttributeError in its place (OmegaConf, composing a sweep's jobs):
    the sweep said "error: AttributeError ..." and a repeated Ctrl-C then killed it. The
    block raises the signal's Interrupted instead, from the library's error."""
    with pytest.raises(Interrupted) as stopped:
        with stopped_by_signals():
            try:
                os.kill(os.getpid(), signal.SIGINT)
                for _ in range(1000):  # the handler runs at one of these steps
                    pass
            finally:
                raise AttributeError("'NoneType' object has no attribute "
                                     "'_invalidate_flags_cache'")
    assert stopped.value.signum == signal.SIGINT
    assert isinstance(stopped.value.__cause__, AttributeError)
    with pytest.raises(AttributeError), stopped_by_signals():  # no signal: the error itself
        raise AttributeError("a bug")


def test_a_stop_a_library_turns_into_its_own_error_in_a_stage_names_the_stage(tmp_path):
    """The same inside a run's stage: status.json said `failed` with the library's error and
    the command "stopped by SIGTERM before the first stage" (the block's own Interrupted has
    no stage). Both say the stage now, and the library's error is the cause."""
    d = tmp_path / "run"
    with pytest.raises(Interrupted) as stopped:
        with stopped_by_signals(), RunDir(d, ["scene", "graph"]) as run:
            run.start("scene")
            run.start("graph")
            try:
                os.kill(os.getpid(), signal.SIGTERM)
                for _ in range(1000):  # the handler runs at one of these steps
                    pass
            finally:
                raise AttributeError("a library's half-made state")
    assert (stopped.value.signum, stopped.value.stage) == (signal.SIGTERM, "graph")
    assert isinstance(stopped.value.__cause__, AttributeError)
    status = json.loads((d / "status.json").read_text())
    assert (status["state"], status["stage"]) == ("interrupted", "graph")
    assert status["error"] == "stopped by SIGTERM at stage graph"
    fresh = tmp_path / "fresh"
    with pytest.raises(AttributeError), stopped_by_signals(), RunDir(fresh, ["scene"]) as run:
        run.start("scene")  # no signal: the error itself, and the run failed
        raise AttributeError("a bug")
    assert read_status(fresh).state == FAILED
