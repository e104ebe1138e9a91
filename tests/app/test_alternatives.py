"""The alternatives lattice's size (birl.alternatives=lattice): as set on a small floor,
coarsened to at most ALTERNATIVES_MAX_NODES nodes on a large one, with the reason."""

import json
import math

import numpy as np
import pytest
from PIL import Image

from pipeline.app import build, limits
from pipeline.app.config import load_settings
from pipeline.inputs.scene_file import load_scene_file
from tests.conftest import OFFICE_SCENE, ROOT, compose_config


def test_a_small_floor_keeps_the_spacing_as_set():
    assert limits.alternatives_spacing(100.0, 0.2, "metropolis") == (0.2, "")


@pytest.mark.parametrize("area", [1600.0, 1.0e4])
def test_a_large_floor_gets_a_coarser_lattice_and_says_why(area):
    spacing, why = limits.alternatives_spacing(area, 0.2, "big")
    assert spacing > 0.2
    assert area / spacing**2 == pytest.approx(limits.ALTERNATIVES_MAX_NODES)
    assert math.isclose(spacing, math.sqrt(area / limits.ALTERNATIVES_MAX_NODES))
    assert "birl.alternatives_spacing" in why and "'big'" in why


def test_an_unknown_margin_round_a_map_leaves_the_lattice_as_it_is(tmp_path):
    """A SLAM map is mostly unknown round the building; the lattice was sized by the map's
    whole extent and coarsened (a 20 m floor with 100 m of margin: 3.04 m apart, on which
    a start could not reach the goal, and other weights were learned). Its nodes lie in the
    free space only, which sizes it now: the same lattice with and without the margin."""
    margin_m, unknown = 20.0, 205
    office = Image.open(ROOT / "data" / "maps" / "office.pgm")
    cells = round(margin_m / 0.05)
    padded = np.pad(np.asarray(office), cells, constant_values=unknown)
    Image.fromarray(padded).save(tmp_path / "padded.pgm")
    (tmp_path / "padded.yaml").write_text(
        "image: padded.pgm\nresolution: 0.05\n"
        f"origin: [{-margin_m}, {-margin_m}, 0.0]\nnegate: 0\noccupied_thresh: 0.65\n"
        "free_thresh: 0.196\n")
    scene = json.loads(OFFICE_SCENE.read_text())
    (tmp_path / "padded.json").write_text(json.dumps({**scene, "map": "padded.yaml"}))
    cfg = load_settings(compose_config())
    lattices = []
    for path in (OFFICE_SCENE, tmp_path / "padded.json"):
        loaded = load_scene_file(path)
        lattice = build.alternatives_lattice(cfg, loaded)()
        assert lattice is not None  # every start reaches the goal on it
        lattices.append(lattice)
    assert loaded.room.area > 10 * loaded.free_area  # the case: mostly unknown
    original, with_margin = lattices
    assert with_margin.mdp.n_nodes == original.mdp.n_nodes
    assert np.allclose(with_margin.positions, original.positions)
