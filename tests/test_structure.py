"""The layers of docs/design.md, Part I, "Layers": read from the sources (ast), so that a change that breaks one fails
here rather than in a reader's head.

- no import cycle among depthguard's modules, counting the imports inside functions too;
- no private name crosses a package: a module imports another package's modules and names only if they are public
  (the kernel layer ``depthguard.kernels`` is a package like the others);
- the lab imports only the library's public names;
- every numba kernel lives in the kernel layer (the baselines' kernel excepted: it is the comparison, not the
  product).
"""

from __future__ import annotations

import ast
import itertools
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = ROOT / "depthguard"
LAB = ROOT / "lab" / "depthguard_lab"


def modules(package: Path) -> dict[str, Path]:
    """Dotted module name -> source file, for every module of ``package`` (a folder)."""
    out = {}
    for path in sorted(package.rglob("*.py")):
        name = ".".join(path.relative_to(package.parent).with_suffix("").parts)
        out[name.removesuffix(".__init__")] = path
    return out


def imports(path: Path) -> list[tuple[str, list[str], int]]:
    """(module, names imported from it, line) for every absolute import of depthguard in ``path``, wherever it
    stands (inside functions too)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module \
                and node.module.split(".")[0] == "depthguard":
            out.append((node.module, [alias.name for alias in node.names], node.lineno))
        elif isinstance(node, ast.Import):
            out.extend((alias.name, [], node.lineno) for alias in node.names
                       if alias.name.split(".")[0] == "depthguard")
    return out


def package_of(name: str, known: dict) -> str:
    """The package a module belongs to: ``depthguard.depth._prepare`` -> ``depthguard.depth``; a module of the top
    level (``depthguard._monitor``, ``depthguard.config``) -> ``depthguard``."""
    parts = name.split(".")
    if len(parts) >= 2 and (LIBRARY / parts[1]).is_dir():
        return ".".join(parts[:2])
    return parts[0]


def import_graph(known: dict) -> dict[str, set[str]]:
    """Module -> the depthguard modules it imports (a name imported from a package counts as that package's module
    when it is one, else as the package)."""
    graph = {name: set() for name in known}
    for name, path in known.items():
        for module, names, _ in imports(path):
            targets = [f"{module}.{n}" if f"{module}.{n}" in known else module for n in names] or [module]
            for target in targets:
                while target and target not in known:
                    target = target.rpartition(".")[0]
                if target and target != name:
                    graph[name].add(target)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan): each holds an import cycle."""
    index, low, stack, on_stack, found, counter = {}, {}, [], set(), [], itertools.count()

    def visit(v):
        index[v] = low[v] = next(counter)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * len(graph) + 100))
    try:
        for v in sorted(graph):
            if v not in index:
                visit(v)
    finally:
        sys.setrecursionlimit(limit)
    return found


def is_private(part: str) -> bool:
    return part.startswith("_") and not part.startswith("__")


def test_the_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle_in_the_library():
    known = modules(LIBRARY)
    assert len(known) > 60
    assert cycles(import_graph(known)) == []


def test_no_private_name_crosses_a_package():
    known = modules(LIBRARY)
    crossings = []
    for name, path in known.items():
        here = package_of(name, known)
        for module, names, line in imports(path):
            if module.split(".")[0] != "depthguard" or package_of(module, known) == here:
                continue
            private = [p for p in module.split(".")[1:] if is_private(p)] + [n for n in names if is_private(n)]
            if private:
                crossings.append(f"{path.relative_to(ROOT)}:{line}: {module} {private}")
    assert crossings == []


def test_the_lab_imports_only_public_names_of_the_library():
    crossings = []
    for name, path in modules(LAB).items():
        for module, names, line in imports(path):
            private = [p for p in module.split(".")[1:] if is_private(p)] + [n for n in names if is_private(n)]
            if private:
                crossings.append(f"{path.relative_to(ROOT)}:{line}: {module} {private}")
    assert crossings == []


def test_the_library_does_not_import_the_lab():
    offenders = [f"{path.relative_to(ROOT)}:{node.lineno}" for path in modules(LIBRARY).values()
                 for node in ast.walk(ast.parse(path.read_text()))
                 if (isinstance(node, ast.ImportFrom) and (node.module or "").startswith("depthguard_lab"))
                 or (isinstance(node, ast.Import) and any(a.name.startswith("depthguard_lab") for a in node.names))]
    assert offenders == []


def test_every_kernel_lives_in_the_kernel_layer():
    from depthguard.kernels import jit

    outside = [name for name in jit.KERNEL_MODULES if not name.startswith("depthguard.kernels.")]
    assert outside == ["depthguard.baselines"]


def test_every_kernel_releases_the_gil():
    """Every kernel is compiled with ``nogil``: a thread that receives frames runs while another prepares a set
    (benchmarks/bench_gil.py measures it)."""
    import importlib

    from numba.core.registry import CPUDispatcher

    from depthguard.kernels import jit

    kernels = [(name, attr, value) for name in jit.KERNEL_MODULES
               for attr, value in vars(importlib.import_module(name)).items() if isinstance(value, CPUDispatcher)
               and value.py_func.__module__ == name]
    assert len(kernels) > 80
    holding = [f"{name}.{attr}" for name, attr, value in kernels if not value.targetoptions.get("nogil")]
    assert holding == []
