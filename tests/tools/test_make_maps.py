"""pipeline.tools.make_maps and make_demos: the generators reproduce the shipped map, scene
and demonstration files byte for byte, and a plan that fails its checks replaces nothing."""

import dataclasses
import subprocess
import sys

import pytest

from pipeline.errors import PipelineError
from pipeline.tools import make_demos, make_maps
from tests.conftest import ROOT

DATA = ROOT / "data"


def _same_bytes(out, names):
    for name in names:
        assert (out / name).read_bytes() == (DATA / name).read_bytes(), name


def test_make_maps_all_reproduces_the_shipped_maps_and_scenes(tmp_path):
    # the command line a maintainer runs, into a scratch data directory
    result = subprocess.run([sys.executable, "-m", "pipeline.tools.make_maps", "all",
                             "--out", str(tmp_path)], cwd=ROOT, capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stderr
    names = [f"{d}/{n}{ext}" for n in ("office", "warehouse")
             for d, ext in (("maps", ".pgm"), ("maps", ".yaml"), ("scenes", ".json"))]
    _same_bytes(tmp_path, names)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["maps", "scenes"]  # no temp dirs left


def test_make_demos_handdrawn_reproduces_the_shipped_drawings(tmp_path):
    make_demos.main(["handdrawn", "--out", str(tmp_path)])
    _same_bytes(tmp_path, ["demos/metropolis_handdrawn.json"])


def test_make_demos_refuses_an_out_that_cannot_hold_the_file_in_one_line(tmp_path, capsys):
    (tmp_path / "a_file").write_text("")
    (tmp_path / "d" / "demos" / "metropolis_handdrawn.json").mkdir(parents=True)
    for out, says in ((tmp_path / "a_file", "a_file is a file; --out needs a directory"),
                      (tmp_path / "d", "metropolis_handdrawn.json is a directory")):
        with pytest.raises(SystemExit) as stop:
            make_demos.main(["handdrawn", "--out", str(out)])
        err = capsys.readouterr().err
        assert stop.value.code == 2 and err.count("\n") == 1 and says in err, err


def test_a_plan_failing_its_checks_replaces_nothing(tmp_path):
    make_maps.write(make_maps.WAREHOUSE, tmp_path)
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    # the first start moved onto the west racks (x 0.5..12.5, y 12.0..14.6)
    broken = dataclasses.replace(make_maps.WAREHOUSE,
                                 starts=[[6.0, 13.0], *make_maps.WAREHOUSE.starts[1:]])
    with pytest.raises(PipelineError, match="start 0 .* from an obstacle"):
        make_maps.write(broken, tmp_path)
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["maps", "scenes"]


def test_an_output_place_that_cannot_take_the_files_replaces_nothing(tmp_path):
    """A file where scenes/ must go: the maps were replaced, then a traceback."""
    make_maps.write(make_maps.OFFICE, tmp_path)
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    (tmp_path / "scenes" / "office.json").unlink()
    (tmp_path / "scenes" / "office.json").mkdir()
    with pytest.raises(PipelineError, match="office.json is a directory"):
        make_maps.write(make_maps.OFFICE, tmp_path)
    (tmp_path / "scenes" / "office.json").rmdir()
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == \
        {p: b for p, b in before.items() if p.name != "office.json"}
    result = subprocess.run([sys.executable, "-m", "pipeline.tools.make_maps", "office",
                             "--out", str(tmp_path / "maps" / "office.yaml")], cwd=ROOT,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 2
    assert result.stderr == f"error: {tmp_path / 'maps' / 'office.yaml'} is a file; --out " \
                            "needs a directory there\n"


def test_the_warehouse_check_refuses_paths_out_of_range(tmp_path):
    # the promised 30-60 m raster paths are checked: a plan promising 10-20 m is refused
    short = dataclasses.replace(make_maps.WAREHOUSE, path_range=(10.0, 20.0))
    with pytest.raises(RuntimeError, match="not all within 10-20 m"):
        make_maps.write(short, tmp_path)
    assert not list(tmp_path.rglob("*.json"))
