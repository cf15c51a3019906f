#!/usr/bin/env python
"""Check the relative links and images of the project's Markdown files.

    python scripts/check_links.py            # README.md, docs/*.md, assets/*/README.md, experiments/README.md
    python scripts/check_links.py FILE...    # only these

A link `[text](target)` or image `![alt](target)` with a relative target must name an
existing file or folder, relative to the Markdown file that holds it; a `#anchor`
(alone or after a .md file) must match a heading of that file, spelled as GitHub
spells heading anchors. Web and mail links are not fetched. Text in code blocks and
`code spans` is ignored. Prints one line per broken link and exits with status 1 if
there is any, 0 otherwise.
"""

from __future__ import annotations

import pathlib
import re
import sys
from typing import Iterator, List, Tuple

ROOT = pathlib.Path(__file__).resolve().parents[1]

LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]*)>?(?:\s+\"[^\"]*\")?\s*\)")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
FENCE = re.compile(r"^\s*(```|~~~)")
CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1", re.S)
EXTERNAL = ("http://", "https://", "mailto:", "ftp://")


def markdown_files(root: pathlib.Path = ROOT) -> List[pathlib.Path]:
    """The Markdown files whose links are checked."""
    files = [
        root / "README.md",
        *sorted((root / "docs").glob("*.md")),
        *sorted((root / "assets").glob("*/README.md")),
        root / "experiments" / "README.md",
    ]
    return [f for f in files if f.is_file()]


def _paragraphs(text: str) -> Iterator[Tuple[int, str]]:
    """(first line number, text) of each paragraph outside fenced code blocks, with code
    spans blanked; a link may run over several lines of its paragraph."""
    fenced = False
    start, lines = 0, []
    for number, line in enumerate(text.splitlines() + [""], start=1):
        if FENCE.match(line):
            fenced = not fenced
            line = ""
        if fenced or not line.strip():
            if lines:
                yield start, CODE_SPAN.sub("", "\n".join(lines))
            lines = []
            continue
        if not lines:
            start = number
        lines.append(line)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link in a heading keeps its text
    text = text.replace("`", "").strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: pathlib.Path) -> set:
    """Every heading anchor of a Markdown file (repeated headings get -1, -2, ...)."""
    seen: dict = {}
    result = set()
    fenced = False
    for line in path.read_text(encoding="utf-8").splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        match = None if fenced else HEADING.match(line)
        if match:
            base = slug(match.group(2))
            count = seen.get(base, 0)
            seen[base] = count + 1
            result.add(base if count == 0 else f"{base}-{count}")
    return result


def relative_links(path: pathlib.Path) -> Iterator[Tuple[int, str, pathlib.Path, str]]:
    """(line number, target as written, resolved file, anchor) of each relative link or
    image in `path`."""
    for first, paragraph in _paragraphs(path.read_text(encoding="utf-8")):
        for match in LINK.finditer(paragraph):
            target = match.group(1)
            if not target or target.startswith(EXTERNAL):
                continue
            file_part, _, anchor = target.partition("#")
            number = first + paragraph.count("\n", 0, match.start())
            destination = (path.parent / file_part).resolve() if file_part else path
            yield number, target, destination, anchor


def reachable(start: pathlib.Path) -> set:
    """The Markdown files and images reachable from `start` by relative links, `start` included."""
    seen, todo = {start.resolve()}, [start.resolve()]
    while todo:
        page = todo.pop()
        for _, _, destination, _ in relative_links(page):
            if destination not in seen and destination.is_file():
                seen.add(destination)
                if destination.suffix == ".md":
                    todo.append(destination)
    return seen


def broken_links(path: pathlib.Path) -> List[str]:
    """One message per broken relative link or image in `path`."""
    problems = []
    for number, target, destination, anchor in relative_links(path):
        where = f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}:{number}"
        if not destination.exists():
            problems.append(f"{where}: {target}: no such file")
        elif anchor and destination.suffix == ".md" and anchor not in anchors(destination):
            problems.append(f"{where}: {target}: no heading #{anchor} in {destination.name}")
    return problems


def main(argv=None) -> int:
    args = sys.argv[1:] if argv is None else argv
    files = [pathlib.Path(a).resolve() for a in args] if args else markdown_files()
    problems = [p for f in files for p in broken_links(f)]
    for problem in problems:
        print(problem)
    print(f"{len(files)} files, {len(problems)} broken links", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
