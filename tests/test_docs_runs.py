"""Every kept run says what it is: docs/runs/<run>/README.md opens with a header, and exactly one run is current.

The header is a list right under the title, one field a line: `- **Date:** ...`, `- **Commit:** ...`,
`- **Overrides:** ...`, `- **What it tested:** ...`, `- **Status:** ...`. The status is `current` (the run the
README's headline comes from), `supplement to [run](link)` or `superseded by [run](link)`, where the link names
another run folder. docs/runs/README.md lists every run once, the current one first. A newcomer can then tell which
numbers stand without reading the history.
"""

from __future__ import annotations

import re
from pathlib import Path

RUNS = Path(__file__).resolve().parents[1] / "docs" / "runs"
FIELDS = ("Date", "Commit", "Overrides", "What it tested", "Status")
_FIELD = re.compile(r"^- \*\*(?P<name>[^*]+):\*\* *(?P<value>.*)$")
_STATUS = re.compile(r"^(?P<kind>current|supplement to|superseded by)\b(?P<rest>.*)$")
_LINK = re.compile(r"\[[^\]]*\]\(([^)#\s]+)[^)]*\)")
_TABLE_RUN = re.compile(r"^\|\s*\[(?P<name>[^\]]+)\]\((?P=name)/README\.md\)\s*\|")


def header(readme: Path) -> dict[str, str]:
    """The header fields of a run's README: the list that follows the title (blank lines around it allowed)."""
    lines = readme.read_text(encoding="utf-8").splitlines()
    fields: dict[str, str] = {}
    if not lines or not lines[0].startswith("# "):
        return fields
    for line in lines[1:]:
        if not line.strip():
            if fields:
                break
            continue
        match = _FIELD.match(line)
        if not match:
            break
        fields[match["name"]] = match["value"].strip()
    return fields


def run_problems(runs: Path = RUNS) -> list[str]:
    """One message per run folder whose header is missing or malformed, and for the count of current runs."""
    problems, current = [], []
    for folder in sorted(p for p in runs.iterdir() if p.is_dir()):
        readme = folder / "README.md"
        if not readme.is_file():
            problems.append(f"{folder.name}: no README.md")
            continue
        fields = header(readme)
        for name in FIELDS:
            if not fields.get(name):
                problems.append(f"{folder.name}: header has no '- **{name}:**' line (or it is empty)")
        status = fields.get("Status", "")
        match = _STATUS.match(status)
        if status and not match:
            problems.append(f"{folder.name}: status {status!r} is not current, supplement to or superseded by")
            continue
        if not match:
            continue
        if match["kind"] == "current":
            current.append(folder.name)
            continue
        link = _LINK.search(match["rest"])
        target = (folder / link.group(1)).resolve() if link else None
        if target is None or target.parent.parent != runs.resolve() or target.parent == folder.resolve():
            problems.append(f"{folder.name}: '{match['kind']}' must link another run's README as its first link")
        elif not target.is_file():
            problems.append(f"{folder.name}: status links {link.group(1)}, which does not exist")
    if len(current) != 1:
        problems.append(f"exactly one run must be current, found {len(current)}: {current}")
    return problems


def table_problems(runs: Path = RUNS) -> list[str]:
    """docs/runs/README.md's table: every run folder once, the current run in the first row."""
    readme = runs / "README.md"
    if not readme.is_file():
        return ["docs/runs/README.md is missing"]
    rows = [m["name"] for m in map(_TABLE_RUN.match, readme.read_text(encoding="utf-8").splitlines()) if m]
    folders = sorted(p.name for p in runs.iterdir() if p.is_dir())
    problems = []
    if sorted(rows) != folders:
        problems.append(f"table rows {sorted(rows)} differ from the run folders {folders}")
    current = [f for f in folders if (runs / f / "README.md").is_file()
               and header(runs / f / "README.md").get("Status", "").startswith("current")]
    if rows and current and rows[0] != current[0]:
        problems.append(f"the first row is {rows[0]}, not the current run {current[0]}")
    return problems


def test_every_run_has_a_header_and_exactly_one_is_current():
    problems = run_problems()
    assert not problems, "docs/runs:\n" + "\n".join(problems)


def test_the_runs_table_lists_every_run_current_first():
    problems = table_problems()
    assert not problems, "docs/runs/README.md:\n" + "\n".join(problems)


def _run(root: Path, name: str, status: str | None, drop: str = "") -> None:
    (root / name).mkdir(parents=True)
    lines = [f"# Run {name}", ""]
    for field in FIELDS:
        value = status if field == "Status" else "x"
        if field != drop and value is not None:
            lines.append(f"- **{field}:** {value}")
    (root / name / "README.md").write_text("\n".join(lines + ["", "Body."]) + "\n", encoding="utf-8")


def test_the_checker_catches_bad_headers(tmp_path):
    _run(tmp_path, "a", "current")
    _run(tmp_path, "b", "superseded by [a](../a/README.md), a newer one.")
    _run(tmp_path, "c", "supplement to [a](../a/README.md)")
    (tmp_path / "README.md").write_text("| run |\n|---|\n| [a](a/README.md) |\n| [b](b/README.md) |\n"
                                        "| [c](c/README.md) |\n", encoding="utf-8")
    assert run_problems(tmp_path) == []
    assert table_problems(tmp_path) == []

    _run(tmp_path, "d", "current", drop="Overrides")  # a second current run, and a field left out
    _run(tmp_path, "e", "superseded by [itself](../e/README.md)")
    _run(tmp_path, "f", "old")
    _run(tmp_path, "g", "superseded by [gone](../gone/README.md)")
    (tmp_path / "h").mkdir()
    text = "\n".join(run_problems(tmp_path))
    assert "d: header has no '- **Overrides:**' line" in text
    assert "exactly one run must be current, found 2: ['a', 'd']" in text
    assert "e: 'superseded by' must link another run's README" in text
    assert "f: status 'old' is not current" in text
    assert "g: status links ../gone/README.md, which does not exist" in text
    assert "h: no README.md" in text
    assert "table rows" in "\n".join(table_problems(tmp_path))
