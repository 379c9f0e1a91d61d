"""The package's layers: every module imports only its own layer and the layers below.

Parsed from the source with :mod:`ast` (nothing is imported), so the check sees
function-local imports too. The layers, lowest first (docs/architecture.md):

    core < model < io < color < reference < device < deliver < pipeline < tools < console

``python tests/test_architecture.py [PACKAGE_DIR]`` prints the violations of any
tree (for instance an older checkout's ``clphong/``) and exits 1 if there are any.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

LAYERS = ("core", "model", "io", "color", "reference", "device", "deliver", "pipeline", "tools",
          "console")
PACKAGE = Path(__file__).resolve().parent.parent / "clphong"
#: Third-party packages only these layers may import (the device layer owns OpenCL).
OWNED = {"pyopencl": {"device"}}


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports(root: Path = PACKAGE) -> dict[str, list[tuple[str, int, bool]]]:
    """module -> [(imported module, line, function-local)] for every import in ``root``."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        name = module_name(path, root)
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        tree = ast.parse(path.read_text(encoding="utf-8"))
        top = {id(n) for n in tree.body}
        found = []
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - node.level + 1]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                # ``from pkg import name``: name may itself be a module of pkg
                targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
            else:
                continue
            for t in targets:
                found.append((t, node.lineno, id(node) not in top))
        out[name] = found
    return out


def layer_of(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def violations(root: Path = PACKAGE) -> list[str]:
    """Every import circle, upward import, forbidden import and hidden local import."""
    graph = imports(root)
    modules = set(graph)
    problems = []
    edges: dict[str, set[str]] = {m: set() for m in modules}
    for mod, found in graph.items():
        for target, line, local in found:
            if target in modules and target != mod and not mod.startswith(target + "."):
                # ``target`` is a clphong module (a parent package's __init__ aside)
                edges[mod].add(target)
                if local:
                    problems.append(f"{mod}:{line}: function-local import of {target} "
                                    "(hides a circle; import it at the top)")
                a, b = layer_of(mod), layer_of(target)
                if a and b and LAYERS.index(b) > LAYERS.index(a):
                    problems.append(f"{mod}:{line}: imports {target}, a higher layer ({b} > {a})")
            top = target.split(".")[0]
            if top in OWNED and layer_of(mod) not in OWNED[top]:
                problems.append(f"{mod}:{line}: imports {top}, which only "
                                f"{', '.join(sorted(OWNED[top]))}/ may import")
        if layer_of(mod) == "reference":
            for target, line, _ in found:
                if layer_of(target) == "device" or target.split(".")[0] == "pyopencl":
                    problems.append(f"{mod}:{line}: the float64 reference imports {target}")
    for mod in modules:
        if layer_of(mod) is None and mod.count(".") == 1 and mod.split(".")[1] not in ("__main__",):
            problems.append(f"{mod}: a module outside the layers (put it in one of {', '.join(LAYERS)})")
    problems += [f"import circle: {' -> '.join(c)}" for c in _circles(edges)]
    return problems


def _circles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges[v]):
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

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def test_no_import_circles_upward_imports_or_hidden_local_imports():
    problems = violations()
    assert not problems, "\n".join(problems)


def test_the_checker_finds_a_circle_an_upward_import_and_a_local_import(tmp_path):
    """The check can fail: a made-up package with each fault is caught."""
    pkg = tmp_path / "clphong"
    for layer in ("core", "model", "device", "reference"):
        (pkg / layer).mkdir(parents=True)
        (pkg / layer / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "core" / "a.py").write_text("from ..model.b import x\n")             # upward
    (pkg / "model" / "b.py").write_text("from ..core.a import y\n")             # circle a <-> b
    (pkg / "reference" / "c.py").write_text("def f():\n    from ..core import a\n"
                                            "import pyopencl\n")               # local, pyopencl
    (pkg / "flat.py").write_text("")                                           # outside the layers
    text = "\n".join(violations(pkg))
    assert "clphong.core.a:1: imports clphong.model.b, a higher layer" in text
    assert "import circle: clphong.core.a -> clphong.model.b" in text
    assert "clphong.reference.c:2: function-local import of clphong.core.a" in text
    assert "clphong.reference.c:3: imports pyopencl, which only device/ may import" in text
    assert "the float64 reference imports pyopencl" in text
    assert "clphong.flat: a module outside the layers" in text


def test_nothing_imports_the_console():
    graph = imports()
    users = [m for m, found in graph.items() for t, _, _ in found
             if layer_of(t) == "console" and layer_of(m) != "console" and m != "clphong.__main__"]
    assert not users, users


if __name__ == "__main__":
    root = Path(sys.argv[1]).resolve() if len(sys.argv) > 1 else PACKAGE
    found = violations(root)
    print("\n".join(found) or "no violations")
    sys.exit(1 if found else 0)
