"""dvc.yaml's `deps` cover all the code a stage runs, so a code change re-runs every stage it affects.

For each stage DVC resolves from dvc.yaml (the `foreach` iterations included), the stage's module `stages.<name>`
(from its cmd) is followed through every project import it executes, read with `ast`: top-level and function-local
`import` / `from … import` (lazy imports run too), relative imports, the parent packages' `__init__.py` that Python
runs before a submodule, and `from pkg import name` where `name` is a submodule. Only `if TYPE_CHECKING:` blocks,
which never run, are skipped. Every file of that closure, and every non-Python file the code reads from the source
tree at run time (RUNTIME_DATA), must lie under a declared dep (the file itself or a directory holding it).

docs/pipeline.md's mermaid DAG (`dvc dag --md`) is checked against the stages and edges DVC resolves.
"""

from __future__ import annotations

import ast
import re
from collections import deque
from pathlib import Path

import pytest
import yaml

PROJECT_ROOT = Path(__file__).resolve().parents[2]
#: top-level project package → its directory; any other import (numpy, torch, …) is not followed
PACKAGE_DIRS = {"stages": PROJECT_ROOT / "stages", "expoctl": PROJECT_ROOT / "src" / "expoctl"}
#: where declared source deps live: one that no longer exists is stale
SOURCE_PREFIXES = ("src/", "stages/", "conf/")


def _city_dir() -> str:
    return yaml.safe_load((PROJECT_ROOT / "conf" / "world" / "default.yaml").read_text())["city_dir"]


#: Non-Python files a project module reads from the source tree when it runs: module → glob patterns (relative to
#: the project root). test_runtime_data_table_is_complete keeps it honest: a module that locates files through
#: `__file__` or package data must be listed here (or in NO_RUNTIME_DATA).
RUNTIME_DATA: dict[str, list[str]] = {
    # _SHADERS = Path(__file__).with_name("shaders"): the EGL back end's GLSL sources
    "src/expoctl/world/gl_renderer.py": ["src/expoctl/world/shaders/*.glsl"],
    # city_config reads <world.city_dir>/<name>.yaml before the packaged defaults (conf/world/default.yaml city_dir)
    "src/expoctl/world/cities.py": [f"{_city_dir()}/*.yaml"],
    # compose_config(conf_dir=PROJECT_ROOT / "conf"): the whole Hydra tree
    "stages/compose.py": ["conf/**/*.yaml"],
    # the fixed paths.* defaults: Path(__file__).resolve().parents[1] / "conf" / "config.yaml"
    "stages/config_check.py": ["conf/config.yaml"],
}
#: modules that use `__file__` only to locate the project root (the files they read are params or data deps). Not
#: listed either: stages/dvcfile.py reads dvc.yaml and dvc.lock, only to name what a failed stage left behind.
#: stages/numerics.py reads configs/resolved.yaml's `numerics` block, a param of every computing stage.
NO_RUNTIME_DATA = {"stages/project.py", "stages/sweep.py", "stages/numerics.py"}


def _rel(path: Path) -> str:
    return path.relative_to(PROJECT_ROOT).as_posix()


def module_file(name: str) -> Path | None:
    """The file of project module `name` (a package's __init__.py), or None (not a project module)."""
    top, *rest = name.split(".")
    if top not in PACKAGE_DIRS:
        return None
    base = PACKAGE_DIRS[top].joinpath(*rest)
    if (base / "__init__.py").is_file():
        return base / "__init__.py"
    if rest and base.with_suffix(".py").is_file():
        return base.with_suffix(".py")
    return None


def _module_name(path: Path) -> str:
    for top, root in PACKAGE_DIRS.items():
        if path.is_relative_to(root):
            parts = [top, *path.relative_to(root).with_suffix("").parts]
            return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
    raise ValueError(path)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _with_parents(name: str) -> list[str]:
    """'a.b.c' → ['a', 'a.b', 'a.b.c']: importing a submodule runs its parent packages first."""
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts) + 1)]


def imported_names(path: Path) -> set[str]:
    """Every module name an import statement anywhere in `path` (functions included, TYPE_CHECKING blocks not) may
    load; names that are not project modules are filtered out by the caller."""
    module = _module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    names: set[str] = set()

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.orelse:
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
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(ast.parse(path.read_text(), str(path)))
    return names


def import_closure(module: str) -> set[str]:
    """The project files (relative paths) `python -m <module>` runs, through every import transitively."""
    todo = deque(_with_parents(module))
    seen: set[str] = set()
    files: set[str] = set()
    while todo:
        name = todo.popleft()
        if name in seen:
            continue
        seen.add(name)
        path = module_file(name)
        if path is None:
            continue
        files.add(_rel(path))
        todo.extend(imported_names(path) - seen)
    return files


def runtime_data(files: set[str]) -> set[str]:
    out = set()
    for module in sorted(files & RUNTIME_DATA.keys()):
        for pattern in RUNTIME_DATA[module]:
            matched = {_rel(p) for p in PROJECT_ROOT.glob(pattern) if p.is_file()}
            assert matched, f"RUNTIME_DATA[{module!r}]: {pattern} matches no file"
            out |= matched
    return out


def is_covered(path: str, deps: list[str]) -> bool:
    return any(path == d or path.startswith(d.rstrip("/") + "/") for d in deps)


