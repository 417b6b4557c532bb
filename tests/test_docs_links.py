"""Every relative link in the user documentation resolves, and the README stays a newcomer's page.

Scans README.md, benchmarks/README.md and docs/**/*.md for Markdown links and image links (inline `[t](target)`,
`![alt](target)` and reference definitions `[id]: target`), outside fenced code blocks and inline code. A relative
target must exist (relative to the file that links it); a `#anchor` must match a heading slug of the target
Markdown file (GitHub's rule: lower case, punctuation dropped, spaces to hyphens, repeats numbered -1, -2, ...).
External links (http:, https:, mailto:) are not fetched.
"""

from __future__ import annotations

import re
import unicodedata
from pathlib import Path
from urllib.parse import unquote

ROOT = Path(__file__).resolve().parents[1]
README_MAX_BYTES = 12_288

_FENCE = re.compile(r"^\s*(```|~~~)")
_CODE_SPAN = re.compile(r"(`+)(?:(?!\1)[^`]|(?!\1)`+)+?\1")
_INLINE_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*(<[^>]*>|[^)\s]+)(?:\s+[\"'(][^)]*)?\)")
_REFERENCE_DEF = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*(<[^>]*>|\S+)")
_HEADING = re.compile(r"^\s{0,3}(#{1,6})\s+(.*?)\s*#*\s*$")
_EXTERNAL = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


def doc_files(root: Path = ROOT) -> list[Path]:
    """The Markdown files whose links must resolve."""
    files = [root / "README.md", root / "benchmarks" / "README.md"]
    files += sorted((root / "docs").rglob("*.md"))
    return [f for f in files if f.is_file()]


def _lines_outside_code(text: str):
    """(line number, line with inline code removed) for every line outside fenced code blocks.

    A code span may run over a line break within a paragraph (CommonMark), so spans are removed per paragraph: a
    link after a backtick that opens on the line before is inside code, and one after a span that closes is not."""
    fenced = False
    paragraph: list[tuple[int, str]] = []

    def flush():
        if paragraph:
            joined = _CODE_SPAN.sub(lambda m: "\n" * m.group(0).count("\n"), "\n".join(l for _, l in paragraph))
            yield from zip((n for n, _ in paragraph), joined.split("\n"))
            paragraph.clear()

    for number, line in enumerate(text.splitlines(), start=1):
        if _FENCE.match(line):
            yield from flush()
            fenced = not fenced
            continue
        if fenced:
            continue
        if line.strip():
            paragraph.append((number, line))
        else:
            yield from flush()
    yield from flush()


def heading_slugs(text: str) -> set[str]:
    """GitHub-style anchors of every heading outside fenced code: lower case, inline-code backticks and
    punctuation dropped, spaces to hyphens, a repeated slug numbered -1, -2, ..."""
    slugs: set[str] = set()
    seen: dict[str, int] = {}
    fenced = False
    for line in text.splitlines():
        if _FENCE.match(line):
            fenced = not fenced
            continue
        match = None if fenced else _HEADING.match(line)
        if not match:
            continue
        title = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", match.group(2))  # a link in a heading keeps its text
        title = title.replace("`", "").lower()
        slug = "".join(c for c in title if c in " -_" or unicodedata.category(c)[0] in ("L", "N")).replace(" ", "-")
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        slugs.add(slug if count == 0 else f"{slug}-{count}")
    return slugs


def links(text: str):
    """(line number, target) of every link and image link outside code."""
    for number, line in _lines_outside_code(text):
        for match in _INLINE_LINK.finditer(line):
            yield number, match.group(1).strip("<>")
        match = _REFERENCE_DEF.match(line)
        if match:
            yield number, match.group(1).strip("<>")


def broken_links(files: list[Path], root: Path = ROOT) -> list[str]:
    """One message per link that does not resolve: 'file:line: target (why)'."""
    problems = []
    for path in files:
        text = path.read_text(encoding="utf-8")
        for number, target in links(text):
            if not target or _EXTERNAL.match(target) or target.startswith("//"):
                continue
            file_part, _, anchor = target.partition("#")
            file_part = unquote(file_part)
            resolved = path if not file_part else (path.parent / file_part)
            where = f"{path.relative_to(root)}:{number}: {target}"
            if file_part.startswith("/"):
                problems.append(f"{where} (absolute path; use a relative link)")
                continue
            if not resolved.exists():
                problems.append(f"{where} (no such file)")
                continue
            if anchor and resolved.is_file() and resolved.suffix.lower() == ".md":
                if unquote(anchor).lower() not in heading_slugs(resolved.read_text(encoding="utf-8")):
                    problems.append(f"{where} (no heading with anchor #{anchor} in {resolved.name})")
    return problems


def test_every_documentation_link_resolves():
    files = doc_files()
    assert ROOT / "README.md" in files
    problems = broken_links(files)
    assert not problems, "broken links:\n" + "\n".join(problems)


def test_readme_is_at_most_12_kib():
    size = (ROOT / "README.md").stat().st_size
    assert size <= README_MAX_BYTES, f"README.md is {size} bytes, over {README_MAX_BYTES}: move detail to docs/"


def test_the_checker_reports_broken_links_and_passes_good_ones(tmp_path):
    (tmp_path / "docs" / "img").mkdir(parents=True)
    (tmp_path / "docs" / "img" / "plot.png").write_bytes(b"\x89PNG")
    (tmp_path / "docs" / "topic.md").write_text("# Topic\n\n## The `sensor` model (EMVA 1288)\n\ntext\n", encoding="utf-8")
    (tmp_path / "README.md").write_text(
        "# Project\n\n"
        "See [the topic](docs/topic.md), [its model](docs/topic.md#the-sensor-model-emva-1288), "
        "[here](#project) and ![a plot](docs/img/plot.png \"title\") and [web](https://example.org/x).\n"
        "A [missing file](docs/nothing.md) and ![a missing image](docs/img/none.png).\n"
        "A [bad anchor](docs/topic.md#no-such-heading) and [a bad local one](#nowhere).\n"
        "`[in code](docs/ignored.md)`\n"
        "```\n[in a fence](docs/ignored_too.md)\n```\n"
        "[ref]: docs/gone.md\n",
        encoding="utf-8",
    )
    problems = broken_links([tmp_path / "README.md"], root=tmp_path)
    text = "\n".join(problems)
    assert len(problems) == 5, text
    assert "README.md:4: docs/nothing.md" in text
    assert "README.md:4: docs/img/none.png" in text
    assert "README.md:5: docs/topic.md#no-such-heading" in text
    assert "README.md:5: #nowhere" in text
    assert "README.md:10: docs/gone.md" in text
    assert "ignored" not in text
    assert "plot.png" not in text and "example.org" not in text


def test_heading_slugs_follow_github():
    text = "# A, b & C!\n## Results (default scale)\n## Results (default scale)\n```\n# not a heading\n```\n"
    assert heading_slugs(text) == {"a-b--c", "results-default-scale", "results-default-scale-1"}


def test_a_code_span_over_a_line_break_hides_links_only_inside_it(tmp_path):
    # a span that opens on one line and closes on the next (CommonMark allows it within a paragraph) must not
    # shift which text counts as code: here the link after the closing backtick is a real link, and is checked
    (tmp_path / "README.md").write_text(
        "# Project\n\nThe key (`train.weight:\n1.0`, [after the span](docs/gone.md)) and `x` [fine](#project).\n\n"
        "`[inside](docs/inside.md)\nstill code` text.\n",
        encoding="utf-8",
    )
    problems = broken_links([tmp_path / "README.md"], root=tmp_path)
    assert problems == ["README.md:4: docs/gone.md (no such file)"], problems
