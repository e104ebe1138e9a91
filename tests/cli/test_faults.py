"""The command line under faults, in real subprocesses: Ctrl-C and SIGTERM (one line, exit
130/143, status.json says interrupted at the stage), a full disk (a real small tmpfs: one line,
no temp file left, status.json failed, also when the log file cannot be written), and a run dir
given with quotes (refused by the early lock before anything is created)."""

from __future__ import annotations

import contextlib
import csv
import errno
import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from pipeline.__main__ import LogFiles, guard_log_files
from pipeline.app import launcher, rundir
from pipeline.app.rundir import RunDir, read_status
from pipeline.errors import PipelineError
from tests.conftest import ROOT

QUICK = ("graph=small", "birl.n_iterations=3")


def lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


def start_run(run_dir: Path, *overrides: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "pipeline", f"hydra.run.dir={run_dir}",
                             *overrides], cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)


def wait_for_stage(run_dir: Path, stage: str, proc: subprocess.Popen) -> None:
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            if json.loads((run_dir / "status.json").read_text()).get("stage") == stage:
                return
        except (OSError, ValueError):
            pass
        time.sleep(0.02)
    raise AssertionError(f"the run never reached stage {stage}: {proc.poll()}")


def wait_until_it_takes_the_signals(proc: subprocess.Popen) -> None:
    """Until the command has taken Ctrl-C, SIGTERM and SIGHUP over for its imports (/proc's
    masks of the signals it catches: SIGTERM and SIGHUP, which the interpreter leaves alone,
    the last of them; one the process ignores stays ignored), not a fixed delay: on a loaded
    machine the interpreter's own start took longer than one, and the signal then killed it
    or came as a KeyboardInterrupt traceback, before any command code ran."""
    wanted = (1 << (signal.SIGTERM - 1)) | (1 << (signal.SIGHUP - 1))
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            status = Path(f"/proc/{proc.pid}/status").read_text()
        except OSError:
            status = ""
        masks = {ln.split()[0]: int(ln.split()[1], 16) for ln in status.splitlines()
                 if ln.startswith(("SigCgt:", "SigIgn:"))}
        caught, ignored = masks.get("SigCgt:", 0), masks.get("SigIgn:", 0)
        if caught & wanted and (caught | ignored) & wanted == wanted:
            return
        time.sleep(0.002)
    raise AssertionError(f"the command never took the signals over while starting: {proc.poll()}")


# -- signals ---------------------------------------------------------------------------------


@pytest.mark.parametrize("sig, code, says", [
    (signal.SIGINT, 130, "interrupted by the user at stage graph"),
    (signal.SIGTERM, 143, "stopped by SIGTERM at stage graph"),
])
def test_a_signal_stops_the_run_in_one_line(tmp_path, sig, code, says):
    d = tmp_path / "run"
    # 5000 nodes grow for several seconds; the default's 460 took about one, and on a loaded
    # machine the signal came after the whole artefact was written (which then stays)
    proc = start_run(d, "graph.max_nodes=5000")
    wait_for_stage(d, "graph", proc)
    time.sleep(0.3)
    proc.send_signal(sig)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == code, err
    assert lines(err) == [says], err
    status = json.loads((d / "status.json").read_text())
    assert (status["state"], status["stage"], status["error"]) == ("interrupted", "graph", says)
    assert status["done"] == ["scene", "demos"]
    assert read_status(d).state == "interrupted"
    assert not list(d.glob("*.tmp")) and not (d / "graph.mcap").exists()
    assert (d / "scene.mcap").exists() and (d / "demos.mcap").exists()


@pytest.mark.parametrize("sig, says", [(signal.SIGINT, "interrupted by the user"),
                                        (signal.SIGTERM, "stopped by SIGTERM"),
                                        (signal.SIGHUP, "stopped by SIGHUP")])
def test_a_signal_while_starting_is_one_line(tmp_path, sig, says):
    """Ctrl-C (or SIGTERM, or the terminal closing) during the command's imports (most of a
    second) is one line and exit 128 + the signal, not a KeyboardInterrupt traceback from
    inside numpy or a silent end; no run dir is created."""
    proc = start_run(tmp_path / "run")
    wait_until_it_takes_the_signals(proc)  # then the imports take most of a second
    proc.send_signal(sig)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 128 + sig, err
    assert lines(err) == [f"{says} while starting"], err


@pytest.mark.parametrize("command", [[sys.executable, "-m", "pipeline.tools.export"],
                                     [str(Path(sys.executable).parent / "birlg-export")],
                                     [sys.executable, "-m", "pipeline.tools.viewer", "--no-open"],
                                     [sys.executable, "-m", "pipeline.tools.redraw"]],
                         ids=["export-module", "export-script", "viewer", "redraw"])
