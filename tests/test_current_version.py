"""One current version of every environment: old names fail naming the new one, nothing else is registered, and no
shipped file (the wheel's contents, README, the docs but the records) names another version."""

import importlib
import json
import re
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import dvrl_marl
from dvrl_marl.envs import CURRENT, RECORDS_COMMIT, suction_debris_v8
from dvrl_marl.suction_debris.presets import PRESETS, evaluation_options

ROOT = Path(__file__).resolve().parents[1]
#: Names of versions that are not the current ones: the collaborative scene's v0-v7 (module, id, seat id), the
#: single-arm -v0 ids.
OLD_NAME = re.compile(r"suction_debris[_-]v[0-7]\b|SurgeonSeat-v[0-7]\b|PSM(Reach|Pick)(Dense)?-v0\b")
#: Files allowed to name old versions: the records and the pages that map or list them.
RECORD_PAGES = {"docs/migration.md", "docs/history.md", "CHANGELOG.md"}


@pytest.mark.parametrize("version", range(8))
def test_an_old_version_names_the_current_one_and_the_commit_of_its_records(version):
    name = f"suction_debris_v{version}"
    with pytest.raises(ImportError, match=rf"{name} is no longer available: use {CURRENT}.*{RECORDS_COMMIT}"):
        importlib.import_module(f"dvrl_marl.envs.{name}")
    with pytest.raises(ImportError, match=CURRENT):
        exec(f"from dvrl_marl.envs import {name}", {})


def test_a_fresh_interpreter_gets_the_same_message():
    result = subprocess.run([sys.executable, "-c", "from dvrl_marl.envs import suction_debris_v2"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode != 0 and "use suction_debris_v8" in result.stderr and "36a42a0" in result.stderr


def test_only_the_current_versions_are_registered():
    ours = sorted(env_id for env_id in gym.registry if env_id.startswith("dvrl_marl/"))
    assert ours == ["dvrl_marl/PSMPick-v1", "dvrl_marl/PSMPickDense-v1", "dvrl_marl/PSMReach-v1",
                    "dvrl_marl/PSMReachDense-v1", "dvrl_marl/SurgeonSeat-v8"]
    import pettingzoo

    if hasattr(pettingzoo, "parallel_registry"):
        assert sorted(k for k in pettingzoo.parallel_registry if k.startswith("dvrl_marl/")) == [
            "dvrl_marl/suction_debris-v8"]
    for old in ("dvrl_marl/PSMReach-v0", "dvrl_marl/PSMPick-v0"):
        with pytest.raises(gym.error.Error, match=old.replace("-v0", "-v1")):
            gym.make(old)


def test_the_current_env_names_itself_everywhere():
    assert suction_debris_v8.parallel_env().metadata["name"] == CURRENT == suction_debris_v8.TASK
    assert suction_debris_v8.batched_env(num_envs=2).metadata["name"] == CURRENT
    assert (ROOT / "tasks" / f"{CURRENT}.toml").is_file()
    assert sorted(p.stem for p in (ROOT / "tasks").glob("suction_debris*.toml")) == [CURRENT]


def _shipped_files():
    """What a user gets or reads: the package (the wheel adds scenes, tasks, the shipped policies and the
    configurations of record), README and the documentation."""
    roots = ["dvrl_marl", "scenes", "tasks", "baselines/policies", "baselines/configs", "docs", "examples"]
    files = [ROOT / "README.md", ROOT / "mkdocs.yml"]
    for root in roots:
        files += [p for p in (ROOT / root).rglob("*") if p.is_file() and p.suffix in
                  (".py", ".md", ".toml", ".yaml", ".json", ".xml", ".js", ".html", ".txt")]
    return [p for p in files if str(p.relative_to(ROOT)) not in RECORD_PAGES and "__pycache__" not in p.parts]


def test_no_shipped_file_names_another_version():
    offenders = []
    for path in _shipped_files():
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
            if line.startswith("Record `") and " made by `" in line:  # (a record's command, as it was run)
                continue
            if OLD_NAME.search(line):
                offenders.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()[:100]}")
    assert not offenders, "\n".join(offenders)


def test_shipped_policies_name_the_current_envs():
    current = {"suction_debris_v8", "dvrl_marl/SurgeonSeat-v8", "dvrl_marl/PSMReach-v1", "dvrl_marl/PSMPick-v1"}
    for manifest in (ROOT / "baselines" / "policies").glob("*/policy.json"):
        spec = json.loads(manifest.read_text())
        assert spec["env_id"] in current, manifest
        assert spec["name"] == manifest.parent.name and not re.search(r"-v\d+$", spec["name"]), manifest


def test_the_benchmark_preset_is_one_argument_in_every_form_and_explicit_keywords_win():
    single = suction_debris_v8.parallel_env(preset="benchmark")
    assert single.reward_type == "guided" and single.params.tool_speed == 0.1 and single.preset == "benchmark"
    assert single.params.jaw_command == "switch" and single.params.hold_until_handoff and single.state_observations
    assert single.world.preset == "benchmark"  # (the world it wraps says the preset it was made with, too)
    explicit = suction_debris_v8.parallel_env(**PRESETS["benchmark"])
    a, _ = single.reset(seed=3)
    b, _ = explicit.reset(seed=3)
    for agent in a:
        np.testing.assert_array_equal(a[agent], b[agent])
    assert suction_debris_v8.parallel_env(preset="benchmark", tool_speed=0.5).params.tool_speed == 0.5
    batch = suction_debris_v8.batched_env(num_envs=2, preset="benchmark")
    assert batch.reward_type == "guided" and batch.params.tool_speed == 0.1 and batch.preset == "benchmark"
    seat = gym.make("dvrl_marl/SurgeonSeat-v8", partner="scripted", preset="benchmark")
    assert seat.unwrapped.scene.params.hold_until_handoff
    assert "reward_type" not in evaluation_options("benchmark") and evaluation_options("benchmark")["tool_speed"] == 0.1


@pytest.mark.parametrize("bad", ["fast", None, 3])
def test_an_unknown_preset_is_named(bad):
    with pytest.raises(ValueError, match=r"preset must be one of \['benchmark', 'default', 'irrigation'\]"):
        suction_debris_v8.parallel_env(preset=bad)
    with pytest.raises(ValueError, match="preset"):
        suction_debris_v8.batched_env(num_envs=2, preset=bad)


def test_the_package_says_its_version():
    assert dvrl_marl.__version__ == "0.2.0"
    text = (ROOT / "pyproject.toml").read_text()
    assert 'version = "0.2.0"' in text and (ROOT / "LICENSE").is_file() and (ROOT / "CITATION.cff").is_file()
    assert "## 0.2.0" in (ROOT / "CHANGELOG.md").read_text()


def test_the_readme_is_a_users_page():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 200
    assert not any(re.search(r"issue \d+", line) for line in lines)


def test_the_readmes_examples_run():
    """Every Python block of README.md runs (BenchMARL's where BenchMARL is installed)."""
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), flags=re.S)
    assert len(blocks) >= 4
    for index, block in enumerate(blocks):
        if "benchmarl" in block:
            try:
                import benchmarl  # noqa: F401
            except ImportError:
                continue
        exec(compile(block, f"README.md block {index}", "exec"), {})


