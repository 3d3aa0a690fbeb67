"""Relative links in the README and docs/ lead to files (and headings) that exist, and every
cited section of docs/method.md exists."""

from __future__ import annotations

from pathlib import Path

from .doccheck import (
    ROOT,
    bad_citations,
    broken_links,
    heading_anchors,
    markdown_files,
    method_sections,
    text_files,
)

METHOD = ROOT / "docs" / "method.md"


def test_relative_links_lead_to_existing_files() -> None:
    found = broken_links(ROOT, markdown_files(ROOT))
    assert not found, "broken links:\n" + "\n".join(found)


def test_the_link_check_finds_broken_links(tmp_path: Path) -> None:
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "a.md").write_text("# A\n\n## Set up, then run\n")
    (tmp_path / "README.md").write_text(
        "[ok](docs/a.md) [ok too](docs/a.md#set-up-then-run) [web](https://example.org/x)\n"
        "[gone](docs/b.md)\n"
        "![img](docs/img/none.png)\n"
        "[anchor](docs/a.md#no-such-part)\n"
        "[out](../elsewhere.md)\n"
        "`[code](docs/c.md)` and\n"
        "```\n[fenced](docs/d.md)\n```\n"
    )
    found = broken_links(tmp_path, [tmp_path / "README.md"])
    assert found == [
        "README.md:2: docs/b.md (no such file)",
        "README.md:3: docs/img/none.png (no such file)",
        "README.md:4: docs/a.md#no-such-part (no such heading)",
        "README.md:5: ../elsewhere.md (outside the repository)",
    ]


def test_heading_anchors_follow_github() -> None:
    text = (
        "# Attune\n## 5. Logs and request ids\n## Episodes: one event, one negotiation\n"
        "### `GET /v1/users`\n## Users\n## Users\n"
    )
    assert heading_anchors(text) == {
        "attune",
        "5-logs-and-request-ids",
        "episodes-one-event-one-negotiation",
        "get-v1users",
        "users",
        "users-1",
    }


def test_cited_method_sections_exist() -> None:
    sections = method_sections(METHOD.read_text(encoding="utf-8"))
    assert sections == set(range(1, max(sections) + 1)), "method.md's sections are numbered 1..N"
    found = bad_citations("docs/method.md", METHOD.read_text(encoding="utf-8"), sections, bare=True)
    for path in text_files(
        ROOT,
        (
            "README.md",
            "docs",
            "app",
            "clients/python/README.md",
            "clients/python/src",
            "tests",
            "bench",
        ),
    ):
        if path == METHOD or path.is_relative_to(ROOT / "tests" / "docs"):
            continue  # method.md is checked above; these tests plant bad citations on purpose
        found += bad_citations(
            str(path.relative_to(ROOT)), path.read_text(encoding="utf-8"), sections
        )
    assert not found, "citations of docs/method.md sections that do not exist:\n" + "\n".join(found)


def test_the_citation_check_finds_a_missing_section() -> None:
    text = "see docs/method.md §2 and §40\nand [method.md §4–§99](method.md)\nno §7 here\n"
    assert bad_citations("x.py", text, {1, 2, 3, 4}) == ["x.py:1: §40", "x.py:2: §99"]
    assert bad_citations("method.md", "as §3 and §12 say\n", {1, 2, 3}, bare=True) == [
        "method.md:1: §12"
    ]
