"""The README is the front page and docs/ the record: every link between them resolves, and the front page stays
short and names the commands that work."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
MAX_README_LINES = 320

_FENCE = re.compile(r"^\s*(```|~~~)")
_HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
_LINK = re.compile(r"!?\[(?:[^\]\\]|\\.)*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_CODE_SPAN = re.compile(r"(`+)(?:.+?)\1")
_SCHEME = re.compile(r"^[a-z][a-z0-9+.-]*:", re.IGNORECASE)
_MAKE = re.compile(r"^\s*make ([a-z][\w-]*)")
_TARGET = re.compile(r"^([A-Za-z0-9_.-]+)\s*:(?!=)", re.MULTILINE)
_DOCS_LINK = re.compile(r"\bdocs/[\w/.-]+\.md(?:#[\w-]+)?")
CODE_FOLDERS = ("pipeline", "sources", "sinks", "models", "tests")


def code_snippets(text: str) -> Iterator[str]:
    """The inline code spans and the lines of fenced code blocks of a Markdown text."""
    fenced = False
    for line in text.splitlines():
        if _FENCE.match(line):
            fenced = not fenced
        elif fenced:
            yield line
        else:
            yield from (match.group(0).strip("`") for match in _CODE_SPAN.finditer(line))


def markdown_files() -> list[Path]:
    return [README, *sorted((ROOT / "docs").rglob("*.md"))]


def prose_lines(text: str) -> Iterator[str]:
    """The lines of a Markdown text outside fenced code blocks."""
    fenced = False
    for line in text.splitlines():
        if _FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            yield line


def github_slug(heading: str) -> str:
    """The anchor GitHub gives a heading: its text lower-cased, link targets and punctuation dropped (letters,
    digits, '_', '-' and spaces stay), spaces turned into hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every heading anchor of a Markdown file; a repeated heading gets -1, -2 … as on GitHub."""
    seen: dict[str, int] = {}
    found: set[str] = set()
    for line in prose_lines(path.read_text(encoding="utf-8")):
        match = _HEADING.match(line)
        if not match:
            continue
        slug = github_slug(match.group(2))
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        found.add(slug if count == 0 else f"{slug}-{count}")
    return found


def broken_links(path: Path) -> list[str]:
    """The relative links (and images) of a Markdown file whose file or #anchor does not exist."""
    problems = []
    for line in prose_lines(path.read_text(encoding="utf-8")):
        for target in _LINK.findall(_CODE_SPAN.sub("", line)):
            if _SCHEME.match(target):
                continue
            file_part, _, anchor = target.partition("#")
            linked = (path.parent / file_part).resolve() if file_part else path
            if not linked.exists():
                problems.append(f"{target}: no file {linked}")
            elif anchor and linked.suffix == ".md" and anchor not in anchors(linked):
                problems.append(f"{target}: no heading with anchor #{anchor} in {linked.name}")
    return problems


@pytest.mark.parametrize("page", markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves_to_an_existing_file_and_heading(page: Path) -> None:
    assert broken_links(page) == []


def docs_links_in_code(root: Path) -> dict[str, list[str]]:
    """Every `docs/….md#anchor` named in the Python code under `root`, with the files that name it."""
    named: dict[str, list[str]] = {}
    for folder in CODE_FOLDERS:
        for source in sorted((root / folder).rglob("*.py")):
            for link in _DOCS_LINK.findall(source.read_text(encoding="utf-8")):
                named.setdefault(link, []).append(str(source.relative_to(root)))
    return named


def test_every_docs_page_and_anchor_a_code_comment_names_exists() -> None:
    missing = {}
    for link, sources in docs_links_in_code(ROOT).items():
        file_part, _, anchor = link.partition("#")
        page = ROOT / file_part
        if not page.exists() or (anchor and anchor not in anchors(page)):
            missing[link] = sources
    assert missing == {}


@pytest.mark.parametrize("page", markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_page_has_one_title_and_it_comes_first(page: Path) -> None:
    levels = [len(m.group(1)) for line in prose_lines(page.read_text(encoding="utf-8")) if (m := _HEADING.match(line))]
    assert levels[0] == 1
    assert levels.count(1) == 1


def test_anchors_follow_githubs_slug_rules_with_repeated_headings_numbered(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text(
        "# Round P2: LRGNet plane features\n\n## Before #12: in-family\n\n## Notes\n\n"
        "```\n## not a heading\n```\n\n## Notes\n\n### `make bench-io`, the [io](io.md) page\n",
        encoding="utf-8",
    )
    assert anchors(page) == {
        "round-p2-lrgnet-plane-features",
        "before-12-in-family",
        "notes",
        "notes-1",
        "make-bench-io-the-io-page",
    }


def test_a_missing_file_or_anchor_is_reported_and_outside_links_and_code_are_not(tmp_path: Path) -> None:
    (tmp_path / "other.md").write_text("# There\n", encoding="utf-8")
    page = tmp_path / "page.md"
    page.write_text(
        "# Here\n\n[ok](other.md#there) [self](#here) [web](https://example.org/x#y) `[code](gone.md)`\n"
        "[gone](gone.md) [no anchor](other.md#nowhere) ![picture](missing.png)\n\n```\n[fenced](gone.md)\n```\n",
        encoding="utf-8",
    )
    problems = broken_links(page)
    assert len(problems) == 3
    assert [p.split(":")[0] for p in problems] == ["gone.md", "other.md#nowhere", "missing.png"]


def test_every_make_target_the_readme_names_exists_in_the_makefile() -> None:
    named = {m.group(1) for code in code_snippets(README.read_text(encoding="utf-8")) if (m := _MAKE.match(code))}
    targets = set(_TARGET.findall((ROOT / "Makefile").read_text(encoding="utf-8")))
    assert {"demo", "test"} <= named
    assert named - targets == set()


def test_make_commands_are_read_from_code_not_from_prose() -> None:
    text = "To make the map, run `make demo` or `make bench-io`.\n\n```bash\nmake test   # all\n```\n"
    assert [m.group(1) for code in code_snippets(text) if (m := _MAKE.match(code))] == ["demo", "bench-io", "test"]


def test_the_readme_stays_a_front_page_under_320_lines() -> None:
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) < MAX_README_LINES


def test_the_front_page_gives_the_two_set_up_commands() -> None:
    text = README.read_text(encoding="utf-8")
    assert "make demo" in text
    assert "make test" in text
