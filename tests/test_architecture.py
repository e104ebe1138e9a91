"""The package layers (README "What is inside"): imports only point down.

    errors  <  core  <  irl | inputs | artefacts  <  app  <  stages  <  tools, __main__

Modules of one layer-2 package do not import another layer-2 package, stage modules never
import each other, and the algorithm packages (core, irl) import no Hydra, OmegaConf, MCAP,
rerun or jsonschema (input files are checked against their schemas in inputs). The checks
parse the source (every import statement, also inside functions), so a lazy import cannot
slip past them.
"""

import ast
from pathlib import Path

import pytest

from tests.conftest import ROOT

LAYER = {"errors": 0, "core": 1, "irl": 2, "inputs": 2, "artefacts": 2, "app": 3,
         "stages": 4, "tools": 5, "api": 5, "__main__": 5}
FRAMEWORKS = ("hydra", "omegaconf", "mcap", "rerun", "jsonschema")
ALGORITHMS = ("core", "irl")


def _package(module: str) -> str:
    """pipeline.core.world -> core; pipeline -> '' (the top-level package)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def imports_of(path: Path, module: str, modules: dict[str, Path]) -> set[str]:
    """Absolute names of the modules `path` (the module `module`) imports."""
    is_package = path.name == "__init__.py"
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            name = node.module or ""
            if node.level:  # relative: resolve against this module's package
                parts = module.split(".")
                base = parts[: len(parts) - node.level + is_package]
                name = ".".join(base + ([name] if name else []))
            # `from pipeline.stages import demos` imports the module pipeline.stages.demos
            submodules = {f"{name}.{a.name}" for a in node.names} & set(modules)
            found |= submodules or {name}
    return found


def violations(modules: dict[str, Path]) -> list[str]:
    """Every import that breaks a rule, as 'importer -> imported: why'."""
    bad = []
    for module, path in modules.items():
        package = _package(module)
        for target in sorted(imports_of(path, module, modules)):
            root = target.split(".")[0]
            if package in ALGORITHMS and root in FRAMEWORKS:
                bad.append(f"{module} -> {target}: algorithm code imports a framework")
            if root != "pipeline":
                continue
            other = _package(target)
            if package == "stages" == other and "pipeline.stages" not in (module, target):
                bad.append(f"{module} -> {target}: a stage imports another stage")
            elif other not in ("", package) and LAYER[other] > LAYER[package]:
                bad.append(f"{module} -> {target}: imports upward ({package} < {other})")
            elif other not in ("", package) and LAYER[other] == LAYER[package]:
                bad.append(f"{module} -> {target}: sibling packages import each other")
    return bad


def pipeline_modules(root: Path) -> dict[str, Path]:
    modules = {}
    for path in sorted((root / "pipeline").rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        modules[".".join(parts)] = path
    return modules


def test_every_package_has_a_layer():
    packages = {_package(m) for m in pipeline_modules(ROOT)} - {""}
    assert packages <= set(LAYER), f"new package(s) {packages - set(LAYER)}: give them a layer"


def test_imports_only_point_down():
    assert violations(pipeline_modules(ROOT)) == []


@pytest.mark.parametrize("module, source, expected", [
    ("pipeline.core.world", "import hydra\n", "algorithm code imports a framework"),
    ("pipeline.irl.birl", "from mcap.writer import Writer\n", "imports a framework"),
    ("pipeline.core.world", "from jsonschema import validate\n", "imports a framework"),
    ("pipeline.core.world", "from pipeline.app.config import Config\n", "imports upward"),
    ("pipeline.core.world", "from ..app import config\n", "imports upward"),
    ("pipeline.irl.birl", "from pipeline.artefacts import topics\n", "sibling packages"),
    ("pipeline.stages.graph", "from pipeline.stages.demos import run\n", "another stage"),
    ("pipeline.stages.graph", "from pipeline.stages import demos\n", "another stage"),
    ("pipeline.stages.graph", "def f():\n    from . import birl\n", "another stage"),
])
def test_a_violation_is_detected(tmp_path, module, source, expected):
    modules = pipeline_modules(ROOT)
    bad_file = tmp_path / "bad.py"
    bad_file.write_text(source)
    modules[module] = bad_file
    found = violations(modules)
    assert len(found) == 1 and expected in found[0], found
