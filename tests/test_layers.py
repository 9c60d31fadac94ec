"""The package's import rules (DESIGN.md, "Data flows one way"), read from the source with ``ast``.

Every ``import`` and ``from ... import`` statement counts, also those inside functions and under
``TYPE_CHECKING``; ``importlib`` calls with a module name in a string (the method and settings
registries) are not import statements and are not followed.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

import gpja

PACKAGE_DIR = Path(gpja.__file__).parent
#: The shared lower layer: it may import only itself (and third-party code).
LOWER = ("gpja.mesh", "gpja.camera", "gpja.io", "gpja.errors", "gpja.lighting", "gpja.surface", "gpja.results",
         "gpja.methods")
UPPER = ("gpja.data", "gpja.render", "gpja.register", "gpja.metrics", "gpja.baselines", "gpja.apply", "gpja.report",
         "gpja.cli")


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def is_module(name: str) -> bool:
    """Whether the dotted ``name`` is a module or package of gpja (a file or folder under the package)."""
    path = PACKAGE_DIR.parent.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def imported_modules(path: Path) -> list[tuple[str, int]]:
    """(module, line) of every module an import statement of ``path`` names (relative imports resolved).

    ``from a.b import c`` names ``a.b``, and ``a.b.c`` too where that is a module of the package.
    """
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            found.append((module, node.lineno))
            found += [(f"{module}.{alias.name}", node.lineno) for alias in node.names
                      if is_module(f"{module}.{alias.name}")]
    return found


def within(module: str, prefixes) -> bool:
    """``module`` is one of ``prefixes`` or inside one of them."""
    if isinstance(prefixes, str):
        prefixes = (prefixes,)
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def package_imports() -> dict[str, list[tuple[str, int]]]:
    """Module name -> the gpja modules it imports, for every module of the package."""
    edges = {}
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        edges[module_name(path)] = [(m, line) for m, line in imported_modules(path) if within(m, "gpja")]
    return edges


#: (rule, importer, forbidden): an importer inside ``importer`` may import nothing inside ``forbidden``.
RULES = [
    ("scoring and baselines do not lean on the method they score", ("gpja.metrics", "gpja.baselines"),
     ("gpja.register",)),
    ("the registration does not read the synthetic generator", ("gpja.register",), ("gpja.data.synthetic",)),
    ("the applications read what registration wrote, never the ground truth", ("gpja.apply",),
     ("gpja.data.synthetic", "gpja.data.ground_truth", "gpja.metrics.correspondence", "gpja.baselines")),
    ("the renderer sits below registration, scoring and reporting", ("gpja.render",),
     ("gpja.register", "gpja.metrics", "gpja.baselines", "gpja.report", "gpja.cli")),
    ("the lower layer imports only itself", LOWER, UPPER),
]


@pytest.fixture(scope="module")
def edges():
    return package_imports()


def test_the_walk_sees_every_module_and_function_level_imports(edges):
    assert len(edges) > 40 and "gpja.surface" in edges and "gpja.baselines.nicp" in edges
    assert any(m == "gpja.report.tables" for m, _ in edges["gpja.cli"])  # imported inside cmd_tables


@pytest.mark.parametrize("rule, importers, forbidden", RULES, ids=[r[0] for r in RULES])
def test_import_rule(edges, rule, importers, forbidden):
    bad = [f"{module} imports {target} (line {line})" for module, targets in edges.items() if within(module, importers)
           for target, line in targets if within(target, forbidden)]
    assert not bad, f"{rule}:\n  " + "\n  ".join(bad)


def test_only_the_report_and_the_cli_import_the_report_and_the_cli(edges):
    top = ("gpja.report", "gpja.cli")
    bad = [f"{module} imports {target} (line {line})" for module, targets in edges.items()
           if not within(module, top) and not within(module, "gpja.__main__")
           for target, line in targets if within(target, top)]
    assert not bad, "only gpja.report and gpja.cli (and python -m gpja) use the top layers:\n  " + "\n  ".join(bad)
