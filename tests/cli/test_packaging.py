"""The built wheel is self-contained: conf/, data/ and the schemas inside, a `birlg` console
script, and the default experiment runs from a fresh venv holding only the wheel and its
dependencies, outside the source tree."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from tests.conftest import ROOT


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "-qq",
                    "--disable-pip-version-check", "-w", str(out)], check=True, timeout=900)
    (path,) = out.glob("birlg_pipeline-*.whl")
    return path


@pytest.mark.slow
def test_the_wheel_holds_conf_data_schemas_and_licences(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for inside in ("pipeline/conf/config.yaml", "pipeline/conf/hydra/help/birlg.yaml",
                   "pipeline/conf/birl/map.yaml", "pipeline/data/scenes/metropolis.json",
                   "pipeline/data/maps/office.pgm", "pipeline/schemas/scene.schema.json"):
        assert inside in names, inside
    licences = [n for n in names if "/licenses/" in n]
    assert any(n.endswith("/LICENSE") for n in licences), licences
    entry_points = next(n for n in names if n.endswith("entry_points.txt"))
    assert "birlg = pipeline.__main__:cli" in zipfile.ZipFile(wheel).read(entry_points).decode()


@pytest.mark.slow
def test_the_default_experiment_runs_from_an_installed_wheel(wheel, tmp_path):
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "-qq",
                    "--disable-pip-version-check", str(wheel)], check=True, timeout=1800)
    elsewhere = tmp_path / "elsewhere"  # no conf/, data/ or pipeline/ here
    elsewhere.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    where = subprocess.run([str(venv / "bin" / "python"), "-c",
                            "import pipeline; print(pipeline.__file__)"], cwd=elsewhere,
                           env=env, capture_output=True, text=True, check=True)
    assert str(venv) in where.stdout  # the installed copy, not the source tree
    run = subprocess.run([str(venv / "bin" / "birlg"), "hydra.run.dir=run"], cwd=elsewhere,
                         env=env, capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-2000:]
    metrics = json.loads((elsewhere / "run" / "metrics.json").read_text())
    assert metrics["policy_loss_norm"] >= 0
    help_text = subprocess.run([str(venv / "bin" / "birlg"), "--help"], cwd=elsewhere, env=env,
                               capture_output=True, text=True, check=True).stdout
    [methods] = [line.split(": ")[1].split(", ") for line in help_text.splitlines()
                 if line.startswith("birl: ")]  # a method of one's own may sort in between
    assert {"fixed", "map", "maxent", "mcmc", "policywalk"} <= set(methods)
    assert "base_" not in help_text and "__main__" not in help_text
