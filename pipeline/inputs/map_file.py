"""ROS map_server occupancy maps (DESIGN §3 "Obstacles and maps"): YAML + PGM/PNG image.

The YAML holds `image` (relative to the YAML's directory unless absolute), `resolution`
(m/cell), `origin` [x, y, yaw] (the lower-left pixel's corner), `negate` (0/1),
`occupied_thresh`, `free_thresh` and optional `mode` (trinary | scale | raw), as read by
ROS 1 map_server and Nav2's map_server:

- a pixel's shade s in [0, 1] is the mean of its red, green and blue values over their
  largest value (a grey pixel v: v/255, or v/65535 in a 16-bit image); in trinary mode an
  image with an alpha channel averages its alpha in as a fourth channel (opaque = 1), so
  even an opaque pixel of such an image reads lighter than its colour;
- trinary, scale: p = 1 − s (negate 0) or s (negate 1); free if p < free_thresh, occupied
  if p > occupied_thresh, otherwise unknown (in scale mode an intermediate occupancy, and a
  pixel that is not fully opaque is unknown);
- raw: round(255 s) is the occupancy in percent (negate and the thresholds are ignored, as
  in map_server): 0 is free, 1..100 occupied to that degree, anything above 100 unknown.

Only free cells are free: occupied, intermediate and unknown cells are obstacles. In scale
mode that is below free_thresh; map_server rounds a band half a per cent of the way above
it (map_saver's unknown grey 205 among them) to occupancy 0, which is kept an obstacle here.
Image row 0 is the map's top (largest y); the grid is flipped so its row 0 is the bottom.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from PIL import Image, UnidentifiedImageError

from pipeline.core.obstacles import OccupancyGrid
from pipeline.errors import PipelineError, file_kind

MODES = ("trinary", "scale", "raw")
YAW_NONE = 1e-6  # rad: an origin yaw this small is read as none
KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh", "mode")
_WARNED: set[tuple[str, tuple[str, ...]]] = set()  # (map, its unknown keys) warned about

log = logging.getLogger(__name__)


class _MapLoader(yaml.SafeLoader):
    """YAML as map_server's yaml-cpp reads a map file: `5e-2` is a number (PyYAML's YAML 1.1
    reads an exponent without a dot as a string), and a key given twice is refused (PyYAML
    keeps the last silently)."""

    def construct_mapping(self, node: Any, deep: bool = False) -> dict:
        seen: set = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {key!r} appears twice; which one is meant?",
                    key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep)


_MapLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$"), list("-+.0123456789"))


@dataclass(frozen=True)
class MapHeader:
    """A map_server YAML as read, with the image's size (its pixels not decoded yet)."""
    path: Path
    image: Path
    resolution: float
    origin: tuple[float, float]
    negate: int
    occupied_thresh: float
    free_thresh: float
    mode: str
    width: int  # pixels
    height: int

    @property
    def cells(self) -> int:
        return self.width * self.height

    def extent(self) -> tuple[float, float, float, float]:
        x0, y0 = self.origin
        return x0, y0, x0 + self.width * self.resolution, y0 + self.height * self.resolution


def _fail(path: Path) -> Callable[[str], PipelineError]:
    def fail(msg: str) -> PipelineError:
        return PipelineError(" ".join(f"map {path}: {msg}".split()))  # always one line
    return fail


