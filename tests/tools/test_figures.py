"""Committed figures cannot go stale: each records the SHA-256 digest of the committed table it
was drawn from (pipeline/app/figure_style.py), which must be the table's digest now; and
every committed figure is drawn at a paper width (3.5 or 7 in)."""

import shutil

import pytest
from PIL import Image

from pipeline.app.figure_style import COLUMN_IN, DPI, PAGE_IN, recorded_digests, table_digest
from pipeline.tools.redraw import FIGURES, RUN_FIGURES, redraw
from tests.conftest import ROOT

COMMITTED = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "results").rglob("*.png"))


def test_every_committed_figure_is_known():
    """A new figure under results/ is drawn from a table (FIGURES) or said to be a run's."""
    assert set(COMMITTED) == set(FIGURES) | set(RUN_FIGURES)


@pytest.mark.parametrize("figure", sorted(FIGURES))
def test_a_figure_records_the_digest_of_its_table_as_committed(figure):
    table = ROOT / FIGURES[figure][0]
    recorded = recorded_digests(ROOT / figure)
    assert list(recorded) == [table.name], f"{figure} records no digest of {table.name}"
    assert recorded[table.name] == table_digest(table), \
        f"{table.name} changed after {figure} was drawn: python -m pipeline.tools.redraw"


@pytest.mark.parametrize("figure", COMMITTED)
def test_committed_figures_have_a_paper_width(figure):
    with Image.open(ROOT / figure) as image:
        width = image.size[0]
    assert width in (round(COLUMN_IN * DPI), round(PAGE_IN * DPI)), figure


def test_redraw_draws_every_figure_from_its_table(tmp_path):
    for table, _ in FIGURES.values():
        (tmp_path / table).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / table, tmp_path / table)
    written = redraw(tmp_path)
    assert sorted(written) == sorted(tmp_path / f for f in FIGURES)
    for figure, (table, _) in FIGURES.items():
        assert recorded_digests(tmp_path / figure) == {
            (ROOT / table).name: table_digest(ROOT / table)}
        assert (tmp_path / figure).with_suffix(".pdf").read_bytes().startswith(b"%PDF")


def test_a_missing_or_damaged_table_is_one_line_naming_it(tmp_path):
    from pipeline.errors import PipelineError
    from pipeline.tools.redraw import FIGURES, redraw
    first_table = next(iter(FIGURES.values()))[0]
    with pytest.raises(PipelineError, match=f"{first_table} not found"):
        redraw(tmp_path)
    (tmp_path / first_table).parent.mkdir(parents=True)
    for text in ("garbage,,,\n", ""):
        (tmp_path / first_table).write_text(text)
        with pytest.raises(PipelineError, match=f"{first_table} cannot be drawn from"):
            redraw(tmp_path)
