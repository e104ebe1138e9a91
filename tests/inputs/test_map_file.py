"""ROS map_server map files (pipeline/inputs/map_file.py): trinary, scale and raw modes,
negate, the image's orientation and origin, one line naming the file and key of a bad map,
and the shipped office map."""

import json

import numpy as np
import pytest
from PIL import Image

from pipeline.core.obstacles import ObstacleMap
from pipeline.errors import PipelineError
from pipeline.inputs.map_file import load_map, read_map_header
from tests.conftest import OFFICE_SCENE

# ---------------------------------------------------------------------------- map_server files

def _write_map(directory, pixels, fmt="pgm", **fields):
    """map.yaml + map.{fmt} in `directory`; `fields` override the YAML's values (None: drop)."""
    Image.fromarray(np.asarray(pixels, dtype=np.uint8)).save(directory / f"map.{fmt}")
    values = {"image": f"map.{fmt}", "resolution": 0.1, "origin": [0.0, 0.0, 0.0], "negate": 0,
              "occupied_thresh": 0.65, "free_thresh": 0.196, **fields}
    lines = [f"{key}: {json.dumps(value)}" for key, value in values.items() if value is not None]
    path = directory / "map.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def _free_in_image_order(grid):
    return ~grid.occupied[::-1]


GREYS = [[0, 50, 100, 150], [205, 206, 254, 255]]


@pytest.mark.parametrize("fmt", ["pgm", "png"])
def test_trinary_classification_follows_map_server(tmp_path, fmt):
    # p = (255 - v)/255: map_saver's unknown 205 -> 0.19608 is just above free_thresh 0.196,
    # 206 -> 0.19216 just below; 0 -> 1.0 occupied; 50, 100 (p 0.80, 0.61) occupied/unknown
    grid = load_map(_write_map(tmp_path, GREYS, fmt))
    assert _free_in_image_order(grid).tolist() == [[False] * 4, [False, True, True, True]]
    grid = load_map(_write_map(tmp_path, GREYS, fmt, free_thresh=0.5))  # 150 -> 0.41
    assert _free_in_image_order(grid).tolist() == [[False, False, False, True], [True] * 4]


def test_map_savers_unknown_grey_read_as_free_is_said(tmp_path, caplog):
    """Nav2's map_saver writes unknown as grey 205 and free_thresh 0.25: reloaded, p =
    50/255 = 0.196 < 0.25 reads as free (in Nav2's map_server too), and a building's unknown
    margin became floor without a word. It is still read so, and said once."""
    pixels = [[254, 254, 205, 205], [254, 0, 205, 205]]
    with caplog.at_level("WARNING"):
        grid = load_map(_write_map(tmp_path, pixels, free_thresh=0.25))
    assert _free_in_image_order(grid).tolist() == [[True] * 4, [True, False, True, True]]
    assert caplog.text.count("map_saver's unknown grey (205)") == 1
    assert "4 cells of map_saver's unknown grey (205) read as free, since free_thresh=0.25" \
        in caplog.text and "set free_thresh: 0.196" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING"):  # map_saver's ROS 1 threshold: unknown, nothing to say
        grid = load_map(_write_map(tmp_path, pixels, free_thresh=0.196))
    assert _free_in_image_order(grid).tolist() == [[True, True, False, False],
                                                   [True, False, False, False]]
    assert "unknown grey" not in caplog.text


def test_negate_inverts_the_grey_values(tmp_path):
    grid = load_map(_write_map(tmp_path, GREYS, negate=1))  # p = v/255: 50 -> 0.19608
    assert _free_in_image_order(grid).tolist() == [[True, False, False, False], [False] * 4]


def test_raw_mode_reads_percentages_and_ignores_negate_and_thresholds(tmp_path):
    """map_server's raw mode: the grey value is the occupancy (0..100, above: unknown), with
    no thresholds; only occupancy 0 is free."""
    pixels = [[0, 1, 19, 20], [50, 100, 101, 255]]
    for negate, free_thresh in ((0, 0.196), (1, 0.196), (0, 0.5)):
        grid = load_map(_write_map(tmp_path, pixels, mode="raw", negate=negate,
                                   free_thresh=free_thresh))
        assert _free_in_image_order(grid).tolist() == [[True, False, False, False],
                                                       [False] * 4]


