"""dvc.yaml, generated from the stage table (stages/table.py) and from the code each stage runs.

    python -m stages.dvc_yaml --write   # rewrite dvc.yaml
    python -m stages.dvc_yaml --check   # exit 1 naming every stage and field that differs (tests/stages/test_table.py)

For each stage the table gives the command, the config keys (DVC `params`), the data deps and the outputs; this module
adds the source deps and writes the file:

- Source deps are the project files `python -m stages.<name>` runs: the closure of its imports under stages/ and
  src/expoctl/, read with `ast` (function-local imports, relative imports, parent packages' `__init__.py`,
  `from pkg import submodule`; not `if TYPE_CHECKING:` blocks), the packages a registry imports by name
  (DYNAMIC_IMPORTS), and the non-Python files that code reads from the source tree (RUNTIME_DATA). A directory
  stands for its files where the stage needs every file in it, so the list is the smallest that covers exactly
  these files. A module the closure reaches that imports by name without an entry here stops the generator: its
  imports cannot be followed, and a dep left out means a code change that does not re-run the stage.
- Paths in the table are templates over an iteration's `paths` (conf/config.yaml `paths`, `iteration<N>.paths`
  over them: fixed, stages/config_check.py refuses to move a DVC output). Iteration 1 is written out; iterations 2 …
  LAST_ITERATION are one `foreach` stage each over `vars: later_iterations`, which holds the values that differ
  between them. A list of earlier iterations (`Each`) cannot be templated in DVC, so it is written as one entry per
  iteration it can name, each filled with the stage's own iteration's value where that iteration is not earlier
  (a duplicate entry, which DVC counts once). The generator checks that every iteration's expansion is exactly its
  stage as the table defines it.

This module is no stage's dependency (no stage imports it): changing how dvc.yaml is written changes no stage's
deps unless the written file changes.
"""

from __future__ import annotations

import argparse
import ast
import string
import subprocess
import sys
import textwrap
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from stages.dvcfile import resolve_document
from stages.project import PROJECT_ROOT
from stages.table import LAST_ITERATION, LATER_KEYS, STAGES, Dep, Each, Out, Stage, config_keys, expand, key_vars

DVC_YAML = "dvc.yaml"
WRITE_COMMAND = "python -m stages.dvc_yaml --write"
RESOLVED = "configs/resolved.yaml"
WIDTH = 118

#: top-level project package → its directory, relative to the project root; other imports are not followed
PACKAGE_DIRS = {"stages": "stages", "expoctl": "src/expoctl"}

#: Non-Python files a project module reads from the source tree at run time: module → glob patterns (relative to the
#: project root; `{city_dir}` is conf/world/default.yaml's `city_dir`).
RUNTIME_DATA: dict[str, tuple[str, ...]] = {
    "src/expoctl/world/gl_renderer.py": ("src/expoctl/world/shaders/*.glsl",),  # the EGL back end's GLSL sources
    "src/expoctl/world/cities.py": ("{city_dir}/*.yaml",),  # <world.city_dir>/<name>.yaml, the packaged cities
    "stages/compose.py": ("conf/**/*.yaml",),  # compose_config: the whole Hydra tree
    "stages/config_check.py": ("conf/config.yaml",),  # the fixed paths.* defaults
}

#: Modules that make project modules be imported by name, which `ast` cannot follow: module → the packages whose every
#: module (subpackages included) gets imported. The plugin registries (src/expoctl/plugins.py `Registry`) import
#: every module of their built-in packages on first use.
DYNAMIC_IMPORTS: dict[str, tuple[str, ...]] = {
    "src/expoctl/controllers/registry.py": ("expoctl.controllers", "expoctl.sim.oracle", "expoctl.bench.rl.controller"),  # its builtin_packages
    "src/expoctl/features/registry.py": ("expoctl.features",),
}
#: Modules that import by name only what the DYNAMIC_IMPORTS modules above ask of them.
IMPORTS_WHAT_IT_IS_TOLD = frozenset({"src/expoctl/plugins.py"})
_BY_NAME = ("import_module", "__import__", "walk_packages", "iter_modules")


class GeneratorError(Exception):
    """The table or the code cannot be written as a correct dvc.yaml; the message says what to change."""


# --- the code a stage runs ----------------------------------------------------------------------------------------


