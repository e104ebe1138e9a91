"""The documentation does not go stale: the README's sample output is what the default run
prints, the generated pages are what the generator writes now, and the README keeps the
newcomer's five jobs near its top with links that resolve (pipeline.tools.docs)."""

import re

import pytest

from pipeline.tools import docs
from tests.conftest import ROOT

README = ROOT / "README.md"
REGENERATE = "regenerate with `make docs-gen` (python -m pipeline.tools.docs) and commit"

# The newcomer's five jobs, each with a command to copy, within the README's first lines.
JOB_COMMANDS = {
    "run the default experiment": ("make experiment", 'make experiment ARGS="'),
    "your own scene or ROS map": ("scene=file scene.path=", '"map":'),
    "your own demonstrations (file, ROS bag)": ("expert=file expert.path=", "expert.topic="),
    "a sweep and its table": ("make sweep EXP=quick", "make aggregate SWEEP="),
    "view a run offline": ("make view RUN=",),
}
README_MAX_LINES, JOBS_WITHIN = 300, 150


def test_readme_sample_output_is_what_the_default_run_prints(default_run):
    run_dir, metrics, printed = default_run
    expected = docs.sample_output(metrics)
    # the formatting the generator reuses is the one the run printed
    assert printed.strip().endswith(expected.replace(docs.SAMPLE_RUN_DIR, str(run_dir), 1))
    shown = docs.sample_block(README.read_text()).splitlines()
    expected_lines = expected.splitlines()
    assert [line.split()[:2] for line in shown] == [line.split()[:2] for line in expected_lines]
    for line, want in zip(shown, expected_lines, strict=True):
        if "stage seconds" in line:  # wall-clock: the stages must match, not the seconds
            assert re.sub(r"\d+\.\d+", "#", line) == re.sub(r"\d+\.\d+", "#", want), REGENERATE
        else:
            assert line == want, f"README.md's sample output is stale: {REGENERATE}"


@pytest.mark.parametrize("relative", list(docs.PAGES))
def test_generated_page_is_current(relative):
    with docs.quiet_logging():
        expected = docs.PAGES[relative]()
    assert (ROOT / relative).read_text() == expected, f"{relative} is stale: {REGENERATE}"


def test_readme_is_short_with_contents_and_the_five_jobs_near_the_top():
    lines = README.read_text().splitlines()
    assert len(lines) <= README_MAX_LINES
    assert any(re.fullmatch(r"#+ (Table of )?[Cc]ontents", line) for line in lines[:40])
    top = "\n".join(lines[:JOBS_WITHIN])
    for job, commands in JOB_COMMANDS.items():
        missing = [c for c in commands if c not in top]
        assert not missing, f"README.md: {job}: {missing} not in its first {JOBS_WITHIN} lines"


def test_readme_relative_links_resolve():
    text = README.read_text()
    targets = re.findall(r"\]\(([^)\s]+)\)", text) + re.findall(r'src="([^"]+)"', text)
    relative = [t.split("#")[0] for t in targets if not re.match(r"[a-z]+:|#", t)]
    assert relative, "README.md links to no file of the repository"
    missing = [t for t in relative if not (ROOT / t).exists()]
    assert not missing, f"README.md links to missing files: {missing}"


# -- hand-written pages quote no measured number -----------------------------------------------
# Measured numbers belong in committed tables under results/ (shown on the generated tables
# page); hand-typed ones in prose go stale. Parameters and defaults (0.5 m, 7.43 σ) are fine;
# a loss-like decimal (three or more decimals) or a count of seeds or runs is not.
HAND_WRITTEN = sorted({*ROOT.glob("docs/*.md"), ROOT / "docs/benchmarks/index.md"}
                      - {ROOT / p for p in docs.PAGES} - {ROOT / "docs/changelog.md"})
COUNT = r"(?:\d+|one|two|three|four|five|six|seven|eight|nine|ten)"
MEASURED = re.compile(
    r"(?<![\w.])\d*\.\d{3,}(?![\w.])"                                    # 0.0035, 1.046
    rf"|\b{COUNT} (?:out )?of {COUNT} (?:seeds|runs|cases|scenes|starts)\b"  # 4 of 10 seeds
    r"|\b\d+ ?/ ?\d+ (?:seeds|runs|on)\b", re.IGNORECASE)                # 7/10 runs, 9/10 on


def prose_lines(text: str):
    """(line number, line) of a Markdown page's prose: without fenced or indented code
    blocks, display maths ($$ ... $$), inline maths ($...$), inline code and HTML comments."""
    fence, maths = None, False
    for number, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if fence:
            fence = None if stripped.startswith(fence) else fence
            continue
        if stripped.startswith(("```", "~~~")):
            fence = stripped[:3]
            continue
        if maths or stripped.startswith("$$"):
            maths = not maths if stripped.count("$$") % 2 else maths
            continue
        if line.startswith(("    ", "\t")):
            continue
        line = re.sub(r"`[^`]*`|\$[^$]*\$|<!--.*?-->", " ", line)
        yield number, line


def measured_numbers(text: str) -> list[str]:
    return [f"{number}: {match.group(0)!r} in {line.strip()[:80]!r}"
            for number, line in prose_lines(text) for match in MEASURED.finditer(line)]


def test_measured_number_detector():
    found = measured_numbers("median 0.0035 over seeds\nin 4 of 10 seeds the test\n"
                             "9/10 on metropolis\nin two of five seeds\n")
    assert [f.split(":")[0] for f in found] == ["1", "2", "3", "4"]
    assert not measured_numbers(
        "a 0.5 m hinge, 7.43 σ, `birl.lr_level=0.001`, $\\gamma = 0.955$, 1.5× target\n"
        "\n    make experiment ARGS=\"x=0.0035\"\n\n```\n0.0123\n```\n$$\nx = 0.125\n$$\n")


@pytest.mark.parametrize("page", HAND_WRITTEN, ids=lambda p: str(p.relative_to(ROOT)))
def test_hand_written_page_quotes_no_measured_number(page):
    found = measured_numbers(page.read_text())
    assert not found, (f"{page.relative_to(ROOT)} quotes measured numbers in prose; point to "
                       f"the committed table under results/ instead:\n" + "\n".join(found))


def test_a_page_that_cannot_be_built_leaves_every_page_as_it_was(tmp_path, monkeypatch):
    """A damaged table was a traceback after the pages before it had been rewritten (the
    pages then disagreed with each other)."""
    from pipeline.errors import PipelineError
    from pipeline.tools import docs

    def damaged() -> str:
        raise AttributeError("'DataFrame' object has no attribute 'measurement'")
    monkeypatch.setattr(docs, "PROJECT_ROOT", tmp_path)
    monkeypatch.setattr(docs, "PAGES", {"docs/first.md": lambda: "new\n",
                                        "docs/second.md": damaged})
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "first.md").write_text("old\n")
    with pytest.raises(PipelineError, match="docs/second.md cannot be built: 'DataFrame'"):
        docs.write_pages(no_run=True)
    assert (tmp_path / "docs" / "first.md").read_text() == "old\n"
    assert sorted(p.name for p in (tmp_path / "docs").iterdir()) == ["first.md"]
