"""Checks that keep the documentation true: docs/api.md against the OpenAPI schema, pointers to
files outside the repository, relative links, and citations of docs/method.md sections.

Each check is a plain function that returns what it found, so the tests can show that it fails
on a planted mistake as well as that the repository passes it.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]

# -- docs/api.md against the OpenAPI schema ---------------------------------------------------
HTTP_METHODS = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS")
# An endpoint is documented by a level-3 heading that starts with its method and path in one code
# span, exactly as in /openapi.json:   ### `GET /v1/users/{user_id}`
ENDPOINT_HEADING = re.compile(
    r"^###[ \t]+`(" + "|".join(HTTP_METHODS) + r") (/[^`\s]*)`", re.MULTILINE
)

Operation = tuple[str, str]  # (METHOD, path)


@dataclass
class ApiDocReport:
    missing: list[Operation] = field(default_factory=list)  # in the schema, not in the doc
    extra: list[Operation] = field(default_factory=list)  # in the doc, not in the schema
    duplicated: list[Operation] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not (self.missing or self.extra or self.duplicated)

    def __str__(self) -> str:
        lines = [f"undocumented in docs/api.md: {m} {p}" for m, p in self.missing]
        lines += [f"documented but not served: {m} {p}" for m, p in self.extra]
        lines += [f"documented twice: {m} {p}" for m, p in self.duplicated]
        return "\n".join(lines)


def documented_operations(doc: str) -> list[Operation]:
    """The (method, path) of every endpoint heading of an api.md text, in order."""
    return [(m, p) for m, p in ENDPOINT_HEADING.findall(_without_fences(doc))]


def schema_operations(schema: Mapping[str, Any]) -> set[Operation]:
    """The (method, path) of every operation of an OpenAPI document."""
    out: set[Operation] = set()
    for path, item in schema.get("paths", {}).items():
        for key in item:
            if key.upper() in HTTP_METHODS:
                out.add((key.upper(), path))
    return out


def check_api_doc(doc: str, schema: Mapping[str, Any]) -> ApiDocReport:
    """Compare an api.md text with an OpenAPI document, both ways.

    HEAD is documented once for every GET (api.md's conventions), so a HEAD operation in the
    schema counts as documented when the GET of the same path is.
    """
    listed = documented_operations(doc)
    documented = set(listed)
    served = schema_operations(schema)
    report = ApiDocReport()
    for method, path in sorted(served):
        if (method, path) in documented:
            continue
        if method == "HEAD" and ("GET", path) in documented:
            continue
        report.missing.append((method, path))
    report.extra = sorted(documented - served)
    report.duplicated = sorted({op for op in listed if listed.count(op) > 1})
    return report


# -- pointers to files outside the repository --------------------------------------------------
OUTSIDE_PATTERNS = (
    "../shared",
    "shared/design",
    "shared/seed",
    "algorithm.md",
    "api-v1.md",
    "paper.txt",
    "/work/",
)
TEXT_SUFFIXES = frozenset(
    {
        ".py",
        ".html",
        ".js",
        ".css",
        ".json",
        ".md",
        ".txt",
        ".toml",
        ".ini",
        ".cfg",
        ".yml",
        ".yaml",
        ".mako",
        ".svg",
    }
)
# What the product shows or ships: the README, the docs, the service's package, the client's
# README and sources.
PRODUCT_PATHS = ("README.md", "docs", "app", "clients/python/README.md", "clients/python/src")


def find_outside_references(name: str, text: str) -> list[str]:
    """``name:line: 'pattern' in: <line>`` for each line of ``text`` that names an outside file."""
    found = []
    for number, line in enumerate(text.splitlines(), start=1):
        for pattern in OUTSIDE_PATTERNS:
            if pattern in line:
                found.append(f"{name}:{number}: {pattern!r} in: {line.strip()[:160]}")
    return found


def text_files(root: Path, relative: Iterable[str]) -> Iterator[Path]:
    """The text files (by suffix) under each of ``relative`` (a file or a folder) in ``root``."""
    for rel in relative:
        path = root / rel
        if path.is_file():
            yield path
        elif path.is_dir():
            for child in sorted(path.rglob("*")):
                if (
                    child.is_file()
                    and child.suffix in TEXT_SUFFIXES
                    and "__pycache__" not in child.parts
                ):
                    yield child


def scan_tree(root: Path, relative: Iterable[str] = PRODUCT_PATHS) -> list[str]:
    """Every outside reference in the text files of ``relative`` under ``root``."""
    found = []
    for path in text_files(root, relative):
        text = path.read_text(encoding="utf-8", errors="replace")
        found += find_outside_references(str(path.relative_to(root)), text)
    return found


# -- relative links in Markdown ----------------------------------------------------------------
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_FENCE = re.compile(r"^(```|~~~)")
_INLINE_CODE = re.compile(r"`+[^`]*`+")


def _without_fences(text: str) -> str:
    """``text`` with the lines of fenced code blocks blanked (line numbers kept)."""
    out, inside = [], False
    for line in text.splitlines():
        if _FENCE.match(line.lstrip()):
            inside = not inside
            out.append("")
            continue
        out.append("" if inside else line)
    return "\n".join(out)


def heading_anchors(text: str) -> set[str]:
    """GitHub's anchors of a Markdown text's headings (lowercase, punctuation dropped, spaces to
    hyphens, ``-1``, ``-2`` for repeats)."""
    seen: dict[str, int] = {}
    anchors = set()
    for line in _without_fences(text).splitlines():
        match = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not match:
            continue
        slug = re.sub(r"[^\w\- ]", "", match.group(1).strip().lower()).replace(" ", "-")
        count = seen.get(slug, 0)
        anchors.add(slug if count == 0 else f"{slug}-{count}")
        seen[slug] = count + 1
    return anchors


def broken_links(root: Path, files: Iterable[Path]) -> list[str]:
    """``file:line: target (why)`` for each relative link that leads nowhere in ``root``: a file
    that does not exist, a path outside the repository, or an anchor no heading makes."""
    found = []
    for path in files:
        text = path.read_text(encoding="utf-8")
        for number, line in enumerate(_without_fences(text).splitlines(), start=1):
            for target in LINK.findall(_INLINE_CODE.sub("", line)):
                if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target):  # http:, https:, mailto:
                    continue
                where = f"{path.relative_to(root)}:{number}: {target}"
                file_part, _, anchor = target.partition("#")
                dest = (path.parent / file_part).resolve() if file_part else path
                if not dest.is_relative_to(root):
                    found.append(f"{where} (outside the repository)")
                elif not dest.exists():
                    found.append(f"{where} (no such file)")
                elif (
                    anchor
                    and dest.suffix == ".md"
                    and anchor not in heading_anchors(dest.read_text(encoding="utf-8"))
                ):
                    found.append(f"{where} (no such heading)")
    return found


def markdown_files(root: Path) -> list[Path]:
    return [
        root / "README.md",
        *sorted((root / "docs").rglob("*.md")),
        root / "clients/python/README.md",
    ]


# -- citations of docs/method.md sections ------------------------------------------------------
METHOD_SECTION = re.compile(r"^## (\d+)\. ", re.MULTILINE)
CITATION = re.compile(r"method\.md\)?\s*((?:§\s*\d+(?:\s*(?:[-–,]|and)\s*)?)+)")


def method_sections(method_text: str) -> set[int]:
    return {int(n) for n in METHOD_SECTION.findall(method_text)}


def bad_citations(name: str, text: str, sections: set[int], *, bare: bool = False) -> list[str]:
    """``name:line: §N`` for each cited section of docs/method.md that does not exist.

    ``bare``: the text is method.md itself, where a plain ``§N`` cites its own sections.
    """
    found = []
    for number, line in enumerate(text.splitlines(), start=1):
        spans = [m.group(1) for m in CITATION.finditer(line)]
        if bare:
            spans.append(line)
        for span in spans:
            for cited in re.findall(r"§\s*(\d+)", span):
                if int(cited) not in sections:
                    found.append(f"{name}:{number}: §{cited}")
    return found
