"""Measure the package's import structure: import loops, upward arrows and cross-module private uses.

Reads the source with `ast` (nothing is imported), so it runs in a second on any checkout:

    python scripts/import_graph.py            # summary and every finding
    python scripts/import_graph.py --quiet    # summary only

Definitions (the target for each is 0; tests/test_structure.py keeps it so):

- **import loop**: a cycle among `lerobot_bavo` modules, counting imports at any depth (imports inside
  functions too: they hide a loop from Python, not from a reader).
- **upward arrow**: an import from a lower layer into a higher one, per `FORBIDDEN` below
  (`envs/` must not import `eval/`; `teacher/` must not import `datasets/`).
- **cross-module private use**: `obj._name` (called or read) on anything but `self` / `cls`, a
  private name imported from another module, or `getattr(obj, "_name")`: private names of our own
  modules and of LeRobot alike. `datasets/lerobot_private.py` is the one module allowed LeRobot's
  private names (its `check_private_api()` names each); `ALLOWED` lists the few private names of
  the standard library, numpy and torch that are their documented API.
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "lerobot_bavo"

# (importer prefix, imported prefix): an arrow from the first to the second runs back up.
FORBIDDEN = [
    ("lerobot_bavo.envs", "lerobot_bavo.eval"),
    ("lerobot_bavo.sim", "lerobot_bavo.envs"),
    ("lerobot_bavo.sim", "lerobot_bavo.eval"),
    ("lerobot_bavo.teacher", "lerobot_bavo.datasets"),
    ("lerobot_bavo.metrics", "lerobot_bavo.envs"),
    ("lerobot_bavo.metrics", "lerobot_bavo.eval"),
]


# Private-looking names that are their library's documented API.
ALLOWED = {"_exit", "_multiarray_umath", "_core"}
ALLOWED_PREFIXES = ("_foreach_",)  # torch's multi-tensor ops
PRIVATE_HOME = "lerobot_bavo.datasets.lerobot_private"


def is_private(name: str) -> bool:
    return (name.startswith("_") and not name.startswith("__") and name not in ALLOWED
            and not name.startswith(ALLOWED_PREFIXES))


def own_private_names(tree: ast.AST) -> set[str]:
    """Private names a module defines itself (functions, methods, classes, `self._x = ...`). Using one on
    another object (`other._x`) stays inside the module when no other module defines that name too."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            for t in node.targets if isinstance(node, ast.Assign) else [node.target]:
                if isinstance(t, ast.Attribute):
                    names.add(t.attr)
    return {n for n in names if is_private(n)}


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def resolve(importer: str, is_pkg: bool, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = importer.split(".")
    if not is_pkg:
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def scan(paths: list[Path]):
    modules = {module_name(p): p for p in paths}
    trees = {mod: ast.parse(path.read_text(), str(path)) for mod, path in modules.items()}
    defined_in: dict[str, set[str]] = defaultdict(set)
    for mod, tree in trees.items():
        for name in own_private_names(tree):
            defined_in[name].add(mod)
    edges: dict[str, set[str]] = defaultdict(set)
    private: list[tuple[str, int, str]] = []  # (module, line, expression)
    for mod, path in modules.items():
        tree = trees[mod]
        is_pkg = path.name == "__init__.py"
        own = {name for name, where in defined_in.items() if where == {mod}}
        for node in ast.walk(tree):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = resolve(mod, is_pkg, node)
                targets = [base]
                targets += [f"{base}.{a.name}" for a in node.names]
            for t in targets:
                # the longest module prefix of the target that is one of ours
                parts = t.split(".")
                for k in range(len(parts), 0, -1):
                    cand = ".".join(parts[:k])
                    if cand in modules:
                        if cand != mod and not mod.startswith(cand + "."):
                            edges[mod].add(cand)
                        break
            if mod == PRIVATE_HOME:
                continue
            if isinstance(node, ast.Attribute) and is_private(node.attr) and node.attr not in own:
                owner = node.value
                is_self = isinstance(owner, ast.Name) and owner.id in ("self", "cls")
                is_super = (isinstance(owner, ast.Call) and isinstance(owner.func, ast.Name)
                            and owner.func.id == "super")
                if not (is_self or is_super):
                    private.append((mod, node.lineno, ast.unparse(node)))
            if isinstance(node, ast.ImportFrom):
                base = resolve(mod, is_pkg, node)
                for a in node.names:
                    if is_private(a.name) and base != mod:
                        private.append((mod, node.lineno, f"from {base} import {a.name}"))
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                    and node.func.id in ("getattr", "setattr", "hasattr") and len(node.args) >= 2
                    and isinstance(node.args[1], ast.Constant) and isinstance(node.args[1].value, str)
                    and is_private(node.args[1].value)
                    and not (isinstance(node.args[0], ast.Name) and node.args[0].id in ("self", "cls"))):
                private.append((mod, node.lineno, ast.unparse(node)))
    return modules, edges, sorted(private)


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]
    sys.setrecursionlimit(10000)

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in list(edges):
        if v not in index:
            visit(v)
    return out


def upward_arrows(edges: dict[str, set[str]]) -> list[tuple[str, str]]:
    """The imports that run from a lower layer up, per `FORBIDDEN`."""
    def within(name: str, prefix: str) -> bool:
        return name == prefix or name.startswith(prefix + ".")

    return [(a, b) for a, targets in sorted(edges.items()) for b in sorted(targets)
            for lo, hi in FORBIDDEN if within(a, lo) and within(b, hi)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quiet", action="store_true", help="print the summary only")
    args = parser.parse_args(argv)
    paths = sorted((ROOT / PACKAGE).rglob("*.py"))
    modules, edges, private = scan(paths)
    loops = cycles(edges)
    upward = upward_arrows(edges)
    print(f"modules: {len(modules)}  import loops: {len(loops)}  upward arrows: {len(upward)}  "
          f"cross-module private uses: {len(private)}")
    if not args.quiet:
        for comp in loops:
            print("loop:", " <-> ".join(comp))
        for a, b in upward:
            print(f"upward: {a} -> {b}")
        for mod, line, expr in private:
            print(f"private: {mod}:{line} {expr}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