def test_ctrl_c_while_a_tool_starts_is_one_line(tmp_path, command):
    """A tool's imports (the export's rosbags, PIL and scipy; the viewer's rerun; matplotlib)
    take most of a second: Ctrl-C then is one line and exit 130, as for birlg."""
    proc = subprocess.Popen([*command, str(tmp_path)], cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    wait_until_it_takes_the_signals(proc)  # then the imports take most of a second
    proc.send_signal(signal.SIGINT)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 130, err
    assert lines(err) == ["interrupted by the user while starting"], err


# -- a closed pipe ---------------------------------------------------------------------------


def piped_into_a_closed_reader(command: list[str]) -> tuple[int, str]:
    """`command | head -0`: stdout is a pipe whose reader has gone before anything is read."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    proc = subprocess.Popen(command, cwd=ROOT, stdout=write_end, stderr=subprocess.PIPE,
                            text=True)
    os.close(write_end)
    err = proc.communicate(timeout=300)[1]
    return proc.returncode, err


def test_a_run_piped_into_a_closed_reader_completes(tmp_path):
    """`birlg | head -1` failed the run at stage evaluate (its summary's print raised
    BrokenPipeError) and the export and viewer ended in a traceback: now what goes to stdout
    is dropped, the run completes and the tools exit 0, with nothing on stderr."""
    run = tmp_path / "run"
    code, err = piped_into_a_closed_reader(
        [sys.executable, "-m", "pipeline", f"hydra.run.dir={run}", *QUICK])
    assert code == 0 and "Traceback" not in err and "Logging error" not in err, err
    assert read_status(run).state == "complete"
    code, err = piped_into_a_closed_reader(
        [sys.executable, "-m", "pipeline.tools.export", str(run)])
    assert (code, lines(err)) == (0, []), err
    assert (run / "export" / "costmap.yaml").is_file()


# -- a full disk -----------------------------------------------------------------------------

_ON_TMPFS = """
set -e
mount -t tmpfs -o size={kb}k tmpfs {mnt}
cd {root}
set +e
{python} -m pipeline hydra.run.dir={mnt}/run {overrides} >/dev/null 2>{err}
echo $? > {rc}
ls -a {mnt}/run > {listing} 2>/dev/null
cp {mnt}/run/status.json {status} 2>/dev/null
exit 0
"""


def run_on_a_small_disk(tmp_path: Path, kb: int, *overrides: str) -> dict:
    """A run into a tmpfs of `kb` KB, mounted in a private user and mount namespace
    (`unshare -rm`: no root needed, gone when the process ends)."""
    if shutil.which("unshare") is None:
        pytest.skip("needs util-linux unshare for a private tmpfs")
    mnt = tmp_path / "disk"
    mnt.mkdir()
    out = {k: tmp_path / f"{k}.txt" for k in ("err", "rc", "listing", "status")}
    script = _ON_TMPFS.format(kb=kb, mnt=mnt, root=ROOT, python=sys.executable,
                              overrides=" ".join(overrides), **out)
    done = subprocess.run(["unshare", "--user", "--map-root-user", "--mount", "sh", "-c",
                           script], capture_output=True, text=True, timeout=600)
    if done.returncode != 0 and "mount" in done.stderr + done.stdout:
        pytest.skip(f"cannot mount a private tmpfs here: {done.stderr.strip()[:200]}")
    assert done.returncode == 0, done.stderr
    status = out["status"]
    return {"rc": int(out["rc"].read_text()), "err": out["err"].read_text(),
            "files": out["listing"].read_text().split(),
            "status": json.loads(status.read_text()) if status.exists() else None}


@pytest.mark.parametrize("kb, stage", [(20, "scene"), (64, "demos"), (384, "graph")])
def test_a_full_disk_is_one_line_and_leaves_no_temp_file(tmp_path, kb, stage):
    # 20 KB: Hydra's files and the log fit, scene.mcap does not (the log's writes fail too);
    # 64 KB: scene.mcap fits; 384 KB: demos.mcap fits, graph.mcap does not
    r = run_on_a_small_disk(tmp_path, kb, *QUICK)
    assert r["rc"] == 2, r
    assert len(lines(r["err"])) == 1 and "the disk is full" in r["err"], r["err"]
    assert "Logging error" not in r["err"] and "Traceback" not in r["err"]
    assert not [f for f in r["files"] if f.endswith(".tmp")], r["files"]
    assert r["status"]["state"] == "failed" and r["status"]["stage"] == stage, r["status"]
    assert "the disk is full" in r["status"]["error"]


@pytest.mark.slow
def test_a_full_disk_at_every_size(tmp_path):
    for kb in (8, 12, 16, 24, 28, 36, 48, 96, 128, 192, 256, 320, 448, 512, 1024):
        work = tmp_path / str(kb)
        work.mkdir()
        r = run_on_a_small_disk(work, kb, *QUICK)
        assert r["rc"] in (0, 2), (kb, r)
        assert len(lines(r["err"])) == (r["rc"] != 0), (kb, r["err"])
        assert not [f for f in r["files"] if f.endswith(".tmp")], (kb, r["files"])
        if r["status"] is not None:  # none when Hydra's own files did not fit
            assert r["status"]["state"] == ("complete" if r["rc"] == 0 else "failed"), (kb, r)


def test_status_json_is_written_in_place_when_no_temp_file_fits(tmp_path, monkeypatch):
    d = tmp_path / "run"

    def disk_full(path, obj):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    with pytest.raises(PipelineError, match="the disk is full"):
        with RunDir(d, ["scene"]):
            monkeypatch.setattr(rundir, "write_json_atomic", disk_full)
            raise PipelineError("stage scene: the disk is full")
    status = json.loads((d / "status.json").read_text())
    assert (status["state"], status["error"]) == ("failed", "stage scene: the disk is full")
    assert [p.name for p in d.iterdir() if p.name != ".lock"] == ["status.json"]


def test_a_log_file_that_cannot_be_written_is_dropped_without_tracebacks(tmp_path, capfd):
    class FullDisk(logging.FileHandler):
        def emit(self, record):
            try:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            except OSError:
                self.handleError(record)

    handler = FullDisk(tmp_path / "birlg.log", delay=True)
    root = logging.getLogger("a private root")  # the real root holds pytest's handlers
    root.propagate = False
    root.addHandler(handler)
    LogFiles.failed.clear()
    guard_log_files(root)
    for _ in range(5):
        root.getChild("pipeline").warning("a record")
    assert "Logging error" not in capfd.readouterr().err
    assert handler not in root.handlers
    assert LogFiles.failed == [f"{tmp_path / 'birlg.log'}: the disk is full"]


# -- run dirs given with quotes --------------------------------------------------------------


@pytest.mark.parametrize("form", ['hydra.run.dir="{d}"', "hydra.run.dir='{d}'",
                                  '++hydra.run.dir="{d}"'])
def test_a_quoted_run_dir_in_use_is_refused_before_anything_is_made(tmp_path, form):
    d = tmp_path / "run"
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    with RunDir(d, ["scene"]):
        (d / ".hydra").mkdir()
        (d / ".hydra" / "config.yaml").write_text("the holder's\n")
        # from another cwd, where a dir named '"' would appear; this source tree's package
        proc = subprocess.run([sys.executable, "-m", "pipeline", "seed=1", form.format(d=d),
                               "stages=[scene]"], cwd=cwd, capture_output=True, text=True,
                              timeout=600, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 2 and lines(proc.stderr) == [
        f"error: run dir {d} is in use by another process (a run or an export); wait for it to "
        "finish, or for a new run choose another hydra.run.dir (pipeline.api: run_dir=)"], \
        proc.stderr
    assert (d / ".hydra" / "config.yaml").read_text() == "the holder's\n"
    assert list(cwd.iterdir()) == []  # no dir named '"' or "'"


# -- a sweep's pool of workers under signals --------------------------------------------------

# three jobs on two workers, each several seconds long (MCMC), so a signal finds two running
SLOW_SWEEP = ("-m", "experiment=quick", "seed=0,1,2", "reward=polite", "birl=mcmc",
              "hydra/launcher=pool", "hydra.launcher.n_jobs=2")


def start_sweep(sweep_dir: Path, *, own_group: bool = False) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "pipeline", *SLOW_SWEEP,
                             f"hydra.sweep.dir={sweep_dir}"], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=own_group)


def job_states(sweep_dir: Path) -> dict[str, tuple]:
    states = {}
    for job in sorted(sweep_dir.glob("[0-9]*")):
        try:
            status = json.loads((job / "status.json").read_text())
        except (OSError, ValueError):
            continue
        states[job.name] = (status["state"], status["stage"], status["error"])
    return states


def wait_for_running_jobs(sweep_dir: Path, proc: subprocess.Popen, n: int = 2) -> None:
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:
        running = [s for s in job_states(sweep_dir).values() if s[0] == "running"]
        if len(running) >= n and all(s[1] == "birl" for s in running):
            return
        time.sleep(0.05)
    raise AssertionError(f"the sweep never had {n} jobs learning: {job_states(sweep_dir)}")


def worker_pids(proc: subprocess.Popen) -> list[int]:
    return [int(p) for p in (Path(f"/proc/{proc.pid}/task/{proc.pid}/children")
                             .read_text().split())]


@pytest.mark.parametrize("sig, code, says, whole_group", [
    (signal.SIGINT, 130, "interrupted by the user", False),
    (signal.SIGINT, 130, "interrupted by the user", True),  # Ctrl-C at a terminal
    (signal.SIGTERM, 143, "stopped by SIGTERM", False),
    (signal.SIGHUP, 129, "stopped by SIGHUP", True),  # the terminal closed
])
def test_a_signal_stops_a_sweep_and_its_workers(tmp_path, sig, code, says, whole_group):
    """The running jobs record the signal once, no queued job starts after it, no worker is
    left behind, and the command says so in one line."""
    proc = start_sweep(tmp_path, own_group=whole_group)
    wait_for_running_jobs(tmp_path, proc)
    workers = worker_pids(proc)
    os.killpg(proc.pid, sig) if whole_group else proc.send_signal(sig)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == code, err
    assert lines(err) == [f"{says} during the sweep (0 of 3 jobs completed; make aggregate "
                          "lists them)"], err
    assert job_states(tmp_path) == {j: ("interrupted", "birl", f"{says} at stage birl")
                                    for j in ("0", "1")}
    assert not (tmp_path / "2").exists()  # the third job never started
    assert not [w for w in workers if Path(f"/proc/{w}").exists()
                and "Z" not in Path(f"/proc/{w}/stat").read_text().split()[2]]


def test_a_second_ctrl_c_kills_jobs_that_do_not_stop(tmp_path):
    """Jobs that do not answer the first Ctrl-C (here frozen with SIGSTOP, as a job stuck in
    a long C call is) would be waited for STOP_WAIT_S (60 s); a second Ctrl-C kills them at
    once, and the sweep still ends in its one line."""
    proc = start_sweep(tmp_path)
    wait_for_running_jobs(tmp_path, proc)
    workers = worker_pids(proc)
    try:
        for w in workers:
            os.kill(w, signal.SIGSTOP)
        proc.send_signal(signal.SIGINT)
        time.sleep(1.0)
        assert proc.poll() is None  # waiting for the frozen jobs to record the stop
        proc.send_signal(signal.SIGINT)
        err = proc.communicate(timeout=20)[1]
    finally:
        for w in workers:
            with contextlib.suppress(ProcessLookupError):
                os.kill(w, signal.SIGKILL)
        proc.kill()
    assert proc.returncode == 130, err
    assert lines(err) == ["interrupted by the user during the sweep (0 of 3 jobs completed; "
                          "make aggregate lists them)"], err
    assert not [w for w in workers if Path(f"/proc/{w}").exists()
                and "Z" not in Path(f"/proc/{w}/stat").read_text().split()[2]]
    # as the jobs' readers see them: killed where they were, no longer running
    assert [(read_status(tmp_path / j).state, read_status(tmp_path / j).error)
            for j in ("0", "1")] == [("interrupted", rundir.KILLED)] * 2


def test_ctrl_c_stops_a_sweep_of_one_worker_in_one_line(tmp_path):
    """hydra.launcher.n_jobs=1 runs the jobs one after another in the sweep's own process
    (no fork): Ctrl-C there stops the sweep as with a pool, the running job records it, the
    queued ones never start, and the last line counts the jobs completed."""
    proc = subprocess.Popen([sys.executable, "-m", "pipeline", *SLOW_SWEEP[:-1],
                             "hydra.launcher.n_jobs=1", f"hydra.sweep.dir={tmp_path}"],
                            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    wait_for_running_jobs(tmp_path, proc, n=1)
    proc.send_signal(signal.SIGINT)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 130, err
    assert lines(err) == ["interrupted by the user during the sweep (0 of 3 jobs completed; "
                          "make aggregate lists them)"], err
    assert job_states(tmp_path) == {"0": ("interrupted", "birl",
                                          "interrupted by the user at stage birl")}
    assert not (tmp_path / "1").exists() and not (tmp_path / "2").exists()


def test_a_killed_worker_fails_its_job_alone(tmp_path):
    """SIGKILL of one worker (the OOM killer's way): its job is one failed job, a new worker
    takes its place, the others complete, and the sweep exits 1 naming it."""
    proc = start_sweep(tmp_path)
    wait_for_running_jobs(tmp_path, proc)
    victim = worker_pids(proc)[0]
    os.kill(victim, signal.SIGKILL)
    err = proc.communicate(timeout=300)[1]
    assert proc.returncode == 1, err
    states = job_states(tmp_path)
    failed = [j for j, s in states.items() if s[0] == "failed"]
    assert len(failed) == 1 and len(states) == 3, states
    assert states[failed[0]] == ("failed", "birl", "the worker process running this job died "
                                 "(killed by SIGKILL)")
    assert [s[0] for j, s in states.items() if j != failed[0]] == ["complete", "complete"]
    assert lines(err)[-1].startswith(f"error: 1 sweep job(s) failed, first {tmp_path / failed[0]}")


def test_the_workers_of_a_killed_sweep_stop(tmp_path):
    """SIGKILL of the sweep's process: its workers notice within a second or two; the running
    jobs record SIGTERM, and none is left running."""
    proc = start_sweep(tmp_path)
    wait_for_running_jobs(tmp_path, proc)
    workers = worker_pids(proc)
    proc.kill()
    proc.communicate(timeout=60)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and any(Path(f"/proc/{w}").exists() for w in workers):
        time.sleep(0.1)
    alive = [w for w in workers if Path(f"/proc/{w}").exists()
             and "Z" not in Path(f"/proc/{w}/stat").read_text().split()[2]]
    assert not alive
    assert {s[0] for s in job_states(tmp_path).values()} == {"interrupted"}
    assert all(s[2] == "stopped by SIGTERM at stage birl" for s in job_states(tmp_path).values())


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_at_any_moment_of_a_short_sweep_is_one_line(tmp_path, sig):
    """Whenever the signal comes (importing, composing the configs in the workers, running
    the jobs, after the last one), and however often it is repeated (three times, 30 ms
    apart), the command says one line naming it and exits 128 + the signal: no traceback
    from a worker, no silent end in Python's teardown. The delays count from the moment the
    command has taken the signals over (0.05 s into it on an idle machine), not from its
    start: on a loaded machine the interpreter's own start took longer than 0.6 s, and the
    signal then killed it (SIGTERM: -15) or came as a KeyboardInterrupt traceback from its
    imports, before any command code ran."""
    for k, delay in enumerate((0.55, 0.95, 1.35, 1.75, 2.35, 3.15)):
        sweep_dir = tmp_path / str(k)
        proc = subprocess.Popen([sys.executable, "-m", "pipeline", "-m", "experiment=quick",
                                 "seed=0,1,2,3", "reward=polite", "hydra.launcher.n_jobs=2",
                                 f"hydra.sweep.dir={sweep_dir}"], cwd=ROOT,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        wait_until_it_takes_the_signals(proc)
        time.sleep(delay)
        for _ in range(3):
            if proc.poll() is None:
                proc.send_signal(sig)
                time.sleep(0.03)
        err = proc.communicate(timeout=120)[1]
        if proc.returncode == 0:  # the sweep was over before the signal came
            continue
        says = "interrupted by the user" if sig == signal.SIGINT else "stopped by SIGTERM"
        assert proc.returncode == 128 + sig, (delay, err)
        assert len(lines(err)) == 1 and lines(err)[0].startswith(says), (delay, err)
        assert "before the first stage" not in err, (delay, err)


@pytest.mark.parametrize("workers", [1, 2])
def test_a_job_whose_run_dir_cannot_be_made_fails_alone(tmp_path, workers):
    """A file where a job's run dir should be (Hydra's run_job cannot make it, so no
    status.json can say anything): that job fails alone, the others complete, and the
    sweep's last line names it with the reason (exit 1)."""
    (tmp_path / "1").write_text("not a dir")
    result = subprocess.run([sys.executable, "-m", "pipeline", "-m", "experiment=quick",
                             "seed=0,1,2", "reward=polite", f"hydra.launcher.n_jobs={workers}",
                             f"hydra.sweep.dir={tmp_path}"], cwd=ROOT, capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 1, result.stderr[-2000:]
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    assert lines(result.stderr)[-1].startswith(
        f"error: 1 sweep job(s) failed, first {tmp_path / '1'}: cannot set up the job's run "
        "dir: "), result.stderr[-2000:]
    assert read_status(tmp_path / "0").complete and read_status(tmp_path / "2").complete


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_while_the_pool_forks_its_workers_stops_the_sweep(tmp_path, sig):
    """Ctrl-C reaching the whole group just as the pool forks its workers (within ~15 ms of
    its first log line): it was swallowed inside the fork (Python's "Exception ignored"),
    the sweep ran on and exited 0, or a half-made worker printed a traceback. Signals are
    held during the forks, so the sweep stops, in one line. (48 jobs, which cost nothing
    when the signal comes: with four, and then twelve, a loaded machine's test process read
    the log line after the sweep had run them all.)"""
    for k, delay in enumerate((0.004, 0.008, 0.012, 0.016)):
        proc = subprocess.Popen([sys.executable, "-m", "pipeline", "-m", "experiment=quick",
                                 "seed=range(48)", "reward=polite", "hydra.launcher.n_jobs=2",
                                 f"hydra.sweep.dir={tmp_path / str(k)}"], cwd=ROOT,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)
        assert proc.stdout is not None
        for line in proc.stdout:
            if "Pool of 2 worker(s)" in line:
                time.sleep(delay)
                os.killpg(proc.pid, sig)
                break
        err = proc.communicate(timeout=120)[1]
        assert proc.returncode == 128 + sig, (delay, err)
        assert len(lines(err)) == 1 and "during the sweep" in err, (delay, err)


# -- a signal while Hydra starts a run in a dir an earlier run completed ---------------------

STOP_AT_JOB_START = ("+hydra.callbacks.stop._target_=tests.hydra_callbacks.SignalAtJobStart",)
STOP_AT_RUN_START = ("+hydra.callbacks.stop._target_=tests.hydra_callbacks.SignalAtRunStart",)


def by_signal(callback: tuple[str, ...], sig: int) -> tuple[str, ...]:
    return (*callback, f"+hydra.callbacks.stop.signum={int(sig)}")


def run_cmd(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pipeline", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_after_hydra_rewrote_a_complete_run_dir_marks_it_interrupted(tmp_path, sig):
    """Hydra writes the new overrides into .hydra/ before the run begins: a signal there
    must not leave the earlier run's `complete` beside them (a table would pair this run's
    overrides with the earlier run's metrics). Its artefacts stay as they were."""
    d = tmp_path / "run"
    assert run_cmd(*QUICK, f"hydra.run.dir={d}").returncode == 0
    artefacts = {p.name: p.stat().st_mtime_ns for p in d.glob("*.mcap")}
    proc = run_cmd(*QUICK, "seed=5", f"hydra.run.dir={d}", *by_signal(STOP_AT_JOB_START, sig))
    assert proc.returncode == 128 + sig, proc.stderr
    assert len(lines(proc.stderr)) == 1, proc.stderr
    assert "seed=5" in (d / ".hydra" / "overrides.yaml").read_text()
    status = read_status(d)
    assert status.state == "interrupted" and status.done == () and \
        "before the first stage" in status.error, status
    assert {p.name: p.stat().st_mtime_ns for p in d.glob("*.mcap")} == artefacts


def test_a_signal_before_hydra_writes_leaves_the_earlier_run_as_it_was(tmp_path):
    d = tmp_path / "run"
    assert run_cmd(*QUICK, f"hydra.run.dir={d}").returncode == 0
    before = {p.name: p.read_bytes() for p in [*d.glob(".hydra/*"), d / "status.json"]}
    proc = run_cmd(*QUICK, "seed=5", f"hydra.run.dir={d}",
                   *by_signal(STOP_AT_RUN_START, signal.SIGTERM))
    assert proc.returncode == 143 and len(lines(proc.stderr)) == 1, proc.stderr
    assert {p.name: p.read_bytes() for p in [*d.glob(".hydra/*"), d / "status.json"]} == before
    assert read_status(d).complete


@pytest.mark.parametrize("launcher, code", [("basic", 143), ("pool", 1)])
def test_a_signal_while_hydra_starts_a_rerun_sweeps_job(tmp_path, launcher, code):
    """A sweep re-run into a dir whose jobs completed: a job stopped after Hydra rewrote
    its .hydra/ says interrupted, with this sweep's number, and counts. With Hydra's basic
    launcher the signal stops the sweep; in a pool worker it fails that job alone (each
    job signals its own worker here: both fail)."""
    sweep = tmp_path / "sweep"
    assert run_cmd("-m", *QUICK, "seed=1,2", f"hydra.sweep.dir={sweep}").returncode == 0
    proc = run_cmd("-m", *QUICK, "seed=3,4", f"hydra.sweep.dir={sweep}",
                   f"hydra/launcher={launcher}", *by_signal(STOP_AT_JOB_START, signal.SIGTERM))
    assert proc.returncode == code, proc.stderr
    err = [ln for ln in lines(proc.stderr) if "[HYDRA]" not in ln]
    assert len(err) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "seed=3" in (sweep / "0" / ".hydra" / "overrides.yaml").read_text()
    first = read_status(sweep / "0")
    assert (first.state, first.sweep) == ("interrupted", 2), first
    table = subprocess.run([sys.executable, "-m", "pipeline.tools.aggregate", str(sweep)],
                           cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert table.returncode != 0, table.stdout + table.stderr
    with open(sweep / "summary.csv", newline="") as f:
        rows = {row["job"]: row for row in csv.DictReader(f)}
    # job 0's row: this sweep's overrides, no metric of the earlier sweep's job 0
    assert (rows["0"]["status"], rows["0"]["seed"]) == ("interrupted", "3"), rows
    assert "policy_loss" not in rows["0"] or rows["0"]["policy_loss"] == "", rows


# A worker stopped after taking a job but before Hydra begins it (made deterministic: the
# worker sends itself the signal given first as it starts job #1).
_STOPPED_BEFORE_HYDRA = """
import os, signal, sys
signum = int(sys.argv.pop(1))
sys.argv[0] = "birlg"
from pipeline.app import launcher
from pipeline.__main__ import cli
_execute = launcher.PoolLauncher.execute
def execute(self, idx, cfg):
    if idx == 1:
        os.kill(os.getpid(), signum)
    return _execute(self, idx, cfg)
launcher.PoolLauncher.execute = execute
cli()
"""


def aggregate_rows(sweep: Path) -> tuple[subprocess.CompletedProcess, dict[str, dict]]:
    table = subprocess.run([sys.executable, "-m", "pipeline.tools.aggregate", str(sweep)],
                           cwd=ROOT, capture_output=True, text=True, timeout=120)
    with open(sweep / "summary.csv", newline="") as f:
        return table, {row["job"]: row for row in csv.DictReader(f)}


@pytest.mark.parametrize("rerun", [False, True])
@pytest.mark.parametrize("sig, state, error", [
    (signal.SIGKILL, "failed", "the worker process running this job died (killed by SIGKILL)"),
    (signal.SIGTERM, "interrupted", "stopped by SIGTERM before the first stage"),
])
def test_a_job_stopped_before_hydra_begins_it_is_a_failed_row(tmp_path, rerun, sig, state,
                                                              error):
    """The job has no status.json of this sweep (a fresh dir: none at all; a re-run: the
    earlier sweep's `complete`): the sweep's last line counts it and the table has it as a
    failed row (with its settings where the dir was fresh), never with the earlier sweep's
    metrics."""
    sweep = tmp_path / "sweep"
    if rerun:
        assert run_cmd("-m", *QUICK, "seed=1,2,3", f"hydra.sweep.dir={sweep}").returncode == 0
    proc = subprocess.run([sys.executable, "-c", _STOPPED_BEFORE_HYDRA, str(int(sig)), "-m",
                           *QUICK, "seed=4,5,6", "hydra/launcher=pool",
                           "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={sweep}"],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 1, proc.stderr
    assert [ln for ln in lines(proc.stderr) if "[HYDRA]" not in ln] == [
        f"error: 1 sweep job(s) failed, first {sweep / '1'}: {error} (make aggregate lists "
        "all)"], proc.stderr
    table, rows = aggregate_rows(sweep)
    assert table.returncode == 1, table.stderr
    assert [rows[j]["status"] for j in "02"] == ["ok", "ok"], rows
    assert rows["1"]["status"] == ("failed" if rerun else state), rows
    assert rows["1"]["error"] == error and rows["1"].get("policy_loss", "") == "", rows
    assert rows["1"]["seed"] == ("" if rerun else "5"), rows
    assert "earlier sweep" not in table.stderr, table.stderr


def test_a_worker_that_died_idle_is_replaced_before_its_next_job(tmp_path):
    """A signal of its own ends an idle worker (between jobs SIGTERM is the default action):
    the next job must go to a new worker, not to a broken pipe that stopped the sweep."""
    class Composer:
        def compose(self, overrides):
            return list(reversed(overrides))

    launcher._Current.launcher, launcher._Current.jobs = Composer(), {0: ["a", "b"], 1: ["c"]}
    pool = launcher._Pool(1)
    try:
        assert pool.run("compose", [(0, None)], on_death=None) == {0: ["b", "a"]}
        dead = pool.workers[0].process
        os.kill(dead.pid, signal.SIGTERM)
        dead.join(10)
        assert pool.run("compose", [(1, None)], on_death=None) == {1: ["c"]}
        assert pool.workers[0].process is not dead
    finally:
        pool.close()
        launcher._Current.launcher, launcher._Current.jobs = None, {}


def test_a_job_that_ends_while_the_sweep_stops_counts_as_completed():
    """Ctrl-C to a sweep: a job whose reply (not Interrupted) comes in while the pool waits
    for its workers to stop was run to its end, and the sweep's last line counts it (it
    said 0 of 6 jobs completed with job 0 complete). A compose request, which a worker
    finishes whatever SIGINT says, stands in for such a job."""
    class SlowComposer:
        def compose(self, overrides):
            time.sleep(0.5)
            return overrides

    launcher._Current.launcher, launcher._Current.jobs = SlowComposer(), {0: ["a"]}
    with rundir.signals_deferred():  # as the launcher forks: a SIGINT before the worker's
        pool = launcher._Pool(1)  # own handlers must not end it (flaky, 1 in ~20, before)
    try:
        pool.workers[0].send("compose", 0, None)
        pool._stop(signal.SIGINT, "execute")
        assert pool.executed == 1 and pool.workers[0].job is None
    finally:
        pool.close()
        launcher._Current.launcher, launcher._Current.jobs = None, {}


def test_a_second_ctrl_c_while_the_sweep_stops_kills_the_job_and_restores_the_handler():
    """While the pool waits for its jobs to record a stop, Ctrl-C is Python's again (a
    second one raises KeyboardInterrupt there): that second Ctrl-C ends the wait, the job
    that did not answer is killed at once (not waited for STOP_WAIT_S), and the stop
    returns, leaving SIGINT as it found it (here ignored, as the first stop leaves it)."""
    class StuckComposer:
        def compose(self, overrides):
            time.sleep(30)  # a compose request is finished whatever SIGINT says
            return overrides

    launcher._Current.launcher, launcher._Current.jobs = StuckComposer(), {0: ["a"]}
    with rundir.signals_deferred():
        pool = launcher._Pool(1)
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    second = threading.Timer(0.5, os.kill, (os.getpid(), signal.SIGINT))
    try:
        worker = pool.workers[0].process
        pool.workers[0].send("compose", 0, None)
        started = time.monotonic()
        second.start()
        try:
            pool._stop(signal.SIGINT, "execute")
        except KeyboardInterrupt:
            pytest.fail("the second Ctrl-C left the stop")
        assert time.monotonic() - started < 10
        worker.join(5)
        assert not worker.is_alive()
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        second.cancel()
        signal.signal(signal.SIGINT, before)
        pool.close()
        launcher._Current.launcher, launcher._Current.jobs = None, {}


def test_a_signal_while_a_reply_comes_in_leaves_the_pipe_whole():
    """Ctrl-C while the sweep's process reads a worker's reply: the reply is read to its end
    before the signal stops the sweep. Cut short, the rest of it stayed in the pipe and the
    pool read a length from its middle, waiting for ever (a sweep hung on a Ctrl-C). A reply
    of 64 MB takes long enough to read that the signal comes while it does; a watchdog ends
    the worker if the pool hangs all the same, so the test fails instead."""
    class BigComposer:
        def compose(self, overrides):
            return bytes(64 << 20) if overrides == ["big"] else overrides

    launcher._Current.launcher = BigComposer()
    launcher._Current.jobs = {0: ["big"], 1: ["small"]}
    with rundir.signals_deferred():
        pool = launcher._Pool(1)
    main_thread, done, seen_in_recv = threading.main_thread().ident, threading.Event(), []

    def interrupt_while_reading() -> None:
        while not done.is_set():
            frame = sys._current_frames().get(main_thread)
            while frame is not None and frame.f_code.co_name != "_recv":
                frame = frame.f_back
            if frame is not None:
                seen_in_recv.append(True)
                os.kill(os.getpid(), signal.SIGINT)
                return
            time.sleep(0.0002)

    def watchdog() -> None:
        if not done.wait(60):
            pool.workers[0].process.kill()

    threads = [threading.Thread(target=f, daemon=True)
               for f in (interrupt_while_reading, watchdog)]
    try:
        with pytest.raises(rundir.Interrupted), rundir.stopped_by_signals():
            for t in threads:
                t.start()
            pool.run("compose", [(0, None)], on_death=None)
        assert seen_in_recv, "the signal did not come while the reply was read"
        assert pool.workers[0].job is None and pool.workers[0].process.is_alive()
        assert pool.run("compose", [(1, None)], on_death=None) == {1: ["small"]}
    finally:
        done.set()
        pool.close()
        launcher._Current.launcher, launcher._Current.jobs = None, {}


# -- a read-only run dir or sweep dir (as a user without root's override of permissions) -----

DROP_ROOTS_OVERRIDE = ["setpriv", "--bounding-set=-dac_override,-dac_read_search",
                       "--inh-caps=-dac_override,-dac_read_search", "--"]


def run_as_user(*args: str) -> subprocess.CompletedProcess:
    """The command as a user for whom permissions hold (root passes over them: here root
    drops that power with setpriv)."""
    prefix = DROP_ROOTS_OVERRIDE if os.geteuid() == 0 else []
    if prefix and shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: permissions cannot be made to hold")
    return subprocess.run([*prefix, sys.executable, "-m", "pipeline", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)


def contents(d: Path) -> dict[str, bytes]:
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def test_a_read_only_run_dir_is_refused_before_hydra_writes_into_it(tmp_path):
    d = tmp_path / "run"
    assert run_cmd(*QUICK, f"hydra.run.dir={d}").returncode == 0
    before = contents(d)
    d.chmod(0o555)
    try:
        proc = run_as_user(*QUICK, "seed=4", f"hydra.run.dir={d}")
    finally:
        d.chmod(0o755)
    assert proc.returncode == 2, proc.stderr
    assert len(lines(proc.stderr)) == 1 and \
        proc.stderr.startswith(f"error: cannot use run dir {d}: Permission denied"), proc.stderr
    assert contents(d) == before  # not this run's overrides beside the earlier run's metrics


def test_a_read_only_sweep_dir_is_refused_in_one_line(tmp_path):
    sweep = tmp_path / "sweep"
    assert run_cmd("-m", *QUICK, "seed=1,2", f"hydra.sweep.dir={sweep}").returncode == 0
    before = contents(sweep)
    sweep.chmod(0o555)
    try:
        proc = run_as_user("-m", *QUICK, "seed=3,4", f"hydra.sweep.dir={sweep}")
    finally:
        sweep.chmod(0o755)
    assert proc.returncode == 2, proc.stderr
    assert len(lines(proc.stderr)) == 1 and proc.stderr.startswith(
        f"error: cannot use sweep dir {sweep}: Permission denied"), proc.stderr
    assert contents(sweep) == before


@pytest.mark.parametrize("launcher", ["basic", "pool"])
def test_a_read_only_job_dir_fails_its_job_alone(tmp_path, launcher):
    sweep = tmp_path / "sweep"
    assert run_cmd("-m", *QUICK, "seed=1,2", f"hydra.sweep.dir={sweep}").returncode == 0
    hydra_files = {f"{p.parent.name}/{p.name}": p.read_bytes()
                   for p in (sweep / "1" / ".hydra").glob("*.yaml")}
    (sweep / "1").chmod(0o555)
    relative = os.path.relpath(sweep, ROOT)  # as users give it (Hydra's job dirs: absolute)
    try:
        proc = run_as_user("-m", *QUICK, "seed=3,4", f"hydra.sweep.dir={relative}",
                           f"hydra/launcher={launcher}")
    finally:
        (sweep / "1").chmod(0o755)
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr
    assert any(lines(proc.stderr)[-1].startswith(
        f"error: 1 sweep job(s) failed, first {job}: cannot use run dir {job}: Permission denied")
        for job in (sweep / "1", os.path.join(relative, "1"))), proc.stderr
    table, rows = aggregate_rows(sweep)
    assert table.returncode == 1, table.stderr
    assert (rows["0"]["status"], rows["0"]["seed"]) == ("ok", "3"), rows
    assert rows["1"]["status"] == "failed" and rows["1"].get("policy_loss", "") == "", rows
    # the dir still pairs the earlier run's overrides with its metrics (Hydra's basic
    # launcher rewrites .hydra/, which stays writable, and the sweep puts it back)
    assert "seed=2" in (sweep / "1" / ".hydra" / "overrides.yaml").read_text()
    assert hydra_files == {f: (sweep / "1" / f).read_bytes() for f in hydra_files}


def test_a_sweep_under_nohup_outlives_its_terminal(tmp_path):
    """`nohup make sweep` ignores SIGHUP so that closing the terminal does not stop the
    sweep: the sweep took the signal over anyway (exit 129), and its workers reset it
    between jobs. Hang-ups all through the sweep now change nothing."""
    proc = subprocess.Popen([sys.executable, "-m", "pipeline", "-m", "experiment=quick",
                             "seed=0,1,2", "reward=polite", "birl=mcmc", "hydra/launcher=pool",
                             "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={tmp_path}"],
                            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_IGN))
    wait_for_running_jobs(tmp_path, proc)
    while proc.poll() is None:  # during jobs and between them
        os.killpg(proc.pid, signal.SIGHUP)
        time.sleep(0.1)
    err = proc.communicate(timeout=300)[1]
    assert proc.returncode == 0, err
    assert {job: state[0] for job, state in job_states(tmp_path).items()} == \
        {"0": "complete", "1": "complete", "2": "complete"}


def test_the_terminal_closing_on_a_joblib_sweep_is_one_line(tmp_path):
    """SIGHUP to the whole process group (the terminal closing) also reached the joblib
    launcher's resource tracker, which died: warnings and tracebacks from its successor
    below the one line, and semaphores left in /dev/shm."""
    proc = subprocess.Popen([sys.executable, "-m", "pipeline", "-m", "experiment=quick",
                             "seed=0,1,2", "reward=polite", "birl=mcmc", "hydra/launcher=joblib",
                             f"hydra.sweep.dir={tmp_path}"], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    wait_for_running_jobs(tmp_path, proc)
    os.killpg(proc.pid, signal.SIGHUP)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 129, err
    assert [ln for ln in lines(err) if "[HYDRA]" not in ln] == [
        "stopped by SIGHUP during the sweep"], err
    left = list(Path("/dev/shm").glob(f"*loky-{proc.pid}-*"))  # (none where no such dir)
    deadline = time.monotonic() + 60
    while left and time.monotonic() < deadline:  # the tracker removes them as it ends
        time.sleep(0.1)
        left = list(Path("/dev/shm").glob(f"*loky-{proc.pid}-*"))
    assert not left