@pytest.mark.parametrize("fields, says", [
    ({"negate": 1}, r"occupancy p = s \(s its shade, 0 black to 1 white\) is below "
                    r"free_thresh=0\.196"),
    ({"mode": "raw"}, r"a pixel is free only at 0 \(mode: raw\)"),
    ({"free_thresh": 0.01}, r"p = 1 - s .* below free_thresh=0\.01;"),
])
def test_a_map_with_no_free_pixel_says_how_its_pixels_were_read(tmp_path, fields, says):
    """A normal map read with negate=1 (or raw, or a free grey above free_thresh) has no free
    pixel; the run said only that the first person 'stands inside an obstacle'."""
    light = [[240, 235, 250], [230, 245, 240]]  # free white and light greys, no black
    load_map(_write_map(tmp_path, light))  # as saved: free
    with pytest.raises(PipelineError, match=r"map .*map\.yaml: no pixel of map\.pgm reads as "
                       r"free: .*" + says + r".*check 'negate', 'free_thresh' and 'mode'"):
        load_map(_write_map(tmp_path, light, **fields))


def test_colour_pixels_are_the_mean_of_their_channels_not_a_luma(tmp_path):
    """map_server averages red, green and blue. (0, 255, 255): mean 170, p = 0.333, unknown
    with the default thresholds; its luma (179) would give p = 0.298, unknown too, so the
    thresholds are set between: free_thresh 0.32 frees the luma only."""
    rgb = np.array([[[0, 255, 255], [255, 255, 255], [0, 0, 0]]], dtype=np.uint8)
    Image.fromarray(rgb, "RGB").save(tmp_path / "map.png")
    path = _write_map(tmp_path, np.zeros((1, 3)), "pgm", image="map.png", free_thresh=0.32)
    assert _free_in_image_order(load_map(path)).tolist() == [[False, True, False]]
    path = _write_map(tmp_path, np.zeros((1, 3)), "pgm", image="map.png", free_thresh=0.34)
    assert _free_in_image_order(load_map(path)).tolist() == [[True, True, False]]


def test_trinary_mode_averages_alpha_in_as_a_fourth_channel(tmp_path):
    """map_server (trinary, an image with alpha): shade = (r + g + b + a) / 4 / 255. An opaque
    unknown grey 205 then reads (615 + 255) / 4 = 217.5: p = 0.147 < 0.196, free; and opaque
    black (0 + 255) / 4: p = 0.75, occupied; a transparent white pixel p = 0.25, unknown."""
    grey = np.array([[205, 0, 255]], dtype=np.uint8)
    alpha = np.array([[255, 255, 0]], dtype=np.uint8)
    Image.fromarray(np.stack([grey, alpha], axis=-1), "LA").save(tmp_path / "map.png")
    path = _write_map(tmp_path, np.zeros((1, 3)), "pgm", image="map.png")
    assert _free_in_image_order(load_map(path)).tolist() == [[True, False, False]]
    path = _write_map(tmp_path, np.zeros((1, 3)), "pgm", image="map.png", mode="raw")
    # raw: the colour's mean only (205, 0, 255): occupancy 205, 0, 255 -> only 0 free
    assert _free_in_image_order(load_map(path)).tolist() == [[False, True, False]]


def test_16_bit_grey_images_are_read_at_their_depth(tmp_path):
    """A 16-bit PNG: shade v / 65535. 52000 -> p = 0.2065 (not free at 0.196, free at 0.21)."""
    values = np.array([[65535, 52000, 0]], dtype=np.uint16)
    Image.fromarray(values).save(tmp_path / "map.png")  # mode I;16
    path = _write_map(tmp_path, np.zeros((1, 3)), "pgm", image="map.png")
    assert _free_in_image_order(load_map(path)).tolist() == [[True, False, False]]
    path = _write_map(tmp_path, np.zeros((1, 3)), "pgm", image="map.png", free_thresh=0.21)
    assert _free_in_image_order(load_map(path)).tolist() == [[True, True, False]]