def _module_file(root: Path, name: str) -> str | None:
    """The file (relative) of project module `name` (a package's __init__.py), or None (not a project module)."""
    top, *rest = name.split(".")
    if top not in PACKAGE_DIRS:
        return None
    base = root / PACKAGE_DIRS[top] / Path(*rest) if rest else root / PACKAGE_DIRS[top]
    if (base / "__init__.py").is_file():
        return (base / "__init__.py").relative_to(root).as_posix()
    if rest and base.with_suffix(".py").is_file():
        return base.with_suffix(".py").relative_to(root).as_posix()
    return None


def _module_name(rel: str) -> str:
    for top, d in PACKAGE_DIRS.items():
        if rel == d or rel.startswith(d + "/"):
            parts = [top, *Path(rel).relative_to(d).with_suffix("").parts]
            return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
    raise ValueError(rel)


def _with_parents(name: str) -> list[str]:
    """'a.b.c' → ['a', 'a.b', 'a.b.c']: importing a submodule runs its parent packages first."""
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts) + 1)]


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.Module, rel: str) -> tuple[set[str], bool]:
    """(every module name an import statement in the module may load, whether it imports by name)."""
    module = _module_name(rel)
    package = module if rel.endswith("__init__.py") else module.rpartition(".")[0]
    names: set[str] = set()
    by_name = False

    def visit(node: ast.AST) -> None:
        nonlocal by_name
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.orelse:  # the `if TYPE_CHECKING:` body never runs
                visit(child)
            return
        if isinstance(node, ast.Import):
            for alias in node.names:
                names.update(_with_parents(alias.name))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(anchor + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            names.update(_with_parents(base))
            names.update(f"{base}.{alias.name}" for alias in node.names if alias.name != "*")
        elif isinstance(node, ast.Call):
            func = node.func
            called = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""
            by_name = by_name or called in _BY_NAME
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return names, by_name


def _package_modules(root: Path, package: str) -> list[str]:
    """Every module name of project package `package`, subpackages included."""
    base = root / PACKAGE_DIRS[package.split(".")[0]] / Path(*package.split(".")[1:])
    out = []
    for path in sorted(base.rglob("*.py")):
        if "__pycache__" not in path.parts:
            out.append(_module_name(path.relative_to(root).as_posix()))
    return out


def import_closure(module: str, root: Path = PROJECT_ROOT) -> set[str]:
    """The project files (relative paths) `python -m <module>` runs, through every import transitively."""
    todo = deque(_with_parents(module))
    seen: set[str] = set()
    files: set[str] = set()
    while todo:
        name = todo.popleft()
        if name in seen:
            continue
        seen.add(name)
        rel = _module_file(root, name)
        if rel is None:
            continue
        files.add(rel)
        names, by_name = _imports(ast.parse((root / rel).read_text(), rel), rel)
        if by_name and rel not in DYNAMIC_IMPORTS and rel not in IMPORTS_WHAT_IT_IS_TOLD:
            raise GeneratorError(
                f"{rel} imports modules by name, which stages/dvc_yaml.py cannot follow: add it to DYNAMIC_IMPORTS "
                f"there with the project packages it imports (or to IMPORTS_WHAT_IT_IS_TOLD), then {WRITE_COMMAND}")
        for package in DYNAMIC_IMPORTS.get(rel, ()):
            names.update(_package_modules(root, package))
        todo.extend(names - seen)
    return files


def _city_dir(root: Path) -> str:
    return yaml.safe_load((root / "conf" / "world" / "default.yaml").read_text())["city_dir"]


def runtime_data(files: set[str], root: Path = PROJECT_ROOT) -> set[str]:
    """The non-Python files the modules `files` read from the source tree (RUNTIME_DATA)."""
    out: set[str] = set()
    for module in sorted(files & RUNTIME_DATA.keys()):
        for pattern in RUNTIME_DATA[module]:
            pattern = pattern.format(city_dir=_city_dir(root))
            matched = {p.relative_to(root).as_posix() for p in root.glob(pattern) if p.is_file()}
            if not matched:
                raise GeneratorError(f"stages/dvc_yaml.py RUNTIME_DATA[{module!r}]: {pattern} matches no file")
            out |= matched
    return out


def project_files(root: Path = PROJECT_ROOT) -> set[str]:
    """The files a directory dep would hash, as every checkout has them: git's tracked and untracked-but-not-ignored
    files, less what .dvcignore excludes (DVC does not hash those: bytecode)."""
    import pathspec

    listed = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=root, capture_output=True,
                            text=True, check=True).stdout.splitlines()
    ignore = root / ".dvcignore"
    spec = pathspec.GitIgnoreSpec.from_lines(ignore.read_text().splitlines() if ignore.is_file() else [])
    return {f for f in listed if (root / f).is_file() and not spec.match_file(f)}


