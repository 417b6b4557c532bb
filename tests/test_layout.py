"""The package layout of src/expoctl: no import circles, and no module takes another module's `_private` name.

Parses every module with `ast` (nothing is imported), so function-level imports count as much as top-level ones.
An import of a package counts as an edge to its `__init__`; an import of a submodule as an edge to that module (not
to the packages above it, which are already initialising when their own modules import each other's siblings).
"""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
ROOT_PACKAGE = "expoctl"


def module_files(src: Path = SRC, root: str = ROOT_PACKAGE) -> dict[str, Path]:
    """Dotted module name -> file, for every .py under src/<root> (a package's name maps to its __init__.py)."""
    out = {}
    for path in sorted((src / root).rglob("*.py")):
        parts = list(path.relative_to(src).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        if is_package:
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def scan(files: dict[str, Path]) -> tuple[dict[str, set[str]], list[str]]:
    """(import graph over the given modules, cross-module `_private` uses as 'importer: module._name (line)')."""
    graph: dict[str, set[str]] = {m: set() for m in files}
    private: list[str] = []

    def target(dotted: str) -> str | None:
        # the longest prefix of `dotted` that is one of our modules
        parts = dotted.split(".")
        for n in range(len(parts), 0, -1):
            cand = ".".join(parts[:n])
            if cand in files:
                return cand
        return None

    for mod, path in files.items():
        is_package = path.name == "__init__.py"
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        aliases: dict[str, str] = {}  # local name -> one of our modules bound to it

        def edge(dst: str | None) -> None:
            if dst is not None and dst != mod:
                graph[mod].add(dst)

        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    dst = target(a.name)
                    edge(dst)
                    if dst is not None and a.asname and dst == a.name:
                        aliases[a.asname] = dst
            elif isinstance(node, ast.ImportFrom):
                base = _resolve(mod, is_package, node)
                if target(base) is None and base.split(".")[0] != ROOT_PACKAGE:
                    continue
                for a in node.names:
                    full = f"{base}.{a.name}" if base else a.name
                    if full in files:  # a submodule
                        edge(full)
                        aliases[a.asname or a.name] = full
                        continue
                    src_mod = target(base)
                    edge(src_mod)
                    if _is_private(a.name) and src_mod != mod:
                        private.append(f"{mod}: from {base} import {a.name} (line {node.lineno})")
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and _is_private(node.attr):
                dotted = _dotted(node.value)
                if dotted is None:
                    continue
                head, _, rest = dotted.partition(".")
                owner = aliases.get(head)
                if owner is not None:
                    owner = target(f"{owner}.{rest}" if rest else owner)
                elif head == ROOT_PACKAGE:
                    owner = target(dotted)
                if owner is not None and owner != mod:
                    private.append(f"{mod}: {dotted}.{node.attr} (line {node.lineno})")
    return graph, private


def _dotted(node: ast.expr) -> str | None:
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if not isinstance(node, ast.Name):
        return None
    parts.append(node.id)
    return ".".join(reversed(parts))


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def package_graph(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """The module graph collapsed to expoctl's top-level packages and modules (expoctl.sim.collect -> expoctl.sim)."""
    top = lambda m: ".".join(m.split(".")[:2])  # noqa: E731
    out: dict[str, set[str]] = {}
    for a, targets in graph.items():
        out.setdefault(top(a), set()).update(top(b) for b in targets if top(b) != top(a))
    return out


def _circles(cycles: list[list[str]]) -> str:
    return "import circles: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_no_import_cycles():
    graph, _ = scan(module_files())
    cycles = find_cycles(graph)
    assert not cycles, _circles(cycles)


def test_packages_depend_on_each_other_without_cycles():
    # so a package's __init__ may import its own modules without ever running into a half-initialised package
    cycles = find_cycles(package_graph(scan(module_files())[0]))
    assert not cycles, _circles(cycles)


def test_no_private_imports_across_modules():
    _, private = scan(module_files())
    assert not private, "private names used outside their module:\n" + "\n".join(private)


def test_every_package_declares_its_public_names():
    """Each package's __init__ has an `__all__` listing exactly the public names it binds (imports and definitions)."""
    for name, path in module_files().items():
        if path.name != "__init__.py" or name == ROOT_PACKAGE:
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        bound, declared = set(), None
        for node in tree.body:
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                bound.update((a.asname or a.name).split(".")[0] for a in node.names)
            elif isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                bound.add(node.name)
            elif isinstance(node, ast.Assign):
                for t in node.targets:
                    if isinstance(t, ast.Name) and t.id == "__all__":
                        declared = set(ast.literal_eval(node.value))
                    elif isinstance(t, ast.Name):
                        bound.add(t.id)
        bound = {n for n in bound if not n.startswith("_") and n != "annotations"}
        assert declared is not None, f"{name}: no __all__"
        assert declared == bound, f"{name}: __all__ {sorted(declared ^ bound)} differ from what __init__ binds"


def test_checker_catches_a_cycle_and_a_private_import(tmp_path):
    pkg = tmp_path / ROOT_PACKAGE
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("from expoctl.sub.a import f\n")
    (pkg / "sub" / "a.py").write_text("def f():\n    from .b import g\n    return g()\n")
    (pkg / "sub" / "b.py").write_text("import expoctl.c as c\n\ndef g():\n    return c._h()\n")
    (pkg / "c.py").write_text("def _h():\n    from expoctl.sub import a\n    return 1\n")
    (pkg / "d.py").write_text("from expoctl.c import _h\n")
    graph, private = scan(module_files(tmp_path))
    assert find_cycles(graph) == [["expoctl.c", "expoctl.sub.a", "expoctl.sub.b"]]
    assert find_cycles(package_graph(graph)) == [["expoctl.c", "expoctl.sub"]]
    assert private == ["expoctl.d: from expoctl.c import _h (line 1)", "expoctl.sub.b: c._h (line 4)"]