@pytest.mark.parametrize("header, body", [
    (b"P5\n3 1\n65535\n", np.array([65535, 52000, 0], ">u2").tobytes()),
    (b"P2\n3 1\n1000\n", b"1000 793 0\n"),  # ASCII, maxval 1000: 793 -> p = 0.207
])
def test_16_bit_pgm_is_read_at_its_maxval(tmp_path, header, body):
    """A PGM with maxval above 255 (Pillow opens it as 32-bit integers scaled to 0..65535):
    shade v / maxval, as map_server reads it."""
    (tmp_path / "map16.pgm").write_bytes(header + body)
    path = _write_map(tmp_path, np.zeros((1, 3)), "pgm", image="map16.pgm")
    assert _free_in_image_order(load_map(path)).tolist() == [[True, False, False]]
    path = _write_map(tmp_path, np.zeros((1, 3)), "pgm", image="map16.pgm", free_thresh=0.21)
    assert _free_in_image_order(load_map(path)).tolist() == [[True, True, False]]


def test_scale_mode_treats_translucent_pixels_as_unknown(tmp_path):
    grey = np.array([[254, 254, 0]], dtype=np.uint8)
    alpha = np.array([[255, 128, 255]], dtype=np.uint8)
    path = _write_map(tmp_path, grey, "png", mode="scale")
    assert _free_in_image_order(load_map(path)).tolist() == [[True, True, False]]
    Image.fromarray(np.stack([grey, alpha], axis=-1), "LA").save(tmp_path / "map.png")
    assert _free_in_image_order(load_map(path)).tolist() == [[True, False, False]]
    path.write_text(path.read_text().replace("scale", "trinary"))
    assert _free_in_image_order(load_map(path)).tolist() == [[True, True, False]]


def test_image_row_zero_is_the_top_and_the_origin_shifts_the_map(tmp_path, monkeypatch):
    pixels = np.full((3, 4), 254)
    pixels[0, 0] = 0  # image row 0, column 0: the map's top-left cell
    (tmp_path / "maps").mkdir()
    path = _write_map(tmp_path / "maps", pixels, "png", origin=[-1.0, 2.0, 0.0])
    monkeypatch.chdir(tmp_path)  # the image is found next to the YAML, not in the cwd
    grid = load_map("maps/map.yaml")
    assert grid.extent() == pytest.approx((-1.0, 2.0, -0.6, 2.3))
    assert grid.occupied.sum() == 1 and grid.occupied[2, 0]
    obstacles = ObstacleMap(grid)
    assert obstacles.points_free(np.array([[-0.95, 2.25], [-0.95, 2.05], [-0.65, 2.25]]),
                                 0.0).tolist() == [False, True, True]
    # an absolute image path works too
    path.write_text(path.read_text().replace("image: \"map.png\"",
                                             f"image: \"{tmp_path / 'maps' / 'map.png'}\""))
    assert (load_map(path).occupied == grid.occupied).all()


def test_what_map_server_reads_is_read_quoted_numbers_no_yaw_and_no_unknown_band(tmp_path):
    """yaml-cpp converts "0.65" as it converts 0.65; map_saver writes yaws like -3.14e-16 for
    none; free_thresh = occupied_thresh leaves no unknown band. map_server loads all three."""
    plain = load_map(_write_map(tmp_path, GREYS))
    quoted = load_map(_write_map(tmp_path, GREYS, resolution="0.1", free_thresh="0.196",
                                 occupied_thresh=" 0.65", origin=["0", 0.0, "-3.14e-16"],
                                 negate="0"))
    assert (quoted.origin, quoted.resolution) == (plain.origin, plain.resolution)
    np.testing.assert_array_equal(quoted.occupied, plain.occupied)
    no_band = load_map(_write_map(tmp_path, GREYS, free_thresh=0.5, occupied_thresh=0.5))
    # p = (255 - v)/255 < 0.5 is free: 150 (0.41), 205, 206, 254, 255
    assert _free_in_image_order(no_band).tolist() == [[False, False, False, True], [True] * 4]


