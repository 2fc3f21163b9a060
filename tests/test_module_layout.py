"""One module per idea, no module reaching into another's internals: no import circles among the training package's
modules (any import, at module level or inside a function), and no private name imported from another module."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "dvrl_marl"


def _imports(path: Path) -> list[tuple[str, list[str]]]:
    """(module imported, names taken from it) for every ``import`` / ``from ... import`` in a file."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append((node.module, [alias.name for alias in node.names]))
        elif isinstance(node, ast.Import):
            out += [(alias.name, []) for alias in node.names]
    return out


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(path): path for path in PACKAGE.rglob("*.py")}


def _targets(module: str, names: list[str]) -> list[str]:
    """The package modules an import reaches (``from pkg import mod`` names a module too)."""
    submodules = [f"{module}.{name}" for name in names if f"{module}.{name}" in MODULES]
    if submodules:  # ``from package import module``: the module is what is used
        return submodules
    return [module] if module in MODULES else []


def test_no_private_names_are_imported_across_modules():
    offenders = []
    for name, path in MODULES.items():
        for module, names in _imports(path):
            if module.startswith("dvrl_marl") and module != name:
                offenders += [f"{name}: from {module} import {n}" for n in names
                              if n.startswith("_") and not n.startswith("__")]
    assert not offenders, offenders


# (dvrl_marl.envs keeps one: suction_debris_v8.batched_env imports the batched module that builds on it.)
@pytest.mark.parametrize("package", ["dvrl_marl.training", "dvrl_marl.integrations", "dvrl_marl.core",
                                     "dvrl_marl.agents"])
def test_no_import_circles_within(package):
    graph = {name: {t for module, names in _imports(path) for t in _targets(module, names)
                    if t.startswith(package) and t != name}
             for name, path in MODULES.items() if name.startswith(package)}
    state, cycles = {}, []

    def visit(node, trail):
        state[node] = "open"
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                cycles.append(trail[trail.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt, trail + [nxt])
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    assert not cycles, cycles
