"""One style for every figure the project draws (run and sweep figures, benchmark figures):
paper widths (3.5 in for one column, 7 in for two), 8-9 pt text at that size, colour-blind-safe
colours, and saving that records the SHA-256 digest of each table a figure was drawn from, so
a test can tell a figure that no longer matches its table (tests/tools/test_figures.py).

    with paper_style():
        fig = new_figure(COLUMN_IN, 2.4)
        ...
        save_figure(fig, path, tables=[csv_path])

matplotlib is imported inside the functions, never at import: the app imports this package
on every run, which needs no plotting.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from matplotlib.typing import RcKeyType

COLUMN_IN = 3.5  # one column of a two-column paper
PAGE_IN = 7.0  # both columns
DPI = 300  # PNG resolution: 1050 px for a column, 2100 px for a page
# Okabe & Ito's colour-blind-safe palette, in the order the series take them (yellow last:
# faint on white).
OKABE_ITO = {"blue": "#0072B2", "orange": "#E69F00", "green": "#009E73", "vermillion": "#D55E00",
             "purple": "#CC79A7", "sky": "#56B4E9", "black": "#000000", "yellow": "#F0E442"}
COLOURS = list(OKABE_ITO.values())
# Markers of series that are told apart by colour: apart also in grey print.
MARKERS = ["o", "s", "^", "D", "v", "P", "X", "*"]
REFERENCE = "0.35"  # grey of reference lines (a threshold, the initial weights' loss)
SOURCE_KEY = "Source-SHA256"  # PNG text chunk: "<table> <digest>" per line


def _rc() -> dict[RcKeyType, Any]:
    from cycler import cycler  # ships with matplotlib

    return {
        "font.size": 8, "axes.titlesize": 9, "axes.labelsize": 8, "xtick.labelsize": 8,
        "ytick.labelsize": 8, "legend.fontsize": 8, "legend.title_fontsize": 8,
        "figure.titlesize": 9, "axes.prop_cycle": cycler(color=COLOURS),
        "lines.linewidth": 1.2, "lines.markersize": 4, "axes.linewidth": 0.6,
        "xtick.major.width": 0.6, "ytick.major.width": 0.6, "xtick.minor.width": 0.4,
        "ytick.minor.width": 0.4, "grid.linewidth": 0.4, "grid.color": "0.85",
        "legend.frameon": False, "legend.handlelength": 1.8, "legend.borderaxespad": 0.3,
        "savefig.dpi": DPI,
        "pdf.fonttype": 42,  # TrueType in the PDF: text a journal's checker can read
    }


@contextmanager
def paper_style() -> Iterator[None]:
    """matplotlib's settings for the block (artists read them when created): draw and save
    inside it."""
    import matplotlib

    with matplotlib.rc_context(_rc()):
        yield


def new_figure(width_in: float, height_in: float) -> Any:
    """A figure of this size with constrained layout (no pyplot: its global state and import
    are not needed); saved at exactly this size (no tight bounding box)."""
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), layout="constrained")


def table_digest(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def save_figure(fig: Any, path: Path, tables: Sequence[Path] = ()) -> None:
    """PNG for the README and slides, PDF (vector) for papers. Each records the digest of
    every table it was drawn from (named relative to the figure's directory); the PDF has
    no creation date, so the same figure gives the same bytes."""
    path = Path(path)
    sources = "\n".join(f"{os.path.relpath(t, path.parent)} {table_digest(t)}" for t in tables)
    fig.savefig(path, dpi=DPI, metadata={SOURCE_KEY: sources} if sources else None)
    fig.savefig(path.with_suffix(".pdf"), metadata={
        "CreationDate": None, **({"Keywords": f"{SOURCE_KEY}\n{sources}"} if sources else {})})


def recorded_digests(png: Path) -> dict[str, str]:
    """Table path (relative to the figure's directory) -> the digest the PNG recorded when it
    was drawn; empty for a figure drawn from no table."""
    from PIL import Image

    with Image.open(png) as image:
        text = getattr(image, "text", {}).get(SOURCE_KEY, "")
    return dict(line.rsplit(" ", 1) for line in text.splitlines() if line)