def test_a_threshold_is_a_strict_bound_on_exact_shades(tmp_path):
    """free if p < free_thresh: with negate=1, p = v/255, and 51/255 is the double 0.2, the
    threshold itself: not free; 50 (p = 0.196) is."""
    grid = load_map(_write_map(tmp_path, [[51, 50, 255]], negate=1, free_thresh=0.2))
    assert _free_in_image_order(grid).tolist() == [[False, True, False]]


def test_a_16_bit_pgm_at_a_threshold_reads_the_files_own_values(tmp_path):
    """maxval 1000: 793 is shade 0.793 as map_server computes it, p = 1 - 0.793 just below
    free_thresh=0.207: free. (Pillow's 0..65535 scaling, 51969, not undone exactly, reads
    792.996: p above the threshold, not free.)"""
    (tmp_path / "map16.pgm").write_bytes(b"P2\n3 1\n1000\n793 0 1000\n")
    path = _write_map(tmp_path, np.zeros((1, 3)), "pgm", image="map16.pgm", free_thresh=0.207)
    assert _free_in_image_order(load_map(path)).tolist() == [[True, False, True]]


def test_raw_mode_rounds_a_16_bit_shade_to_a_percentage(tmp_path):
    """raw: round(255 s) is the occupancy; in a 16-bit image 128 is 255·128/65535 = 0.498:
    occupancy 0, free; 129 (0.502) is 1, occupied."""
    values = np.array([[0, 128, 129, 65535]], dtype=np.uint16)
    Image.fromarray(values).save(tmp_path / "map.png")  # mode I;16
    path = _write_map(tmp_path, np.zeros((1, 4)), "pgm", image="map.png", mode="raw")
    assert _free_in_image_order(load_map(path)).tolist() == [[True, True, False, False]]


def test_the_header_gives_the_maps_size_and_extent_without_the_pixels(tmp_path):
    """GREYS is 4 pixels wide, 2 high, at 0.1 m from (-1, 2): x -1..-0.6, y 2..2.2."""
    header = read_map_header(_write_map(tmp_path, GREYS, origin=[-1.0, 2.0, 0.0]))
    assert (header.width, header.height, header.cells) == (4, 2, 8)
    assert header.extent() == pytest.approx((-1.0, 2.0, -0.6, 2.2))
    assert header.extent() == pytest.approx(load_map(header.path).extent())


@pytest.mark.parametrize("fields, needle", [
    ({"resolution": None}, "missing key 'resolution'"),
    ({"image": None}, "missing key 'image'"),
    ({"origin": None}, "missing key 'origin'"),
    ({"negate": None}, "missing key 'negate'"),
    ({"occupied_thresh": None}, "missing key 'occupied_thresh'"),
    ({"free_thresh": None}, "missing key 'free_thresh'"),
    ({"resolution": 0}, "key 'resolution'=0"),
    ({"resolution": -0.05}, "key 'resolution'=-0.05"),
    ({"resolution": "fine"}, "key 'resolution'='fine'"),
    ({"origin": [0.0, 0.0]}, "key 'origin'"),
    ({"origin": [0.0, "a", 0.0]}, "key 'origin'"),
    ({"origin": [0.0, 0.0, 0.3]}, "origin yaw 0.3 is not supported; rotate the image instead"),
    ({"negate": 2}, "key 'negate'=2"),
    ({"negate": True}, "key 'negate'=True must be 0 or 1"),  # map_server (yaml-cpp) refuses it
    ({"occupied_thresh": 1.5}, "key 'occupied_thresh'=1.5"),
    ({"free_thresh": -0.1}, "key 'free_thresh'=-0.1"),
    ({"free_thresh": 0.7}, "key 'free_thresh'=0.7 must not be above occupied_thresh=0.65"),
    ({"origin": [0.0, 0.0, 2e-6]}, "origin yaw 2e-06 is not supported"),
    ({"origin": [0.0, 0.0, -0.3]}, "origin yaw -0.3 is not supported"),  # clockwise too
    ({"resolution": True}, "key 'resolution'=True is not allowed"),  # a YAML bool: no number
    ({"mode": "fancy"}, "key 'mode'='fancy' is not one of trinary, scale, raw"),
    ({"image": "missing.pgm"}, "missing.pgm (key 'image') not found"),
    ({"image": "."}, "(key 'image') is a directory, not an image"),
    ({"image": "broken.pgm"}, "broken.pgm (key 'image') cannot be read"),
    ({"image": 3}, "key 'image'=3"),
])
def test_a_malformed_map_is_one_line_naming_file_and_key(tmp_path, fields, needle):
    path = _write_map(tmp_path, GREYS, **fields)
    (tmp_path / "broken.pgm").write_bytes(b"P5\n4 2\n255\nshort\n")
    with pytest.raises(PipelineError) as caught:
        load_map(path)
    message = str(caught.value)
    assert "\n" not in message and message.startswith(f"map {path}: ")
    assert needle in message


