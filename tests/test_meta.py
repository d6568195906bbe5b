"""Meta-tests: import layering, documented parameters match signatures, no mutable defaults, every verb tested."""

import ast
import importlib
import inspect
import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "forecast_design"

# Lower layers never import higher ones (STYLE section 9, adapted to this layout).
LAYERS = {
    "errors": 0, "params": 0, "controllers": 0, "discrete": 0, "environments": 0, "effects": 0, "experiment": 0, "experiment_io": 0, "fileio": 0, "lti": 0, "__init__": 0, "plausibility": 0, "limits": 0, "polynomials": 0, "margins": 0,
    "symbolic": 1, "friction": 1, "compensators": 1, "program": 1,
    "analysis": 2, "passivity": 2, "executor": 2, "loops": 2, "simulation": 2, "export": 2, "independent": 2,
    "worstcase": 2,
    "tuning": 3, "gap": 3, "reproduce": 3, "table3": 3, "benchmark": 3,
    "plotting": 4, "runtime": 4, "reporting": 4,
    "pipeline": 5, "cli": 6, "__main__": 6,
}


def _layer(module: str) -> int | None:
    parts = module.split(".")
    for n in range(len(parts), 0, -1):
        key = ".".join(parts[:n])
        if key in LAYERS:
            return LAYERS[key]
    return None


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).with_suffix("")
        name = ".".join(rel.parts)
        yield path, rel, name.removesuffix(".__init__") if name != "__init__" else name


def test_import_layering_holds():
    violations = []
    for path, rel, name in _modules():
        mine = _layer(name)
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level > 0:
                base = list(rel.parts[:-1])
                if node.level > 1:
                    base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
                theirs = _layer(target)
                if target.startswith(name + "."):
                    continue            # a package re-exporting its own submodule
                if mine is not None and theirs is not None and theirs > mine:
                    violations.append(f"{name} (layer {mine}) imports {target} (layer {theirs}), line {node.lineno}")
    assert not violations, "\n".join(violations)


def test_private_names_stay_inside_their_package():
    """A module imports another's private (underscore) names only within one subpackage.

    Across top-level modules or subpackages a shared helper must be public (documented),
    so that each concept keeps one home that others use through its interface. The CLI
    package is exempt: it is the top of the stack and its helpers are its own.
    """
    violations = []
    for path, rel, name in _modules():
        if name.startswith("cli"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if not (isinstance(node, ast.ImportFrom) and node.level > 0):
                continue
            base = list(rel.parts[:-1])
            if node.level > 1:
                base = base[: len(base) - (node.level - 1)]
            target = base + (node.module.split(".") if node.module else [])
            same_subpackage = len(rel.parts) > 1 and target[:1] == list(rel.parts[:1])
            for alias in node.names:
                if alias.name.startswith("_") and not alias.name.startswith("__") and not same_subpackage:
                    violations.append(f"{name} imports private {'.'.join(target)}.{alias.name}, line {node.lineno}")
    assert not violations, "\n".join(violations)


PUBLIC_MODULES = [
    "forecast_design", "forecast_design.experiment", "forecast_design.symbolic", "forecast_design.analysis", "forecast_design.margins", "forecast_design.loops", "forecast_design.reporting",
    "forecast_design.tuning", "forecast_design.friction", "forecast_design.simulation", "forecast_design.gap",
    "forecast_design.export", "forecast_design.runtime", "forecast_design.reproduce", "forecast_design.pipeline",
    "forecast_design.independent", "forecast_design.tuning.tradeoff",
]


def _public_callables():
    seen = set()
    for module_name in PUBLIC_MODULES:
        module = importlib.import_module(module_name)
        for name in getattr(module, "__all__", []):
            obj = getattr(module, name)
            if inspect.isfunction(obj) and obj not in seen:
                seen.add(obj)
                yield f"{module_name}.{name}", obj


def _documented_parameters(doc: str) -> list[str] | None:
    match = re.search(r"\n\s*Parameters\n\s*-{5,}\n(.*?)(\n\s*\n\s*[A-Z][a-z]+( [A-Z][a-z]+)?\n\s*-{5,}|\Z)", doc, re.S)
    if not match:
        return None
    names = []
    indent = None
    for line in match.group(1).splitlines():
        if not line.strip():
            continue
        current = len(line) - len(line.lstrip())
        indent = current if indent is None else indent
        if current == indent:
            head = line.strip().split(" : ")[0].rstrip(":")
            names += [n.strip().lstrip("*") for n in head.split(",") if n.strip()]
    return names


@pytest.mark.parametrize("qualname,func", list(_public_callables()), ids=lambda x: x if isinstance(x, str) else "")
def test_public_function_documents_its_parameters(qualname, func):
    doc = inspect.getdoc(func)
    assert doc, f"{qualname} has no docstring"
    params = [p.name for p in inspect.signature(func).parameters.values() if p.name not in ("self", "cls")]
    documented = _documented_parameters("\n" + doc)
    if not params:
        return
    assert documented is not None, f"{qualname}: no Parameters section"
    missing = [p for p in params if p not in documented]
    extra = [d for d in documented if d not in params]
    assert not missing and not extra, f"{qualname}: undocumented {missing}, documented but absent {extra}"


def test_no_mutable_default_arguments():
    offenders = []
    for path, _, name in _modules():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for default in node.args.defaults + [d for d in node.args.kw_defaults if d is not None]:
                    if isinstance(default, (ast.List, ast.Dict, ast.Set)):
                        offenders.append(f"{name}.{node.name} line {node.lineno}")
    assert not offenders, offenders


def test_every_cli_verb_has_a_test():
    from forecast_design.cli import build_parser

    verbs = build_parser()._subparsers._group_actions[0].choices  # noqa: SLF001 - argparse has no public API
    tests = "".join(p.read_text() for p in (ROOT / "tests").glob("test_*.py"))
    untested = [v for v in verbs if f'"{v}"' not in tests]
    assert not untested, untested


def test_importing_the_package_keeps_heavy_dependencies_at_the_edges():
    import subprocess
    import sys

    code = ("import sys, forecast_design; "
            "print(sorted(m for m in ('sympy', 'casadi', 'numba', 'matplotlib', 'cvxpy', 'serial') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


MAX_MODULE_LINES = 800


def test_no_module_grows_past_the_size_a_reader_can_hold():
    """Issue 12: a module holds one topic; past ~800 lines it is split by concept."""
    long = {name: n for _, rel, name in _modules()
            if (n := len((PACKAGE / rel).with_suffix(".py").read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, long
