"""What issue 10 asks to be shown: each obstacle source blocks a wall at the map's
resolution, the same polylines learn the same reward from JSON, CSV and a ROS bag, and a
transferred reward scores the same whether deployed with birl=fixed or scored with
evaluate.transfer_scenes."""

import json

import numpy as np
import pytest
from PIL import Image

from pipeline.core.roadmap import segments_feasible
from pipeline.inputs.scene_file import load_scene_file
from tests.conftest import run_in_process
from tests.inputs.test_recorded import write_bag
from tests.pipeline.test_obstacle_scenes import DRIVE_0, DRIVE_2

FAST = ("graph=small", "birl.n_iterations=3")
ROOM = {"x_min": 0.0, "y_min": 0.0, "x_max": 4.0, "y_max": 2.0}
# A wall 0.1 m thick at x = 2 (cells [1.95, 2.05) at 5 cm), floor to ceiling.


def _scene(tmp_path, **extra) -> dict:
    data = {"name": "wall", "persons": [], "relations": [], "starts": [[0.5, 1.0]],
            "goal": [1.5, 1.0], "robot_radius": 0.1, **extra}
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(data))
    return load_scene_file(path)


def _map(tmp_path, suffix: str, negate: int):
    """A 4 x 2 m map at 5 cm with the wall at x = 2; free pixels white (black when negated)."""
    free, wall = (0, 255) if negate else (255, 0)
    pixels = np.full((40, 80), free, np.uint8)
    pixels[:, 39:41] = wall  # columns 39, 40: x in [1.95, 2.05)
    Image.fromarray(pixels).save(tmp_path / f"map{suffix}")
    (tmp_path / "map.yaml").write_text(
        f"image: map{suffix}\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: {negate}\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    return _scene(tmp_path, map="map.yaml")


@pytest.mark.parametrize("source", ["polygon", "png", "pgm_negate"])
def test_each_obstacle_source_blocks_the_wall_at_its_resolution(tmp_path, source):
    if source == "polygon":
        scene = _scene(tmp_path, room=ROOM, obstacles=[[[1.95, 0.0], [2.05, 0.0], [2.05, 2.0],
                                                        [1.95, 2.0]]])
    else:
        scene = _map(tmp_path, ".png" if source == "png" else ".pgm", int(source != "png"))
    a = np.array([[1.0, 1.0], [1.0, 0.5], [1.0, 1.0], [2.6, 0.3]])
    b = np.array([[3.0, 1.0], [1.8, 0.5], [1.84, 1.5], [3.5, 1.7]])
    # through the wall; beside it (0.15 m > r away); 0.11 m from it (just clear); other side
    expected = [False, True, True, True]
    assert segments_feasible(scene, a, b).tolist() == expected
    # one cell (5 cm) closer than robot_radius to the wall is a collision
    assert not segments_feasible(scene, np.array([[1.0, 1.0]]), np.array([[1.88, 1.0]]))[0]


def test_the_same_polylines_learn_the_same_weights_from_json_csv_and_a_bag(tmp_path):
    polylines = [DRIVE_0, DRIVE_2]
    json_file = tmp_path / "demos.json"
    json_file.write_text(json.dumps({"trajectories": [p.tolist() for p in polylines]}))
    csv_file = tmp_path / "demos.csv"
    csv_file.write_text("trajectory,x,y\n" + "".join(
        f"{k},{x!r},{y!r}\n" for k, p in enumerate(polylines) for x, y in p.tolist()))
    bag = write_bag(tmp_path / "bag", {"/plan": ("nav_msgs/msg/Path", polylines)})
    weights = {}
    for name, path in [("json", json_file), ("csv", csv_file), ("bag", bag)]:
        m, _ = run_in_process(tmp_path / name, "expert=file", f"expert.path={path}", *FAST)
        weights[name] = np.array([m[k] for k in sorted(m) if k.startswith("weight_")])
    np.testing.assert_allclose(weights["csv"], weights["json"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(weights["bag"], weights["json"], rtol=0, atol=1e-9)


def test_fixed_deployment_equals_the_transfer_score(tmp_path):
    office = "data/scenes/office.json"
    # learned on metropolis (the default scene), scored on the office map
    learned, _ = run_in_process(tmp_path / "learn", *FAST, f"evaluate.transfer_scenes=[{office}]")
    deployed, _ = run_in_process(tmp_path / "deploy", "scene=office", "graph=small",
                                 "birl=fixed", f"birl.from_run={tmp_path / 'learn'}")
    assert deployed["policy_loss_ref"] == learned["transfer_office_policy_loss"]
    assert deployed["policy_loss_norm"] == learned["transfer_office_policy_loss_norm"]
    assert deployed["ref_success"] == learned["transfer_office_success"]