def minimal_cover(needed: set[str], universe: set[str]) -> list[str]:
    """The fewest paths (files and directories) that cover exactly `needed`: a directory replaces its files where
    every file of `universe` under it is needed (the highest such directory, never the project root)."""
    under: dict[str, set[str]] = {}
    for f in universe | needed:
        parts = f.split("/")
        for i in range(1, len(parts)):
            under.setdefault("/".join(parts[:i]), set()).add(f)
    out = set()
    for f in needed:
        parts = f.split("/")
        cover = f
        for i in range(len(parts) - 1, 0, -1):  # from the file's own directory upwards
            d = "/".join(parts[:i])
            if under[d] <= needed:
                cover = d
            else:
                break
        out.add(cover)
    return sorted(out)


def source_deps(stage: str, root: Path = PROJECT_ROOT, universe: set[str] | None = None) -> list[str]:
    """The source deps of `python -m stages.<stage>`: its code and the files that code reads, as `minimal_cover`."""
    files = import_closure(f"stages.{stage}", root)
    return minimal_cover(files | runtime_data(files, root), project_files(root) if universe is None else universe)


# --- the stages, per iteration -------------------------------------------------------------------------------------


def iteration_paths(conf: dict, n: int) -> dict[str, str]:
    """`paths` of iteration `n` (conf/config.yaml: `iteration<N>.paths` over `paths`)."""
    paths = dict(conf["paths"])
    if n >= 2:
        paths.update(conf[f"iteration{n}"]["paths"])
    return paths


def placeholder_values(conf: dict, n: int) -> dict[str, str]:
    """The values of every placeholder a table template may use in iteration `n`."""
    def own(k: int) -> dict[str, str]:
        paths = iteration_paths(conf, k)
        values = dict(paths)
        values.update({f"{key}_onnx": str(Path(paths[key]).with_suffix(".onnx")) for key in ("model", "final_model")
                       if key in paths})
        return values

    out = {**key_vars(n), **own(n)}
    if n >= 2:
        out.update({f"prev_{k}": v for k, v in own(n - 1).items()})
    return out


@dataclass(frozen=True)
class Concrete:
    """A stage as DVC resolves it, for one iteration: what the rendered dvc.yaml must say."""

    cmd: str
    deps: tuple[str, ...]
    keys: tuple[str, ...]
    outs: tuple[tuple[str, bool, bool], ...]  # (path, cache, metric)


def _path(entry: str | Dep) -> str:
    return entry.path if isinstance(entry, Dep) else entry


def _cmd(stage: Stage, n: int) -> str:
    return f"python -m stages.{stage.name}" + (f" --iteration {n}" if n >= 2 else "")


def concrete(stage: Stage, n: int, conf: dict, code: list[str]) -> Concrete:
    """Stage `stage` in iteration `n`, straight from the table (no templating)."""
    def values(k: int) -> dict[str, str]:
        return placeholder_values(conf, k)

    deps = stage.deps + (stage.later_deps if n >= 2 else ())
    outs = stage.outs + (stage.later_outs if n >= 2 else ())
    return Concrete(_cmd(stage, n), tuple(dict.fromkeys([_path(t).format(**v) for t, v in expand(deps, n, values)]
                                                        + code)),
                    tuple(config_keys(stage, n)),
                    tuple((o.path.format(**values(n)), o.cache, o.metric) for o in outs))


# --- templating the later iterations -------------------------------------------------------------------------------


