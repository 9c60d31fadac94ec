"""The modules of gpja.render import one another without a circle (every import, also inside functions)."""
from __future__ import annotations

import ast
from pathlib import Path

import gpja.render

RENDER = Path(gpja.render.__file__).parent


def imported_render_modules(path: Path) -> set[str]:
    """Names of the gpja.render modules (``"__init__"`` for the package itself) a file imports."""
    modules = {p.stem for p in RENDER.glob("*.py")}
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from . import x / from .passes import y
                base = "gpja.render" + (f".{base}" if base else "")
            names = [base] + [f"{base}.{alias.name}" for alias in node.names]
        else:
            continue
        for name in names:
            parts = name.split(".")
            if parts[:2] != ["gpja", "render"]:
                continue
            if len(parts) == 2:
                # "from gpja.render import x": a submodule x, or a name re-exported by the package
                if isinstance(node, ast.ImportFrom) and any(a.name in modules for a in node.names):
                    continue
                found.add("__init__")
            elif parts[2] in modules:
                found.add(parts[2])
    return found


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle of ``graph`` (module -> modules it imports), or None."""
    state: dict[str, int] = {}  # 1 = on the current path, 2 = done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state:
                cycle = visit(nxt)
                if cycle:
                    return cycle
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state:
            cycle = visit(node)
            if cycle:
                return cycle
    return None


def test_render_modules_import_without_a_circle():
    graph = {p.stem: imported_render_modules(p) - {p.stem} for p in RENDER.glob("*.py")}
    assert {"output", "passes", "targets", "backend", "nvdiffrast_backend"} <= set(graph)
    assert find_cycle(graph) is None, f"import circle in gpja/render: {' -> '.join(find_cycle(graph))}"
    # only the package itself gathers the modules: no module imports gpja.render's __init__
    assert not [m for m, deps in graph.items() if m != "__init__" and "__init__" in deps]


def test_cycle_finder_sees_a_circle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None
