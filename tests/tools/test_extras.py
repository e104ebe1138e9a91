"""The optional extras: the core install runs an experiment without them, and the tools that
need rerun (the viewer extra) say in one line how to install it instead of a traceback.

Each run is a real subprocess in which the optional packages cannot be imported
(`sys.modules[name] = None` makes `import name` raise ModuleNotFoundError), as in a venv
without them."""

import json
import subprocess
import sys

import pytest

from tests.conftest import ROOT

# Not in the core install: the viewer extra (rerun-sdk, pyarrow), the tune extra (optuna),
# and ArviZ, which the convergence diagnostics no longer use.
OPTIONAL = ("rerun", "pyarrow", "optuna", "arviz")


def run_without(missing: tuple[str, ...], module: str, *args: str) -> subprocess.CompletedProcess:
    """`python -m module args` with the packages `missing` not importable."""
    code = ("import runpy, sys\n"
            f"for name in {missing!r}:\n"
            "    sys.modules[name] = None\n"
            f"sys.argv = [{module!r}, *sys.argv[1:]]\n"
            f"runpy.run_module({module!r}, run_name='__main__', alter_sys=True)\n")
    return subprocess.run([sys.executable, "-c", code, *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=600)


def test_an_mcmc_experiment_runs_without_the_optional_packages(tmp_path):
    result = run_without(OPTIONAL, "pipeline", "graph=small", "birl=mcmc",
                         "birl.n_iterations=1", "birl.n_samples=20", "birl.burn_in=10",
                         "birl.n_chains=2", f"hydra.run.dir={tmp_path}")
    assert result.returncode == 0, result.stderr[-2000:]
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["mcmc_rhat_max"] > 0.9 and metrics["mcmc_ess_min"] > 0  # diagnostics ran
    assert "arviz" not in result.stderr.lower()


@pytest.mark.parametrize("tool", ["pipeline.tools.viewer", "pipeline.tools.screenshot"])
def test_the_viewer_tools_without_rerun_say_how_to_install_it(tool, tmp_path):
    result = run_without(("rerun",), tool, str(tmp_path))
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    assert result.stderr.startswith("error: the viewer needs rerun-sdk")
    assert "pip install -e '.[viewer]'" in result.stderr and "make view" in result.stderr
