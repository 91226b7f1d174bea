"""The README and the pages of docs/ hold together: every relative link (and image) points to
a file of the repository, every ``#anchor`` to a heading of its page; the README stays one page."""

from __future__ import annotations

import itertools
import re
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest
from markdown_it import MarkdownIt
from markdown_it.token import Token

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]  # reached from the README
CHECKED = [*PAGES, ROOT / "sample_logs" / "README.md"]
README_MAX_LINES = 250


def _walk(tokens: list[Token]) -> Iterator[Token]:
    for token in tokens:
        yield token
        yield from _walk(token.children or [])


def links(text: str) -> list[str]:
    """Every link and image target of a Markdown text (code spans and blocks hold none)."""
    found = []
    for token in _walk(MarkdownIt("commonmark").parse(text)):
        if token.type == "link_open":
            found.append(str(token.attrGet("href")))
        elif token.type == "image":
            found.append(str(token.attrGet("src")))
    return found


def slug(heading: str) -> str:
    """A heading's anchor as GitHub and most renderers make it: lower case, punctuation dropped
    (hyphens and underscores kept), spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(text: str) -> set[str]:
    """The anchors of a page's headings; a repeated heading gets -1, -2, … as on GitHub."""
    seen: dict[str, int] = {}
    found = set()
    tokens = MarkdownIt("commonmark").parse(text)
    for opening, inline in itertools.pairwise(tokens):
        if opening.type != "heading_open":
            continue
        words = "".join(t.content for t in _walk(inline.children or []) if t.type != "softbreak")
        base = slug(words)
        count = seen.get(base, 0)
        seen[base] = count + 1
        found.add(f"{base}-{count}" if count else base)
    return found


def has_anchor(page: Path, fragment: str) -> bool:
    return unquote(fragment) in anchors(page.read_text(encoding="utf-8"))


def test_slug_follows_github():
    assert slug("`--json` documents") == "--json-documents"
    assert slug("Topics twincd writes (MCAP)") == "topics-twincd-writes-mcap"
    assert slug("Exit codes and streams") == "exit-codes-and-streams"
    assert anchors("# A\n\n## A\n") == {"a", "a-1"}


def test_links_skip_code():
    text = "see [x](a.md#b) and ![i](p.png)\n\n```\n[not](c.md)\n```\n`[no](d.md)`\n"
    assert links(text) == ["a.md#b", "p.png"]


@pytest.mark.parametrize("page", CHECKED, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page: Path):
    broken = []
    for target in links(page.read_text(encoding="utf-8")):
        parts = urlsplit(target)
        if parts.scheme or parts.netloc:  # a web address: not checked offline
            continue
        path = (page.parent / unquote(parts.path)).resolve() if parts.path else page
        if not path.exists() or not path.is_relative_to(ROOT):
            broken.append(f"{target}: no file {path}")
        elif parts.fragment and path.suffix == ".md" and not has_anchor(path, parts.fragment):
            broken.append(f"{target}: no heading #{parts.fragment} in {path.name}")
    assert not broken, broken


def test_every_docs_page_is_reachable_from_the_readme():
    """A page no link reaches is a page nobody reads."""
    reached, todo = set(), [ROOT / "README.md"]
    while todo:
        page = todo.pop()
        if page in reached:
            continue
        reached.add(page)
        for target in links(page.read_text(encoding="utf-8")):
            parts = urlsplit(target)
            path = (page.parent / unquote(parts.path)).resolve()
            if not (parts.scheme or parts.netloc) and path.suffix == ".md" and path.exists():
                todo.append(path)
    assert set(PAGES) - reached == set()


def test_readme_is_one_page():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES
