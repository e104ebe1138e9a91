"""Demonstration files as the demos stage loads them (pipeline/inputs/demo_file.py): JSON
trajectories matched to the scene's starts and goal, one line naming what is wrong."""

import json

import numpy as np
import pytest

from pipeline.core.features import FeatureModel
from pipeline.errors import PipelineError
from pipeline.inputs.demo_file import load_demo_file
from tests.inputs.conftest import refused


def test_demo_file_loading(tmp_path, metropolis):
    fm = FeatureModel.from_scene(metropolis)
    path = tmp_path / "demos.json"
    path.write_text(json.dumps({"scene": "metropolis", "trajectories": [
        [[0.5, 0.5], [0.5, 0.5], [1.0, 8.0], [5.5, 9.0]]]}))
    [d] = load_demo_file(path, metropolis, fm, speed=1.0)
    assert d.start_index == 0 and len(d.points) == 3  # repeated point dropped
    path.write_text(json.dumps({"trajectories": [[[0.5, 0.5], [3.0, 3.0]]]}))
    with pytest.raises(PipelineError, match="trajectory 0 ends .* from the goal"):
        load_demo_file(path, metropolis, fm, speed=1.0)
    path.write_text(json.dumps({"trajectories": [[[0.5, 0.5], [15.0, 9.0]]]}))
    with pytest.raises(PipelineError, match="trajectory 0 leaves the room"):
        load_demo_file(path, metropolis, fm, speed=1.0)


def test_json_demonstration_far_from_every_start_is_refused(tmp_path, metropolis):
    fm = FeatureModel.from_scene(metropolis)
    path = tmp_path / "far.json"
    path.write_text(json.dumps({"trajectories": [[[0.5, 0.5], [5.5, 9.0]],
                                                 [[9.5, 9.5], [6.0, 9.0], [5.5, 9.0]]]}))
    refused(rf"demonstration file {path}: trajectory 1 starts 4\.41 m from the nearest start "
            r"\(8\.5, 5\.2\); at most 1 m \(expert\.start_radius\)",
            load_demo_file, path, metropolis, fm, 1.0)
    [d0, d1] = load_demo_file(path, metropolis, fm, 1.0, start_radius=5.0)
    assert d1.start_index == 3 and np.array_equal(d1.points, [[9.5, 9.5], [6.0, 9.0], [5.5, 9.0]])
    path.write_text(json.dumps({"trajectories": [[[0.5, 0.5], [float("nan"), 9.0]]]}))
    refused(r"trajectories\[0\]\[1\]\[0\]: NaN is not a finite number", load_demo_file, path,
            metropolis, fm, 1.0)