def test_the_library_says_the_scenes_version_in_one_place():
    """PettingZoo's way: internals import the unversioned module (dvrl_marl.envs.suction_debris); the version's name is
    the task's (suction_debris.task.TASK), and only dvrl_marl.envs, its versioned module and the registry say it
    in code (the docstrings are the users' pages, which name what users import)."""
    import ast

    allowed = {"envs/__init__.py", "envs/suction_debris_v8.py", "registration.py", "suction_debris/task.py"}
    package = ROOT / "dvrl_marl"
    found = []
    for path in sorted(package.rglob("*.py")):
        relative = str(path.relative_to(package))
        if relative in allowed:
            continue
        tree = ast.parse(path.read_text())
        documentation = {id(node.body[0].value) for node in ast.walk(tree)
                         if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                         and node.body and isinstance(node.body[0], ast.Expr)
                         and isinstance(node.body[0].value, ast.Constant)}
        for node in ast.walk(tree):
            named = (isinstance(node, ast.Name) and node.id == "suction_debris_v8"
                     or isinstance(node, ast.alias) and "suction_debris_v8" in node.name
                     or isinstance(node, ast.ImportFrom) and "suction_debris_v8" in (node.module or "")
                     or isinstance(node, ast.Constant) and id(node) not in documentation
                     and isinstance(node.value, str) and "suction_debris_v8" in node.value)
            if named:
                found.append(f"{relative}:{node.lineno}")
    assert not found, f"the version named outside its one place: {found}"
