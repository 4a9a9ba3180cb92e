"""The README is a short front door: its length, its test command (CI's), its links into docs/,
no text dated by "session", and `tron1 --help` listing the commands in the order a user meets them."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from conftest import tron1

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
ORDER = [
    "train",
    "eval",
    "push-test",
    "export-onnx",
    "deploy-sim",
    "deploy-robot",
    "sim-robot",
    "report",
    "bench",
]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = heading.strip().lower().replace("`", "")
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    fenced, out = False, set()
    for line in path.read_text().splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and line.startswith("#"):
            out.add(_slug(line.lstrip("#")))
    return out


def test_the_readme_is_at_most_350_lines():
    assert len(README.read_text().splitlines()) <= 350


def test_the_readme_test_command_is_what_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    blocks = re.findall(r"```bash\n(.*?)```", README.read_text(), re.S)
    assert any(b.strip() == ci for b in blocks), "the README's test command differs from .ci/run"


@pytest.mark.parametrize("doc", [README, *DOCS], ids=lambda p: p.name)
def test_links_resolve(doc):
    """Every relative link names a file that exists, and an anchor one of its headings."""
    for target in LINK.findall(doc.read_text()):
        if re.match(r"[a-z]+://", target):
            continue
        name, _, anchor = target.partition("#")
        path = (doc.parent / name).resolve() if name else doc
        assert path.exists(), f"{doc.name}: {target}"
        if anchor and path.suffix == ".md":
            assert anchor in _anchors(path), f"{doc.name}: {target}"


def test_the_readme_links_every_doc():
    text = README.read_text()
    assert DOCS and all(f"docs/{d.name}" in text for d in DOCS)


def test_nothing_is_dated_by_session():
    pattern = re.compile(r"sessions? \d|a later\s+session|resumed\s+sessions", re.I)
    for doc in [README, ROOT / "CHANGELOG.md", *DOCS]:
        hits = [line for line in doc.read_text().splitlines() if pattern.search(line)]
        assert not hits, f"{doc.name}: {hits}"


def test_the_changelog_groups_by_date():
    heads = re.findall(r"^## (.+)$", (ROOT / "CHANGELOG.md").read_text(), re.M)
    assert heads[0] == "[Unreleased]"
    dates = heads[1:]
    assert dates and all(re.fullmatch(r"\d{4}-\d{2}-\d{2}", d) for d in dates)
    assert dates == sorted(dates, reverse=True)


def test_help_lists_the_commands_in_the_order_a_user_meets_them():
    r = tron1("--help", env={"COLUMNS": "100"}, timeout=120)
    assert r.returncode == 0, r.stderr
    listed = re.findall(r"^│ ([a-z][a-z-]+) ", r.stdout, re.M)
    assert listed == ORDER, listed
    table = README.read_text().split("## Commands", 1)[1]
    assert [c for c in re.findall(r"^\| `([a-z-]+)` \|", table, re.M)] == ORDER
