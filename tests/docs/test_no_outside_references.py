"""Nothing the product shows or ships points at a file outside the repository: not the README,
the docs, the service's package (code, console templates, static files), the client's README and
sources, nor the help of any command of the command line."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

from typer.main import get_command
from typer.testing import CliRunner

from app.cli import app

from .doccheck import ROOT, find_outside_references, scan_tree, text_files


def test_the_product_files_point_only_inside_the_repository() -> None:
    found = scan_tree(ROOT)
    assert not found, "references to files outside the repository:\n" + "\n".join(found)


def test_the_scan_covers_the_product() -> None:
    scanned = {
        str(p.relative_to(ROOT))
        for p in text_files(
            ROOT, ("README.md", "docs", "app", "clients/python/README.md", "clients/python/src")
        )
    }
    for expected in (
        "README.md",
        "docs/api.md",
        "docs/method.md",
        "app/cli.py",
        "app/console/templates/why.html",
        "app/learning/learners/hri.py",
        "clients/python/README.md",
        "clients/python/src/attune_client/_base.py",
    ):
        assert expected in scanned, expected


def _help_pages() -> Iterator[tuple[str, str]]:
    """(command line, output) of ``attune --help`` and of every command's and group's --help."""
    runner = CliRunner()
    env = {"COLUMNS": "240", "TERM": "dumb", "NO_COLOR": "1"}

    def walk(command: Any, path: list[str]) -> Iterator[tuple[str, str]]:
        result = runner.invoke(app, [*path, "--help"], env=env)
        line = " ".join(["attune", *path, "--help"])
        assert result.exit_code == 0, (line, result.output)
        yield line, result.output
        # A group (Typer's own click objects): its subcommands by name.
        for name, sub in sorted((getattr(command, "commands", None) or {}).items()):
            yield from walk(sub, [*path, name])

    yield from walk(get_command(app), [])


def test_no_help_page_points_outside_the_repository() -> None:
    pages = list(_help_pages())
    names = [line for line, _ in pages]
    for expected in (
        "attune --help",
        "attune experiment paper --help",
        "attune keys create --help",
        "attune fleet simulate --help",
        "attune serve --help",
    ):
        assert expected in names
    found = [f for line, output in pages for f in find_outside_references(line, output)]
    assert not found, "help pointing outside the repository:\n" + "\n".join(found)


def test_the_scan_finds_a_planted_reference(tmp_path: Path) -> None:
    (tmp_path / "docs").mkdir()
    (tmp_path / "app" / "console").mkdir(parents=True)
    (tmp_path / "README.md").write_text("# X\n\nThe method of ../shared/seed/paper.txt.\n")
    (tmp_path / "docs" / "guide.md").write_text("fine\nsee algorithm.md section 3\n")
    (tmp_path / "app" / "console" / "page.html").write_text("<p>as api-v1.md says</p>\n")
    (tmp_path / "app" / "mod.py").write_text('"""Read /work/shared/design first."""\n')
    (tmp_path / "app" / "image.png").write_bytes(b"\x89PNG algorithm.md")  # not text: skipped

    found = scan_tree(tmp_path, ("README.md", "docs", "app"))

    assert any(f.startswith("README.md:3: '../shared'") for f in found), found
    assert any(f.startswith("README.md:3: 'paper.txt'") for f in found), found
    assert any(f.startswith("docs/guide.md:2: 'algorithm.md'") for f in found), found
    assert any(f.startswith("app/console/page.html:1: 'api-v1.md'") for f in found), found
    assert any(f.startswith("app/mod.py:1: '/work/'") for f in found), found
    assert not any("image.png" in f for f in found)


def test_help_text_with_a_planted_reference_is_found() -> None:
    found = find_outside_references(
        "attune demo --help", "Usage: attune demo\n\n  As in algorithm.md section 6.\n"
    )
    assert found == ["attune demo --help:3: 'algorithm.md' in: As in algorithm.md section 6."]