@pytest.mark.parametrize("text, needle", [
    (None, "file not found"),
    ("- just\n- a list\n", "must be a YAML mapping"),
    ("image: [unclosed\n", "is not valid YAML at line"),
    ("image: m.pgm\nresolution: 0.05\nresolution: 0.1\n",
     "is not valid YAML at line 3 (key 'resolution' appears twice; which one is meant?)"),
])
def test_an_unreadable_yaml_is_one_line_naming_the_file(tmp_path, text, needle):
    path = tmp_path / "map.yaml"
    if text is not None:
        path.write_text(text)
    with pytest.raises(PipelineError) as caught:
        load_map(path)
    message = str(caught.value)
    assert "\n" not in message and str(path) in message and needle in message


@pytest.mark.parametrize("written, resolution", [("5e-2", 0.05), ("1E-1", 0.1), ("0.05", 0.05),
                                                 ("1.5e-1", 0.15)])
def test_an_exponent_without_a_dot_is_a_number_as_map_server_reads_it(tmp_path, written,
                                                                       resolution):
    path = _write_map(tmp_path, GREYS)
    path.write_text(path.read_text().replace("resolution: 0.1", f"resolution: {written}"))
    assert load_map(path).resolution == resolution


def test_keys_map_server_does_not_know_are_one_warning(tmp_path, caplog):
    path = _write_map(tmp_path, GREYS, comment="drawn by hand")
    with caplog.at_level("WARNING"):
        load_map(path)
        read_map_header(path)  # a run reads the header in its checks too: still one warning
    assert "key 'comment' is not map_server's" in caplog.text
    assert caplog.text.count("not map_server's") == 1


# ---------------------------------------------------------------------------- shipped office

def test_the_office_scene_has_free_connected_starts_and_goal():
    scene = json.loads(OFFICE_SCENE.read_text())
    assert "room" not in scene and scene["robot_radius"] == 0.2
    grid = load_map(OFFICE_SCENE.parent / scene["map"])
    assert grid.extent() == pytest.approx((0.0, 0.0, 20.0, 14.0)) and grid.shape == (280, 400)
    obstacles = ObstacleMap(grid)
    points = np.array(scene["starts"] + [scene["goal"]], dtype=float)
    persons = np.array([[p["x"], p["y"]] for p in scene["persons"]])
    assert obstacles.points_free(points, 0.3).all()
    assert obstacles.points_free(persons, 0.25).all()
    blocked = obstacles.blocked_disks(persons, 0.25)
    assert obstacles.reachable(points[-1], points, 0.2, blocked).all()
    # the doors are 1 m wide: a robot wider than a door stays in its room
    assert not obstacles.reachable(points[-1], points[:-1], 0.55).any()
    ids = {p["id"] for p in scene["persons"]}
    assert all(a in ids and b in ids for a, b in scene["relations"])


def test_the_picture_given_for_the_yaml_is_named_as_such(tmp_path):
    _write_map(tmp_path, GREYS)
    with pytest.raises(PipelineError, match=r"map .*map\.pgm: is not a text file: give the "
                                            r"map's YAML file .* not the picture"):
        load_map(tmp_path / "map.pgm")
