"""One module per idea, imports only down the layers: every module has a rank, no import (at module level or inside a
function) reaches a higher one, no import circles anywhere, and no private name imported from another module."""

import ast
from pathlib import Path


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


#: Each module's layer, lowest first (the longest dotted prefix decides). A module may import its own layer and those
#: below it, never one above: kinematics -> core -> the MuJoCo mirror and rendering -> envs -> policies -> agents and
#: pipelines -> seats and devices -> datasets -> the browser session, integrations and training -> demo and CLI.
LAYERS = (
    ("kinematics", "schemas", "files", "task", "assets", "validation"),
    ("core", "suction_debris"),
    ("scene", "arm", "display", "rendering", "viewer", "video", "frames", "preview", "pacing"),
    ("envs", "registration", ""),  # ("": the package itself, which registers the environments)
    ("policies",),
    ("agents", "pipeline"),
    ("seats", "teleop", "dvrk"),
    ("datasets",),
    ("teleop.session", "teleop.web", "teleop.person", "integrations", "training"),
    ("demo", "cli"),
)
RANKS = {name: rank for rank, names in enumerate(LAYERS) for name in names}


def _rank(module: str) -> int | None:
    parts = module.split(".")[1:]
    if not parts:
        return RANKS[""]
    for length in range(len(parts), 0, -1):
        rank = RANKS.get(".".join(parts[:length]))
        if rank is not None:
            return rank
    return None


def test_every_module_has_a_layer():
    assert [name for name in MODULES if _rank(name) is None] == []


def test_every_import_goes_down_the_layers():
    upward = [f"{name} ({_rank(name)}) imports {target} ({_rank(target)})"
              for name, path in MODULES.items() for module, names in _imports(path)
              for target in _targets(module, names) if target != name and _rank(target) > _rank(name)]
    assert not upward, upward


def test_no_import_circles():
    graph = {name: {t for module, names in _imports(path) for t in _targets(module, names) if t != name}
             for name, path in MODULES.items()}
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


def test_the_scenes_vectors_are_read_by_name():
    """The scene's modules take an action's move and tool, a pin's flags and the observation's parts from
    dvrl_marl.suction_debris.layout, not from literal positions (a new field changes that file, not every reader): the
    scene's step and envs, its experts and partners, the pipeline, the policies' rules, the trainers and the devices."""
    import re

    literal = re.compile(r"\[(?:\.\.\.|:|:, :|resting|resting & close|batch), (?:3|4|5|:3)\]|reshape\([^)]*\b6\)|"
                         r"shape=\(4,\)|shape != \(4,\)|, 4\), dtype|action_dim: int = 4|"
                         r"observation\[\.\.\., (?:0:3|4:7|7:|-3:)")  # (the collaborative observation's parts)
    readers = ["suction_debris/rules.py", "suction_debris/instruments.py", "suction_debris/features.py",
               "suction_debris/guidance.py", "suction_debris/scripted_team.py", "envs/suction_debris.py",
               "envs/suction_debris_batched.py",
               "envs/suction_debris_device.py", "pipeline/core.py", "agents/partners.py", "agents/in_the_way.py",
               "policies/felt_contact.py", "training/pretrain.py", "training/pixel_seat.py", "training/models.py",
               "training/jax_mappo.py", "training/collectors.py", "teleop/devices.py", "teleop/browser.py",
               "teleop/session.py"]
    found = []
    for reader in readers:
        for number, line in enumerate((PACKAGE / reader).read_text().splitlines(), 1):
            code = line.split("#", 1)[0]
            if literal.search(code) and not code.lstrip().startswith(('"', "'", "``")):
                found.append(f"{reader}:{number}: {line.strip()}")
    assert not found, "\n".join(found)


def test_the_scene_folder_knows_no_api():
    """The collaborative scene's folder (its task, state, rules, observation, shaping, experts) reaches neither MuJoCo
    nor Gymnasium nor PettingZoo, through any import of its own or of the modules it imports: the environments drive
    it, it knows none of them (docs/design.md, "One step, many shells")."""
    folder = [name for name in MODULES if name.startswith("dvrl_marl.suction_debris.")]
    assert len(folder) >= 15, folder
    seen, stack, outside = set(), list(folder), {}
    while stack:
        name = stack.pop()
        if name in seen:
            continue
        seen.add(name)
        for module, names in _imports(MODULES[name]):
            targets = _targets(module, names)
            stack += [t for t in targets if t != "dvrl_marl"]  # (the package's face registers the envs; not imported for it)
            if not module.startswith("dvrl_marl"):
                outside.setdefault(module.split(".")[0], set()).add(name)
    assert not {api: sorted(users) for api, users in outside.items() if api in ("mujoco", "gymnasium", "pettingzoo")}