class _Template:
    """Renders table templates once for all later iterations: a placeholder whose value is the same in every one is
    written out, one that differs becomes `${item.<name>}` with its values in `later_iterations`."""

    def __init__(self, conf: dict):
        self.iterations = list(range(2, LAST_ITERATION + 1))
        self.values = {n: placeholder_values(conf, n) for n in self.iterations}
        self.of_iteration = {k: placeholder_values(conf, k) for k in range(1, LAST_ITERATION + 1)}
        self.vars: dict[int, dict[str, str]] = {n: {} for n in self.iterations}

    def render(self, template: str, binding: dict[int, dict[str, str]], prefix: str = "") -> str:
        out = []
        for literal, name, _, _ in string.Formatter().parse(template):
            out.append(literal)
            if name is None:
                continue
            values = {n: binding[n][name] for n in self.iterations}
            if len(set(values.values())) == 1:
                out.append(values[self.iterations[0]])
                continue
            var = name if values == {n: self.values[n][name] for n in self.iterations} else f"{prefix}{name}"
            for n, value in values.items():
                if self.vars[n].setdefault(var, value) != value:
                    raise GeneratorError(f"later_iterations: variable {var} would need two values in iteration {n}")
            out.append(f"${{item.{var}}}")
        return "".join(out)

    def entries(self, entries: tuple) -> list[tuple[Any, str]]:
        """(entry, rendered) per table entry; an earlier-iterations `Each` gives one per iteration it can name, which
        in an iteration where that one is not earlier repeats the iteration's own value (DVC counts it once)."""
        out = []
        for entry in entries:
            if isinstance(entry, Dep) and entry.first_only:
                continue
            if isinstance(entry, Each):
                last = entry.iterations(LAST_ITERATION).stop  # the widest range any later iteration has
                for k in range(entry.first, last):
                    binding = {n: self.of_iteration[k] if k < n or entry.upto != "earlier" else self.values[n]
                               for n in self.iterations}
                    out += [(t, self.render(_path(t), binding, prefix=f"earlier{k}_")) for t in entry.templates]
            else:
                out.append((entry, self.render(_path(entry), self.values)))
        return out


# --- writing dvc.yaml ---------------------------------------------------------------------------------------------


def _scalar(value: str) -> str:
    """`value` as a YAML scalar in flow or block context: plain where that reads back as the same string, else
    double-quoted (`${item.raw_dir}`: braces are flow indicators)."""
    if value and not any(c in value for c in "{}[],#\"'") and ": " not in value and value[0] not in "!&*?|>%@`-" \
            and yaml.safe_load(value) == value:
        return value
    return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _comment(text: str, indent: int) -> list[str]:
    return [" " * indent + "# " + line for line in textwrap.wrap(text, WIDTH - indent - 2)] if text else []


def _flow_list(head: str, items: list[tuple[str, str]], indent: int) -> list[str]:
    """`head: [a, b, …]` wrapped at WIDTH; an item with a note ends its line, the note as a comment."""
    lead = " " * indent + head + ": ["
    pad = " " * len(lead)
    lines: list[str] = []
    current = lead
    for i, (item, note) in enumerate(items):
        text = _scalar(item) + ("]" if i == len(items) - 1 else ",")
        fresh = current in (lead, pad)  # nothing on this line yet
        if not fresh and (note or len(current) + 1 + len(text) > WIDTH):
            lines.append(current)
            current, fresh = pad, True
        current += ("" if fresh else " ") + text
        if note:
            lines.append(f"{current}  # {note}")
            current = pad
    if current not in (lead, pad):
        lines.append(current)
    return lines if items else [lead + "]"]


def _out_lines(outs: list[tuple[str, Out]], indent: int) -> list[str]:
    lines = []
    for path, out in outs:
        opts = "{cache: false, persist: true}" if not out.cache else "{persist: true}"
        lines.append(" " * indent + f"- {_scalar(path)}: {opts}")
    return lines


def _stage_lines(name: str, cmd: str, stage: Stage, deps: list[tuple[str, str]], keys: list[str],
                 outs: list[tuple[str, Out]], indent: int) -> list[str]:
    pad = " " * indent
    lines = [pad + f"cmd: {cmd}"]
    if stage.always_changed:
        lines.append(pad + "always_changed: true")
    lines += _flow_list("deps", deps, indent)
    if keys or stage.whole_params:
        lines.append(pad + "params:")
        lines += [pad + f"  - {f}:  # the whole file" for f in stage.whole_params]
        if keys:
            lines += _flow_list(f"  - {RESOLVED}", [(k, "") for k in keys], indent)
    for field, metric in (("outs", False), ("metrics", True)):
        chosen = [(p, o) for p, o in outs if o.metric == metric]
        if chosen:
            lines.append(pad + f"{field}:")
            lines += _out_lines(chosen, indent + 2)
    return lines


