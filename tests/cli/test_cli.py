"""The command line itself, in subprocesses: --help, the `birlg` console script's completion,
and errors at start-up (a typo, a wrong type, an out-of-range value): one line, non-zero exit."""

import subprocess
import sys
from pathlib import Path

from tests.conftest import ROOT, run_app


def _fails_with_one_line(result, *fragments):
    assert result.returncode != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    for f in fragments:
        assert f in lines[0]
    assert "Traceback" not in result.stderr + result.stdout


def test_typo_and_wrong_type_fail_at_start_up(tmp_path):
    typo = run_app(f"hydra.run.dir={tmp_path}", "scene.n_persns=3")
    assert typo.returncode != 0 and "n_persns" in typo.stderr
    wrong_type = run_app(f"hydra.run.dir={tmp_path}", "seed=abc")
    assert wrong_type.returncode != 0 and "seed" in wrong_type.stderr
    assert not (tmp_path / "scene.mcap").exists()


def test_relative_input_paths_are_the_launch_dirs_also_with_hydra_job_chdir(tmp_path):
    """With hydra.job.chdir=true Hydra runs the job in its run dir: a scene file given
    relative to where the command was launched is still found there."""
    (tmp_path / "in").mkdir()
    scene = (ROOT / "data" / "scenes" / "metropolis.json").read_text()
    (tmp_path / "in" / "mine.json").write_text(scene)
    done = run_app("hydra.job.chdir=true", "scene=file", "scene.path=in/mine.json",
                   "stages=[scene]", f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "run" / "scene.mcap").exists()


def test_out_of_range_value_exits_with_one_line(tmp_path):
    _fails_with_one_line(run_app(f"hydra.run.dir={tmp_path}", "scene.body_radius=-1"),
                         "scene.body_radius=-1")


SHIPPED_SCENES = ["file", "hallway", "metropolis", "office", "random", "warehouse"]


def test_help_lists_groups_and_options_without_schemas():
    result = run_app("--help")
    assert result.returncode == 0, result.stderr
    text = result.stdout
    assert text.startswith("birlg: BIRL-G")
    # the shipped options, in order, whatever presets a user adds (conf/scene/NAME.yaml)
    [scenes] = [line.split(": ")[1].split(", ") for line in text.splitlines()
                if line.startswith("scene: ")]
    assert [s for s in scenes if s in SHIPPED_SCENES] == SHIPPED_SCENES
    assert "base_" not in text and "__main__" not in text and "powered by Hydra" not in text
    assert len(text.splitlines()) < 40  # groups and options, not the whole config


def test_the_birlg_console_script_completes_keys_and_options():
    import os

    birlg = Path(sys.executable).parent / "birlg"
    assert birlg.exists(), "pip install -e . creates the console script"
    env = {**os.environ, "COMP_LINE": "birlg scene=ra", "COMP_POINT": "14"}
    done = subprocess.run([str(birlg), "-sc", "query=bash"], env=env, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "scene=random" in done.stdout.split()


def test_no_config_sets_hydra_mode():
    """The CLI skips Hydra's extra composition that only reads hydra.mode (pipeline.__main__,
    mode_from_the_command_line): no config of this package may set it."""
    from hydra import compose, initialize_config_dir

    from tests.conftest import ROOT

    presets = [None] + sorted(p.stem for p in (ROOT / "conf" / "experiment").glob("*.yaml"))
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        for preset in presets:
            overrides = [] if preset is None else [f"experiment={preset}"]
            cfg = compose(config_name="config", overrides=overrides, return_hydra_config=True)
            assert cfg.hydra.mode is None, preset


def test_a_sweep_preset_run_without_m_warns_that_it_is_one_job(tmp_path):
    """`birlg experiment=quick` (no -m) runs one job at the config's own seed and reward:
    its sweep over them was dropped without a word."""
    result = run_app("experiment=quick", "stages=[scene]", f"hydra.run.dir={tmp_path}")
    assert result.returncode == 0, result.stderr
    warnings = [line for line in (result.stdout + result.stderr).splitlines()
                if "WARNING" in line]
    assert len(warnings) == 1 and "the config sweeps seed: 0,1; reward: polite,rude" in \
        warnings[0] and "add -m to run the sweep" in warnings[0], warnings
    plain = run_app("stages=[scene]", f"hydra.run.dir={tmp_path / 'plain'}")
    assert "WARNING" not in plain.stdout + plain.stderr


def test_make_sweep_that_runs_no_job_is_its_one_line(tmp_path):
    """A bad preset is the news; aggregating the sweep dir no job made added a second error
    about a generated dir the user never named."""
    result = subprocess.run(["make", "-s", "sweep", "EXP=nonexistent",
                             f"SWEEP={tmp_path / 'sweep'}"], cwd=ROOT, capture_output=True,
                            text=True, timeout=120)
    errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert result.returncode == 2 and len(errors) == 1, result.stderr
    assert "experiment/nonexistent" in errors[0]


def test_make_targets_pass_a_path_with_spaces_whole(tmp_path):
    """`make export RUN="my runs/a"`: the tools get one argument, not two."""
    for target, variable, tool_says in (("export", "RUN", "run dir {} not found"),
                                        ("aggregate", "SWEEP", "{}")):
        where = tmp_path / "my runs" / "a"
        result = subprocess.run(["make", "-s", target, f"{variable}={where}"], cwd=ROOT,
                                capture_output=True, text=True, timeout=120)
        assert result.returncode != 0
        assert tool_says.format(where) in result.stderr, result.stderr
        assert "Traceback" not in result.stderr


def test_the_log_file_ends_with_how_the_run_ended(tmp_path):
    """birlg.log stopped at the last progress line of a run that failed: the one line the
    command said on stderr now ends the log as well."""
    bad = tmp_path / "bad.json"
    bad.write_text('{"trajectories": [')
    run = tmp_path / "run"
    proc = run_app("expert=file", f"expert.path={bad}", f"hydra.run.dir={run}")
    said = proc.stderr.strip().splitlines()[-1]
    assert proc.returncode == 2 and said.startswith("error: demonstration file"), proc.stderr
    assert (run / "birlg.log").read_text().strip().splitlines()[-1].endswith(said)
