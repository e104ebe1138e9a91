"""The run's provenance (pipeline/app/context.py): the source tree's git state."""

import os
import subprocess

from pipeline.app import context


def git(repo, *args):
    subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], cwd=repo,
                   check=True, capture_output=True)


def test_reading_the_tree_state_writes_nothing_into_the_source_tree(tmp_path, monkeypatch):
    """`git status` refreshes a stale index: it wrote .git/index (through index.lock) in the
    source tree on every run, outside the run dir, and could collide with the user's own
    git commands ("index.lock exists")."""
    git(tmp_path, "init", "-q")
    (tmp_path / "a.txt").write_text("a\n")
    git(tmp_path, "add", "a.txt")
    git(tmp_path, "commit", "-q", "-m", "a")
    stamp = (tmp_path / "a.txt").stat().st_mtime_ns + 5_000_000_000
    os.utime(tmp_path / "a.txt", ns=(stamp, stamp))  # same content, newer: the index is stale
    index = tmp_path / ".git" / "index"
    before = index.stat().st_mtime_ns, index.read_bytes()
    monkeypatch.setattr(context, "PROJECT_ROOT", tmp_path)
    for cached in (context.git_revision, context.git_tree_state):
        cached.cache_clear()
    try:
        assert context.git_tree_state() == "clean"
        (tmp_path / "a.txt").write_text("b\n")
        context.git_tree_state.cache_clear()
        assert context.git_tree_state() == "modified"
    finally:
        for cached in (context.git_revision, context.git_tree_state):
            cached.cache_clear()
    assert (index.stat().st_mtime_ns, index.read_bytes()) == before