HEADER = f"""\
# Generated by `{WRITE_COMMAND}` from the stage table in stages/table.py. Do not edit: change
# the table (or the code a stage imports) and regenerate; tests/stages/test_table.py fails while this file differs.
#
# Per stage: its data deps first (with why, where it is not obvious), then the project files its module runs (the
# closure of its imports, and the files that code reads; a directory stands for its files where the stage needs
# every one), so a code change re-runs exactly the stages it can affect. `params` are the keys of
# configs/resolved.yaml the stage reads (stages/keys.py), so a config edit re-runs exactly the stages that read the
# edited key. Every output is `persist: true`: DVC does not delete it before its stage runs, and every stage writes
# its outputs atomically, so a failed or interrupted stage leaves the last good outputs in place (the price: DVC's
# run-cache is off for these stages; docs/pipeline.md). Real recordings live in data/recordings, no stage's output.
#
# Data-collection iterations: the iteration-1 stages (collect … train) are written out; iterations 2 … N run the
# same stage code through `foreach` over `later_iterations` (DVC names them collect_iter@2, train_iter@3, …), whose
# items hold what differs between them: conf/config.yaml `iteration<N>.paths` and the previous iteration's (prev_*).
"""


def render(root: Path = PROJECT_ROOT, universe: set[str] | None = None, conf: dict | None = None) -> str:
    """The text of dvc.yaml for the project at `root` (`conf`: its conf/config.yaml). Checks that it reads back, for
    every stage and iteration, as exactly the stage the table defines (GeneratorError otherwise)."""
    conf = yaml.safe_load((root / "conf" / "config.yaml").read_text()) if conf is None else conf
    universe = project_files(root) if universe is None else universe
    code = {s.name: source_deps(s.name, root, universe) for s in STAGES}
    template = _Template(conf)
    body: list[str] = []
    for stage in STAGES:
        v1 = placeholder_values(conf, 1)
        deps1 = [(_path(t).format(**v), t.why if isinstance(t, Dep) else "")
                 for t, v in expand(stage.deps, 1, lambda k: placeholder_values(conf, k))]
        body += _comment(stage.comment, 2) + [f"  {stage.name}:"]
        body += _stage_lines(stage.name, _cmd(stage, 1), stage, deps1 + [(c, "") for c in code[stage.name]],
                             config_keys(stage, 1), [(o.path.format(**v1), o) for o in stage.outs], 4)
    for stage in STAGES:
        if not stage.iterated:
            continue
        deps = [(r, t.why if isinstance(t, Dep) else "") for t, r in template.entries(stage.deps + stage.later_deps)]
        keys = list(dict.fromkeys(r for _, r in template.entries(stage.keys + LATER_KEYS + stage.later_keys)))
        outs = [(template.render(o.path, template.values), o) for o in stage.outs + stage.later_outs]
        body += _comment(stage.later_comment, 2) + [f"  {stage.name}_iter:", "    foreach: ${later_iterations}",
                                                     "    do:"]
        body += _stage_lines(stage.name, f"python -m stages.{stage.name} --iteration ${{key}}", stage,
                             deps + [(c, "") for c in code[stage.name]], keys, outs, 6)
    head = ["vars:", "  - later_iterations:  # what differs between the later iterations (conf/config.yaml)"]
    order = list(placeholder_values(conf, LAST_ITERATION))  # its block, its paths, then the previous iteration's
    for n, values in template.vars.items():
        head.append(f'      "{n}":')
        head += [f"        {k}: {_scalar(values[k])}" for k in sorted(values, key=lambda k: (
            order.index(k) if k in order else len(order), k))]
    text = HEADER + "\n".join(head + ["stages:"] + body) + "\n"
    _check_rendered(text, conf, code)
    return text


