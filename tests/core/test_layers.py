"""Layers import one way: core → readers/config → engine → protocol → dataset → learning → per-file
inference → loop (residual → effect analysis) → commands. Parses every module's imports (also the
ones inside functions) and fails on an import of a higher layer or on an import cycle between modules."""

import ast
import graphlib
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[2] / "src"
PACKAGE = SRC / "forcdecode"

LAYERS = {
    "core": 0, "_runtime": 0,            # _runtime: process tuning (allocator), imports nothing
    "config": 1, "measured": 1,          # configuration and instrument-file readers
    "micromag": 2, "reference": 2,       # the engine (and the reference engine it is checked against)
    "forc": 3,                           # the FORC protocol, rasterization, diagrams
    "dataset": 4,
    "learn": 5,
    "infer": 6,                          # per-file inference by simulation: re-simulation, refinement, predictive checks
    "loop": 7,                           # the residual → effect analysis
    "bench": 8, "cli": 8, "__main__": 8,  # commands and benchmarks (__main__: `python -m forcdecode`)
}
"""Layer of each top-level sub-package or module of forcdecode; a module imports its own layer or lower."""
ROOT_LAYER = 0  # forcdecode/__init__.py (the version string) imports nothing of the package


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict:
    return {_module_name(p): p for p in PACKAGE.rglob("*.py") if "__pycache__" not in p.parts}


def _resolve(module: str, is_package: bool, node: ast.AST, known: dict) -> list[str]:
    """The forcdecode modules one import statement loads."""
    if isinstance(node, ast.Import):
        names = [alias.name for alias in node.names]
        return [n for n in names if n == "forcdecode" or n.startswith("forcdecode.")]
    if node.level:
        base = module.split(".") if is_package else module.split(".")[:-1]
        base = base[: len(base) - (node.level - 1)]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module or ""
    if not (target == "forcdecode" or target.startswith("forcdecode.")):
        return []
    found = []
    for alias in node.names:
        sub = f"{target}.{alias.name}"
        found.append(sub if sub in known else target)
    return found


def _layer(module: str) -> int:
    parts = module.split(".")
    if len(parts) == 1:
        return ROOT_LAYER
    if parts[1] not in LAYERS:
        pytest.fail(f"{module}: sub-package {parts[1]!r} has no layer in tests/core/test_layers.py")
    return LAYERS[parts[1]]


def import_graph() -> dict:
    known = _modules()
    graph = {}
    for module, path in known.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        edges = set()
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                edges.update(t for t in _resolve(module, path.name == "__init__.py", node, known) if t != module)
        graph[module] = edges
    return graph


def test_every_module_imports_its_own_layer_or_lower():
    upward = sorted(f"{m} (layer {_layer(m)}) imports {t} (layer {_layer(t)})"
                    for m, targets in import_graph().items() for t in targets if _layer(t) > _layer(m))
    assert not upward, "upward imports:\n" + "\n".join(upward)


def test_no_import_cycle():
    try:
        tuple(graphlib.TopologicalSorter(import_graph()).static_order())
    except graphlib.CycleError as error:
        pytest.fail(f"import cycle: {' -> '.join(error.args[1])}")


def test_the_checker_sees_upward_imports_and_cycles(tmp_path):
    """The parser resolves relative imports, imports inside functions and sub-module imports."""
    known = {"forcdecode.loop.effects": None, "forcdecode.loop.physics_effects": None, "forcdecode.dataset.io": None,
             "forcdecode.dataset": None, "forcdecode.forc.cli": None}
    lazy = ast.parse("def f():\n    from ..dataset.io import atomic_path\n")
    node = next(n for n in ast.walk(lazy) if isinstance(n, ast.ImportFrom))
    assert _resolve("forcdecode.forc.cli", False, node, known) == ["forcdecode.dataset.io"]
    assert _layer("forcdecode.dataset.io") > _layer("forcdecode.forc.cli")
    sibling = next(n for n in ast.walk(ast.parse("from . import physics_effects")) if isinstance(n, ast.ImportFrom))
    assert _resolve("forcdecode.loop.effects", False, sibling, known) == ["forcdecode.loop.physics_effects"]
    with pytest.raises(graphlib.CycleError):
        tuple(graphlib.TopologicalSorter({"a": {"b"}, "b": {"a"}}).static_order())
