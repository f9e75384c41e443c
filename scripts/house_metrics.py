"""The house's counts (issue 61), read from the source with `ast`: re-run before and after a refactor.

    python scripts/house_metrics.py [--json] [--list]

Counts, over src/forcdecode:
- ``mu0_definitions``: module-level assignments to a name ``MU0`` (or ``MU_0``), and inline ``4e-7 * pi``
  / ``4 * pi * 1e-7`` literals outside the one definition;
- ``cli_imports_outside_cli``: imports of a module whose name contains ``cli`` made by a module whose
  name does not (a CLI may import a CLI; library code may not);
- ``functions_over_100_lines``: functions (and methods) longer than 100 lines, decorators excluded;
- ``largest_signature`` and ``signatures_over_8``: parameters of a function (``self``/``cls`` excluded);
- ``internal_imports_inside_functions``: the share of ``forcdecode`` imports (absolute or relative)
  written inside a function body rather than at a module's top.
"""

from __future__ import annotations

import argparse
import ast
import json
from pathlib import Path

SOURCE = Path(__file__).resolve().parents[1] / "src" / "forcdecode"


def _module_name(path: Path) -> str:
    return ".".join(path.relative_to(SOURCE.parent).with_suffix("").parts)


def _imported_modules(node: ast.AST, module: str) -> list[str]:
    """Absolute names of the forcdecode modules an Import/ImportFrom node reads."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names if a.name.startswith("forcdecode")]
    if isinstance(node, ast.ImportFrom):
        if node.level:
            base = module.split(".")
            package = base[:-node.level] if not module.endswith("__init__") else base[:-node.level]
            name = ".".join(package + ([node.module] if node.module else []))
        else:
            name = node.module or ""
        if not name.startswith("forcdecode"):
            return []
        if node.module is None:
            return [f"{name}.{a.name}" for a in node.names]
        return [name]
    return []


def _is_mu0_literal(node: ast.AST) -> bool:
    text = ast.unparse(node).replace(" ", "")
    return text in {"4e-07*np.pi", "4e-7*np.pi", "4*np.pi*1e-07", "4*np.pi*1e-7", "4e-07*math.pi", "4e-7*math.pi",
                    "4*math.pi*1e-07", "np.pi*4e-07", "4.0e-7*np.pi", "4.0*np.pi*1e-07"}


def measure() -> dict:
    functions = []
    mu0 = []
    cli_imports = []
    imports_total = imports_inside = 0
    for path in sorted(SOURCE.rglob("*.py")):
        module = _module_name(path)
        tree = ast.parse(path.read_text(), filename=str(path))
        parents: dict[ast.AST, ast.AST] = {}
        for parent in ast.walk(tree):
            for child in ast.iter_child_nodes(parent):
                parents[child] = parent

        def inside_function(node: ast.AST) -> bool:
            while node in parents:
                node = parents[node]
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    return True
            return False

        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                args = node.args
                names = [a.arg for a in args.posonlyargs + args.args + args.kwonlyargs]
                names = [n for n in names if n not in {"self", "cls"}]
                names += [a.arg for a in (args.vararg, args.kwarg) if a is not None]
                length = (node.end_lineno or node.lineno) - node.lineno + 1
                functions.append({"where": f"{path.relative_to(SOURCE.parent)}:{node.lineno}", "name": node.name,
                                  "lines": length, "parameters": len(names)})
            elif isinstance(node, ast.Assign) and not inside_function(node):
                for target in node.targets:
                    if isinstance(target, ast.Name) and target.id in {"MU0", "MU_0"}:
                        mu0.append(f"{path.relative_to(SOURCE.parent)}:{node.lineno} (definition)")
            if isinstance(node, ast.BinOp) and _is_mu0_literal(node):
                parent = parents.get(node)
                defines = isinstance(parent, ast.Assign) and any(
                    isinstance(t, ast.Name) and t.id in {"MU0", "MU_0"} for t in parent.targets)
                if not defines:
                    mu0.append(f"{path.relative_to(SOURCE.parent)}:{node.lineno} (inline)")
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                targets = _imported_modules(node, module)
                if not targets:
                    continue
                imports_total += 1
                if inside_function(node):
                    imports_inside += 1
                own_is_cli = "cli" in module.rsplit(".", 1)[-1] or module.endswith("__main__")
                for target in targets:
                    if "cli" in target.rsplit(".", 1)[-1] and not own_is_cli:
                        cli_imports.append(f"{path.relative_to(SOURCE.parent)}:{node.lineno} -> {target}")
    long_functions = sorted((f for f in functions if f["lines"] > 100), key=lambda f: -f["lines"])
    wide = sorted((f for f in functions if f["parameters"] > 8), key=lambda f: -f["parameters"])
    return {
        "mu0_definitions": len(mu0),
        "cli_imports_outside_cli": len(cli_imports),
        "functions_over_100_lines": len(long_functions),
        "largest_signature": max(f["parameters"] for f in functions),
        "signatures_over_8": len(wide),
        "internal_imports": imports_total,
        "internal_imports_inside_functions": round(imports_inside / max(imports_total, 1), 3),
        "_mu0": mu0,
        "_cli_imports": cli_imports,
        "_long_functions": [f"{f['where']} {f['name']} {f['lines']}" for f in long_functions],
        "_wide_signatures": [f"{f['where']} {f['name']} {f['parameters']}" for f in wide],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="one JSON line of the counts")
    parser.add_argument("--list", action="store_true", help="also list where each count comes from")
    args = parser.parse_args()
    figures = measure()
    counts = {k: v for k, v in figures.items() if not k.startswith("_")}
    if args.json:
        print(json.dumps(counts))
    else:
        for key, value in counts.items():
            print(f"{key:36s} {value}")
    if args.list:
        for key, value in figures.items():
            if key.startswith("_"):
                print(f"\n{key[1:]}:")
                for line in value:
                    print(f"  {line}")


if __name__ == "__main__":
    main()