def _check_rendered(text: str, conf: dict, code: dict[str, list[str]]) -> None:
    """Every stage of `text`, as DVC would resolve it, is exactly its table stage in its iteration."""
    resolved = _as_concrete(resolve_document(yaml.safe_load(text)))
    expected = {}
    for stage in STAGES:
        for n in ([1] + (list(range(2, LAST_ITERATION + 1)) if stage.iterated else [])):
            name = stage.name if n == 1 else f"{stage.name}_iter@{n}"
            expected[name] = concrete(stage, n, conf, code[stage.name])
    problems = _differences(expected, resolved)
    if problems:
        raise GeneratorError("the rendered dvc.yaml does not read back as the table says:\n" + "\n".join(problems))
    for line in text.splitlines():
        if len(line) > WIDTH + 2:
            raise GeneratorError(f"dvc.yaml line longer than {WIDTH + 2}: {line}")


def _as_concrete(stages: dict[str, dict]) -> dict[str, Concrete]:
    """{name: Concrete} of resolved dvc.yaml stages (set semantics for deps and keys: DVC counts a repeat once)."""
    out = {}
    for name, s in stages.items():
        keys: list[str] = []
        for entry in s.get("params") or []:
            if isinstance(entry, dict):
                for f, ks in entry.items():
                    keys += list(ks or []) if f == RESOLVED else []
            else:
                keys.append(str(entry))
        outs = []
        for field in ("outs", "metrics"):
            for entry in s.get(field) or []:
                (path, opts), = entry.items() if isinstance(entry, dict) else ((entry, {}),)
                outs.append((str(path), bool((opts or {}).get("cache", True)), field == "metrics"))
        out[name] = Concrete(str(s.get("cmd")), tuple(dict.fromkeys(map(str, s.get("deps") or []))),
                             tuple(dict.fromkeys(keys)), tuple(outs))
    return out


def _differences(expected: dict[str, Concrete], actual: dict[str, Concrete]) -> list[str]:
    """One line per stage and field that differ: what `actual` lacks and what it has beyond `expected`."""
    problems = [f"stage {name}: missing" for name in expected if name not in actual]
    problems += [f"stage {name}: not in the stage table" for name in actual if name not in expected]
    for name in (n for n in expected if n in actual):
        e, a = expected[name], actual[name]
        if e.cmd != a.cmd:
            problems.append(f"stage {name}: cmd is {a.cmd!r}, the table says {e.cmd!r}")
        for field in ("deps", "keys", "outs"):
            want, got = getattr(e, field), getattr(a, field)
            if field == "outs" and list(want) != list(got) or set(want) != set(got):
                what = "params" if field == "keys" else field
                lacks = [x for x in want if x not in got]
                extra = [x for x in got if x not in want]
                problems.append(f"stage {name}: {what} lacks {lacks or 'nothing'}, has extra {extra or 'nothing'}"
                                + (" (order)" if not lacks and not extra else ""))
    return problems


def drift(root: Path = PROJECT_ROOT) -> list[str]:
    """What differs between the committed dvc.yaml and the one the table gives: [] when none; else one line per
    stage and field, and the command that fixes it."""
    path = root / DVC_YAML
    return describe_drift(render(root), path.read_text() if path.is_file() else "")


def describe_drift(generated: str, current: str) -> list[str]:
    """[] if `current` is `generated`; else a first line with the command that fixes it, then one line per stage and
    field that differ, read as DVC resolves them (`foreach` expanded)."""
    if current == generated:
        return []
    try:
        problems = _differences(_as_concrete(resolve_document(yaml.safe_load(generated))),
                                _as_concrete(resolve_document(yaml.safe_load(current) or {})))
    except Exception as exc:  # noqa: BLE001 — a hand-broken file still gets the fix
        problems = [f"dvc.yaml cannot be read ({type(exc).__name__}: {exc})"]
    if not problems:
        problems = ["the stages agree; only comments, order or layout differ"]
    return [f"dvc.yaml is not what stages/table.py gives: run `{WRITE_COMMAND}`"] + problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m stages.dvc_yaml", description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--write", action="store_true", help="rewrite dvc.yaml")
    group.add_argument("--check", action="store_true", help="exit 1 if dvc.yaml differs, naming what differs")
    args = parser.parse_args(argv)
    try:
        if args.check:
            problems = drift()
            print("\n".join(problems) or "dvc.yaml is up to date")
            return 1 if problems else 0
        text = render()
    except GeneratorError as exc:
        print(f"stages.dvc_yaml: error: {exc}", file=sys.stderr)
        return 2
    if args.write:
        (PROJECT_ROOT / DVC_YAML).write_text(text)
        print(f"wrote {DVC_YAML}")
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
