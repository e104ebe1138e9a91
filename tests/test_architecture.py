"""The package layers (docs/architecture.md): imports only point down.

    errors, progress  <  core  <  irl | inputs | artefacts  <  app  <  stages  <  tools, __main__

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

LAYER = {"errors": 0, "progress": 0, "core": 1, "irl": 2, "inputs": 2, "artefacts": 2, "app": 3,
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


def method_modules(modules: dict[str, Path]) -> set[str]:
    """The IRL modules that register a method (`@register(...)`): method modules import the
    shared modules of pipeline.irl, never another method's."""
    def registers(path: Path) -> bool:
        return any(isinstance(d, ast.Call) and getattr(d.func, "id", None) == "register"
                   for node in ast.walk(ast.parse(path.read_text()))
                   if isinstance(node, ast.FunctionDef) for d in node.decorator_list)

    return {m for m, path in modules.items() if m.startswith("pipeline.irl.") and registers(path)}


def violations(modules: dict[str, Path]) -> list[str]:
    """Every import that breaks a rule, as 'importer -> imported: why'."""
    bad = []
    methods = method_modules(modules)
    for module, path in modules.items():
        package = _package(module)
        for target in sorted(imports_of(path, module, modules)):
            if module in methods and target in methods and target != module:
                bad.append(f"{module} -> {target}: a method module imports another method")
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


def test_method_modules_are_found():
    assert {"pipeline.irl.birl", "pipeline.irl.maxent", "pipeline.irl.policywalk",
            "pipeline.irl.fixed"} <= method_modules(pipeline_modules(ROOT))


def stage_imports_in_tests(root: Path, modules: dict[str, Path]) -> list[str]:
    """Tests that import a stage module: what a test reaches through a stage (an
    algorithm, an adapter) belongs to the library; tests run stages via run_pipeline."""
    stage_modules = {m for m in modules if m.startswith("pipeline.stages.")}
    bad = []
    for path in sorted((root / "tests").rglob("*.py")):
        module = ".".join(path.relative_to(root).with_suffix("").parts)
        for target in imports_of(path, module, modules):
            if target in stage_modules:
                bad.append(f"{path.relative_to(root)} -> {target}")
    return bad


def test_tests_reach_algorithms_through_the_library_not_the_stages():
    assert stage_imports_in_tests(ROOT, pipeline_modules(ROOT)) == []


def test_a_test_importing_a_stage_is_detected(tmp_path):
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_x.py").write_text("from pipeline.stages.birl import run\n")
    assert stage_imports_in_tests(tmp_path, pipeline_modules(ROOT)) == \
        ["tests/test_x.py -> pipeline.stages.birl"]


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
    ("pipeline.irl.maxent",
     "from pipeline.irl.policywalk import f\n@register('x', C)\ndef fit(p, c):\n    pass\n",
     "method module imports another method"),
])
def test_a_violation_is_detected(tmp_path, module, source, expected):
    modules = pipeline_modules(ROOT)
    bad_file = tmp_path / "bad.py"
    bad_file.write_text(source)
    modules[module] = bad_file
    found = violations(modules)
    assert len(found) == 1 and expected in found[0], found