@pytest.fixture(scope="module")
def dvc_stages() -> dict[str, tuple[str, list[str], bool]]:
    """{stage name: (module its cmd runs, declared deps, always_changed)} as DVC resolves dvc.yaml."""
    from dvc.repo import Repo

    out = {}
    for s in Repo(str(PROJECT_ROOT)).index.stages:
        m = re.match(r"python -m (stages\.\w+)\b", s.cmd)
        assert m, f"stage {s.name}: cmd {s.cmd!r} is not `python -m stages.<name> …`"
        deps = [str(d) for d in s.deps if type(d).__name__ != "ParamsDependency"]
        out[s.name] = (m[1], deps, bool(s.always_changed))
    return out


def test_closure_follows_lazy_relative_and_package_imports():
    """The closure is the real one: function-local imports, parent packages and `from pkg import submodule`."""
    train = import_closure("stages.train")
    # stages.train imports expoctl.config_reader inside configs() and stages.project inside _path()
    assert {"stages/__init__.py", "stages/train.py", "stages/project.py", "src/expoctl/__init__.py",
            "src/expoctl/config_reader.py", "src/expoctl/net/__init__.py", "src/expoctl/net/model.py"} <= train
    assert "stages/sweep.py" not in train
    evaluate = import_closure("stages.evaluate")
    assert {"src/expoctl/evaluation/inputs.py", "src/expoctl/sim/collect.py", "src/expoctl/sim/protocol.py",
            "src/expoctl/config_reader.py"} <= evaluate


def test_every_stage_depends_on_the_code_and_files_it_runs(dvc_stages):
    assert "sweep" not in dvc_stages  # stages/sweep.py is a Hydra entry point, not a DVC stage
    missing, stale = {}, {}
    for name, (module, deps, always_changed) in sorted(dvc_stages.items()):
        files = import_closure(module)
        assert _rel(module_file(module)) in files
        needed = sorted(files | runtime_data(files))
        # an `always_changed: true` stage runs on every `dvc repro` whatever its deps say
        if not always_changed and (gaps := [f for f in needed if not is_covered(f, deps)]):
            missing[name] = gaps
        if gone := [d for d in deps if d.startswith(SOURCE_PREFIXES) and not (PROJECT_ROOT / d).exists()]:
            stale[name] = gone
    report = "".join(f"\n  {name}: {', '.join(paths)}" for name, paths in missing.items())
    assert not missing, f"dvc.yaml: these stages run code or read files they do not list in deps:{report}"
    report = "".join(f"\n  {name}: {', '.join(paths)}" for name, paths in stale.items())
    assert not stale, f"dvc.yaml: these stages list source deps that no longer exist:{report}"


def test_runtime_data_table_is_complete():
    """A module that finds files next to itself (`__file__`, package resources) is listed in RUNTIME_DATA."""
    pattern = re.compile(r"__file__|importlib\.resources|importlib_resources|pkgutil\.get_data|pkg_resources")
    users = {_rel(p) for root in PACKAGE_DIRS.values() for p in root.rglob("*.py") if pattern.search(p.read_text())}
    unlisted = sorted(users - RUNTIME_DATA.keys() - NO_RUNTIME_DATA)
    assert not unlisted, f"add to RUNTIME_DATA the files these modules read (or to NO_RUNTIME_DATA): {unlisted}"
    for module in RUNTIME_DATA.keys() | NO_RUNTIME_DATA:
        assert (PROJECT_ROOT / module).is_file(), f"{module} no longer exists"


def _mermaid_dag() -> tuple[set[str], set[tuple[str, str]]]:
    text = (PROJECT_ROOT / "docs" / "pipeline.md").read_text()
    m = re.search(r"^## The DAG\n.*?^```mermaid\n(.*?)^```", text, re.S | re.M)
    assert m, "docs/pipeline.md: no ```mermaid block under '## The DAG' (paste `dvc dag --md`)"
    labels = dict(re.findall(r'^\s*(\w+)\["([^"]+)"\]', m[1], re.M))
    arrows = re.findall(r"^\s*(\w+)-->(\w+)\s*$", m[1], re.M)
    unnamed = sorted({node for arrow in arrows for node in arrow} - labels.keys())
    assert not unnamed, f"docs/pipeline.md DAG: edges from or to undeclared nodes {unnamed}; regenerate it"
    return set(labels.values()), {(labels[a], labels[b]) for a, b in arrows}


def test_docs_dag_matches_dvc():
    """docs/pipeline.md's DAG is `dvc dag --md`: regenerate it when a stage or a dependency between stages changes."""
    from dvc.repo import Repo

    repo = Repo(str(PROJECT_ROOT))
    graph = repo.index.graph  # edge stage → the stage it depends on
    stages = {s.name for s in repo.index.stages}
    edges = {(dep.name, stage.name) for stage, dep in graph.edges}
    documented, documented_edges = _mermaid_dag()
    assert documented == stages, (f"docs/pipeline.md DAG: missing {sorted(stages - documented)}, "
                                  f"extra {sorted(documented - stages)}; regenerate with `dvc dag --md`")
    assert documented_edges == edges, (f"docs/pipeline.md DAG edges: missing {sorted(edges - documented_edges)}, "
                                       f"extra {sorted(documented_edges - edges)}; regenerate with `dvc dag --md`")
