"""The documentation is self-contained (issue 31, deliverable 7): every relative link and every backticked repo
path in README.md and docs/*.md resolves to a file of the clone, links into a page name one of its headings,
and docs/references.md cites every seed paper the code cites."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
# the clone's top-level folders and files: a backticked path that starts with one of them is a repo path
TOP_LEVEL = {
    ".ci", "bench", "config", "docs", "drivers", "examples", "procedures", "station", "tests", "web",
    "BENCHMARKS.md", "README.md", "pyproject.toml", "setup.py",
}  # fmt: skip
DOCS_CITING = [p for p in PAGES if p.parent.name == "docs" and p.name != "references.md"]
CODE_PACKAGES = ("station", "drivers", "procedures", "web")

FENCE = re.compile(r"^```.*?^```", re.S | re.M)
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
CODE_SPAN = re.compile(r"`([^`\s]+)`")
HEADING = re.compile(r"^#{1,6}\s+(.+?)\s*$", re.M)
EXPLICIT_ANCHOR = re.compile(r'<a id="([^"]+)"')
SEED_CITED = re.compile(r"\bseed (\d{3})\b", re.I)


def _prose(page: Path) -> str:
    """The page without its fenced code blocks (their backticks are code, not paths)."""
    return FENCE.sub("", page.read_text(encoding="utf-8"))


def _anchors(page: Path) -> set[str]:
    """The anchors a link may name: GitHub's slug of every heading and every explicit `<a id>`."""
    text = _prose(page)
    slugs = {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in HEADING.findall(text)}
    return slugs | set(EXPLICIT_ANCHOR.findall(text))


def _resolves(pattern: str) -> bool:
    """A repo path exists; a `<placeholder>` in it stands for any name (at least one must exist)."""
    glob = re.sub(r"<[^>]*>", "*", pattern.rstrip("/"))
    return any(ROOT.glob(glob)) if "*" in glob else (ROOT / glob).exists()


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_resolves_in_the_clone(page: Path) -> None:
    broken = []
    for target in LINK.findall(_prose(page)):
        if re.match(r"[a-z]+:", target):
            continue  # http(s), mailto: outside the clone by design
        path, _, anchor = target.partition("#")
        file = (page.parent / path).resolve() if path else page
        if not file.is_relative_to(ROOT) or not file.exists():
            broken.append(f"{target}: no such file in the clone")
        elif anchor and file.suffix == ".md" and anchor not in _anchors(file):
            broken.append(f"{target}: no heading with anchor #{anchor}")
    assert not broken, f"{page.name}: {broken}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_backticked_repo_path_exists(page: Path) -> None:
    spans = CODE_SPAN.findall(_prose(page))
    paths = [s for s in spans if s.split("/")[0] in TOP_LEVEL and ("/" in s or "." in s)]
    missing = [p for p in paths if not _resolves(p)]
    assert not missing, f"{page.name} names paths that are not in the clone: {missing}"


def test_the_checks_see_a_broken_link_and_a_missing_path(tmp_path: Path) -> None:
    assert _resolves("drivers/<device>/emulator.py")
    assert not _resolves("drivers/<device>/no_such_module.py")
    page = tmp_path / "page.md"
    page.write_text("# Seed 000: the core\n\n## Seed 001\n\n```\n# not a heading\n```\n", encoding="utf-8")
    assert _anchors(page) == {"seed-000-the-core", "seed-001"}


@pytest.mark.parametrize("page", DOCS_CITING, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_a_doc_that_names_a_seed_links_its_citation(page: Path) -> None:
    text = _prose(page)
    unlinked = sorted(n for n in set(SEED_CITED.findall(text)) if f"references.md#seed-{n}" not in text)
    assert not unlinked, f"{page.name} names seed(s) {unlinked} without a link to docs/references.md#seed-NNN"


def test_references_cite_every_seed_the_code_cites() -> None:
    cited = set()
    for package in CODE_PACKAGES:
        for module in (ROOT / package).rglob("*.py"):
            cited |= set(SEED_CITED.findall(module.read_text(encoding="utf-8")))
    assert cited >= {"000", "001", "002", "003", "004"}
    anchors = _anchors(ROOT / "docs" / "references.md")
    assert not {f"seed-{n}" for n in cited} - anchors, f"docs/references.md lacks {sorted(cited)}"


def test_references_quote_the_citations_a_certificate_prints() -> None:
    from procedures.common.papers import PAPERS

    text = " ".join(_prose(ROOT / "docs" / "references.md").split())
    for n, citation in PAPERS.items():
        section = text.split(f"## Seed {n} ")[1].split("## Seed")[0]
        assert f"A certificate cites it as: {citation}" in section, n
