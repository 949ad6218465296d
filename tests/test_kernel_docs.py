"""Every argument of every kernel is documented (the kernel layer's docstrings).

Reads the kernel modules' sources with ``ast`` (nothing is imported, so neither numba nor a compile is needed) and
checks that every top-level function of ``depthguard/kernels`` (all modules but ``__init__.py`` and ``jit.py``) has a
docstring, and that each of its arguments is named, as a whole word, in that docstring or in its module's glossary:
the section of the module docstring that starts with a line ``Arguments used throughout:``, a bullet list whose
bullets each start with the backquoted names they define, as in the line "- ``X, Y, Z``: float64, metres, ...". A
name in the glossary counts as documented for every function of its module.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

#: The kernel layer's folder; a test (or a check of another copy) may point :func:`offenders` elsewhere.
KERNELS = Path(__file__).resolve().parents[1] / "depthguard" / "kernels"

#: Modules of the layer that hold no kernels of their own.
SKIPPED = ("__init__.py", "jit.py")

GLOSSARY_HEADER = "Arguments used throughout:"


def glossary_names(module_doc: str | None) -> set[str]:
    """The argument names the module docstring's ``Arguments used throughout:`` section defines: the backquoted names
    at the start of each of its bullets, split at commas. The section runs from its header line to the first line
    after it that is neither blank, nor a bullet (``- ``), nor indented (a bullet's continuation)."""
    if not module_doc:
        return set()
    lines = module_doc.splitlines()
    try:
        start = next(i for i, line in enumerate(lines) if line.strip() == GLOSSARY_HEADER)
    except StopIteration:
        return set()
    names: set[str] = set()
    for line in lines[start + 1:]:
        if not line.strip() or line[:1].isspace():
            continue  # a blank line, or a bullet's continuation
        if not line.startswith("- "):
            break
        head = re.match(r"-\s+((?:``[^`]+``\s*,?\s*)+)", line)
        if head is None:
            continue
        for group in re.findall(r"``([^`]+)``", head.group(1)):
            names.update(name.strip() for name in group.split(",") if name.strip())
    return names


def _named(name: str, text: str) -> bool:
    """Whether ``name`` occurs in ``text`` as a whole word (not as part of a longer identifier)."""
    return re.search(r"(?<![A-Za-z0-9_])" + re.escape(name) + r"(?![A-Za-z0-9_])", text) is not None


def _arguments(function: ast.FunctionDef) -> list[str]:
    args = function.args
    names = [a.arg for a in args.posonlyargs + args.args + args.kwonlyargs]
    names += [a.arg for a in (args.vararg, args.kwarg) if a is not None]
    return names


def kernel_modules(folder: Path = KERNELS) -> list[Path]:
    """The kernel modules of ``folder``: every ``*.py`` but :data:`SKIPPED`, sorted."""
    return sorted(path for path in Path(folder).glob("*.py") if path.name not in SKIPPED)


def offenders(folder: Path = KERNELS) -> list[tuple[str, str, str]]:
    """(module, function, argument) for every argument of a top-level function of the kernel modules in ``folder``
    that neither the function's docstring nor the module's glossary names; argument ``"<no docstring>"`` for a
    function without a docstring (its arguments may still be covered by the glossary, and are reported when not)."""
    found = []
    for path in kernel_modules(folder):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        glossary = glossary_names(ast.get_docstring(tree))
        for node in tree.body:
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            doc = ast.get_docstring(node)
            if not doc:
                found.append((path.name, node.name, "<no docstring>"))
            for name in _arguments(node):
                if name not in glossary and not _named(name, doc or ""):
                    found.append((path.name, node.name, name))
    return found


def test_the_kernel_modules_are_there():
    modules = kernel_modules()
    assert modules, f"no kernel modules found in {KERNELS}"


def test_every_kernel_argument_is_documented():
    missing = offenders()
    assert not missing, f"{len(missing)} kernel arguments undocumented or functions without a docstring " \
        "(module, function, argument):\n" + \
        "\n".join(f"  {module} {function}: {argument}" for module, function, argument in missing)


def test_the_glossary_parser_reads_bullets():
    doc = "Intro.\n\nArguments used throughout:\n\n- ``X, Y, Z``: float64, metres,\n  the point ``P``.\n" \
          "- ``rho``, ``block``: radius; side.\n\nMore text.\n\n- ``later``: another list, not the glossary.\n"
    assert glossary_names(doc) == {"X", "Y", "Z", "rho", "block"}
    assert glossary_names("Intro.\n\n- ``X``: a list, but no glossary.\n") == set()


def test_an_undocumented_argument_is_reported(tmp_path):
    (tmp_path / "jit.py").write_text("def kernel(f):\n    return f\n")
    (tmp_path / "sample.py").write_text(
        '"""Kernels.\n\nArguments used throughout:\n- ``X, Y``: float64 metres.\n"""\n\n\n'
        'def documented(X, Y, rho):\n    """Uses rho (metres)."""\n\n\n'
        'def undocumented(X, rho_max, width):\n    """Uses rho and the width2 of nothing."""\n\n\n'
        'def bare(Y, q):\n    return q\n')
    assert offenders(tmp_path) == [("sample.py", "undocumented", "rho_max"), ("sample.py", "undocumented", "width"),
                                   ("sample.py", "bare", "<no docstring>"), ("sample.py", "bare", "q")]