def read_map_header(path: str | Path) -> MapHeader:
    """Read and check a map_server YAML and the size of its image, without decoding it: what
    the size guards need before the map is loaded."""
    path = Path(path)
    fail = _fail(path)
    if not path.exists():
        raise fail("file not found")
    kind = file_kind(path)
    if kind is not None:
        raise fail(f"is {kind}, not a map's YAML file")
    try:
        data = yaml.load(path.read_text(), Loader=_MapLoader)  # noqa: S506 (a safe loader)
    except UnicodeDecodeError:
        raise fail("is not a text file: give the map's YAML file (the one whose `image:` "
                   "names the picture), not the picture") from None
    except OSError as e:
        raise fail(f"cannot be read ({e})") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise fail(f"is not valid YAML{where} ({getattr(e, 'problem', None) or e})") from None
    if not isinstance(data, dict):
        raise fail(f"must be a YAML mapping of map_server keys, got {type(data).__name__}")

    unknown = [k for k in data if k not in KEYS]
    # other tools add keys of their own; map_server ignores them too. Said once: a run reads
    # the header in its checks, and again with the image
    if unknown and (str(path), tuple(unknown)) not in _WARNED:
        _WARNED.add((str(path), tuple(unknown)))
        log.warning("map %s: %s %s %s not map_server's (%s) and not used", path,
                    "keys" if len(unknown) > 1 else "key", ", ".join(repr(k) for k in unknown),
                    "are" if len(unknown) > 1 else "is", ", ".join(KEYS))

    def get(key: str) -> Any:
        if key not in data:
            raise fail(f"missing key '{key}'")
        return data[key]

    def number(key: str, ok: Callable[[float], bool], allowed: str) -> float:
        value = get(key)
        as_number = _as_number(value)
        if as_number is None or not ok(as_number):
            raise fail(f"key '{key}'={value!r} is not allowed (allowed: {allowed})")
        return as_number

    image = get("image")
    if not isinstance(image, str) or not image.strip():
        raise fail(f"key 'image'={image!r} must be an image file name")
    resolution = number("resolution", lambda v: v > 0, "a finite number > 0")
    given_origin = get("origin")
    given = [_as_number(v) for v in given_origin] \
        if isinstance(given_origin, list | tuple) else []
    origin = [v for v in given if v is not None]
    if not (len(given) == 3 and len(origin) == 3):
        raise fail(f"key 'origin'={given_origin!r} must be 3 finite numbers [x, y, yaw]")
    # map_saver writes the yaw it computes, e.g. -3.14e-16 for none: over 1 km, a yaw of
    # 1e-6 rad moves a cell by a millimetre
    if abs(origin[2]) > YAW_NONE:
        raise fail(f"origin yaw {given_origin[2]} is not supported; rotate the image instead")
    negate = get("negate")
    if isinstance(negate, str) and negate.strip() in ("0", "1"):  # yaml-cpp reads "1" as 1
        negate = int(negate)
    if negate not in (0, 1) or isinstance(negate, float | bool):  # yaml-cpp: true is no int
        raise fail(f"key 'negate'={negate!r} must be 0 or 1")
    occupied_thresh = number("occupied_thresh", lambda v: 0 <= v <= 1, "0..1")
    free_thresh = number("free_thresh", lambda v: 0 <= v <= 1, "0..1")
    if free_thresh > occupied_thresh:  # equal: no unknown band, as map_server reads it
        raise fail(f"key 'free_thresh'={free_thresh} must not be above "
                   f"occupied_thresh={occupied_thresh}")
    mode = data.get("mode", "trinary")
    if mode not in MODES:
        raise fail(f"key 'mode'={mode!r} is not one of {', '.join(MODES)}")
    image_path = Path(image)
    if not image_path.is_absolute():
        image_path = path.parent / image_path
    width, height = _image_size(image_path, fail)
    return MapHeader(path, image_path, resolution, (float(origin[0]), float(origin[1])),
                     int(negate), occupied_thresh, free_thresh, mode, width, height)


# map_saver writes unknown cells as grey 205; read with free_thresh above 50/255 = 0.196 (Nav2
# map_saver's default 0.25 among them) they are free, in Nav2's map_server as here.
MAP_SAVER_UNKNOWN = 205 / 255


def _warn_unknown_read_as_free(header: MapHeader, grey_free: np.ndarray) -> None:
    """One warning when map_saver's unknown grey reads as free: a building's unknown margin,
    seen through its windows, would then be floor (nodes, free area, an exported costmap's
    free cells)."""
    if header.negate or not grey_free.any():
        return
    log.warning("map %s: %d cells of map_saver's unknown grey (205) read as free, since "
                "free_thresh=%g is above 0.196 (Nav2's map_server reads them so too); if they "
                "are unknown space, set free_thresh: 0.196 in the YAML", header.path,
                int(grey_free.sum()), header.free_thresh)


def load_map(path: str | Path,
             check_cells: Callable[[MapHeader], None] | None = None) -> OccupancyGrid:
    """Read a map_server YAML and its image into an OccupancyGrid (True = obstacle);
    `check_cells(header)` runs before the image is decoded (the size guards)."""
    header = read_map_header(path)
    if check_cells is not None:
        check_cells(header)
    shade, opaque = _read_image(header.image, _fail(header.path),
                                alpha_is_a_channel=header.mode == "trinary")
    if header.mode == "raw":
        free = np.rint(shade * 255.0) == 0
    else:
        p = shade if header.negate else 1.0 - shade
        free = p < header.free_thresh
        if header.mode == "scale":
            free &= opaque
        _warn_unknown_read_as_free(header, free & (np.abs(shade - MAP_SAVER_UNKNOWN) < 1e-9))
    if not free.any():  # else the first person or start "stands inside an obstacle"
        read_as = ("a pixel is free only at 0 (mode: raw)" if header.mode == "raw" else
                   f"a pixel is free where its occupancy p = {'s' if header.negate else '1 - s'}"
                   f" (s its shade, 0 black to 1 white) is below free_thresh="
                   f"{header.free_thresh:g}")
        raise _fail(header.path)(f"no pixel of {header.image.name} reads as free: {read_as}; "
                                 f"check 'negate', 'free_thresh' and 'mode' against how the "
                                 "image was saved")
    return OccupancyGrid(np.ascontiguousarray(~free[::-1]), header.origin, header.resolution)


def _image_size(path: Path, fail: Callable[[str], PipelineError]) -> tuple[int, int]:
    """(width, height) in pixels from the image's header alone."""
    try:
        kind = file_kind(path)  # before open: opening a named pipe waits for a writer
        if kind is not None:
            raise fail(f"image {path} (key 'image') is {kind}, not an image")
        with _no_bomb_check(), Image.open(path) as img:
            width, height = img.size
    except FileNotFoundError:
        raise fail(f"image {path} (key 'image') not found") from None
    except (OSError, UnidentifiedImageError, ValueError) as e:
        raise fail(f"image {path} (key 'image') cannot be read ({e})") from None
    if width * height == 0:
        raise fail(f"image {path} (key 'image') is empty")
    return int(width), int(height)


@contextmanager
def _no_bomb_check() -> Iterator[None]:
    """Pillow's decompression-bomb guard off (its warning was two extra lines at 10,000² px):
    the map's size is checked against the memory available by the size guards instead."""
    limit = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = None
    try:
        yield
    finally:
        Image.MAX_IMAGE_PIXELS = limit


def _as_number(value: Any) -> float | None:
    """A finite number, also given as a quoted string (yaml-cpp, map_server's reader, converts
    "0.65" to a double as it converts 0.65); None otherwise."""
    if isinstance(value, str):
        try:
            value = float(value.strip())
        except ValueError:
            return None
    if not isinstance(value, int | float) or isinstance(value, bool) \
            or not math.isfinite(value):
        return None
    return float(value)


def _read_image(path: Path, fail: Callable[[str], PipelineError],
                alpha_is_a_channel: bool) -> tuple[np.ndarray, np.ndarray]:
    """Shade (H, W) in [0, 1] (image row 0 first) and opaque (H, W) bool of an image, as
    map_server reads them (the module docstring)."""
    try:
        with _no_bomb_check(), Image.open(path) as img:
            # a 16-bit PGM's maxval: 65535 read raw, else only in its decoder's arguments
            # (before loading)
            pgm_maxval: int | None = None
            if img.format == "PPM" and img.tile:
                tile = img.tile[0]
                if tile.codec_name not in ("ppm", "ppm_plain"):
                    pgm_maxval = 65535
                elif isinstance(tile.args, tuple):  # (rawmode, maxval); a plain bitmap's
                    pgm_maxval = tile.args[1]       # (P1, mode "1") is "1;I", no maxval
            img.load()
            has_alpha = "A" in img.getbands() or "transparency" in img.info
            top = 255  # the largest channel value
            total: np.ndarray
            if img.mode.startswith("I;16"):  # 16-bit grey (PNG)
                total, top = 3 * np.asarray(img, dtype=np.uint32), 65535
            elif img.mode == "I" and pgm_maxval is not None:
                # 16-bit grey PGM: Pillow scales it to 0..65535; the file's own values
                # (that scaling undone, exactly: it only rounds) over its maxval, as
                # map_server reads them
                raw = np.rint(np.asarray(img, dtype=float) * pgm_maxval / 65535)
                total, top = 3 * raw, pgm_maxval
            elif img.mode.startswith(("I", "F")):
                raise fail(f"image {path} (key 'image') has {img.mode} pixels; "
                           "save it as 8- or 16-bit grey or 8-bit colour (PGM/PNG)")
            elif img.mode in ("1", "L", "LA"):  # grey: red = green = blue
                total = 3 * np.asarray(img.convert("L"), dtype=np.uint16)
            else:  # colour (a palette too): the channels' mean, not a weighted luma
                total = np.asarray(img.convert("RGB")).sum(axis=-1, dtype=np.uint16)
            alpha = np.asarray(img.convert("RGBA"))[..., 3] if has_alpha else None
            opaque = np.ones(total.shape, dtype=bool) if alpha is None else alpha == 255
            channels = 3
            if alpha is not None and alpha_is_a_channel:
                total, channels = total + alpha, 4
            # in map_server's order of operations: the same doubles at a threshold
            shade = total / float(channels) / float(top)
    except FileNotFoundError:
        raise fail(f"image {path} (key 'image') not found") from None
    except (OSError, UnidentifiedImageError, ValueError) as e:
        raise fail(f"image {path} (key 'image') cannot be read ({e})") from None
    if shade.size == 0:
        raise fail(f"image {path} (key 'image') is empty")
    return shade, opaque
