"""The collaborative core is the step, written once: it reads the scene file's text and steps without MuJoCo."""

import subprocess
import sys

import numpy as np

WITHOUT_MUJOCO = """
import sys
sys.modules["mujoco"] = None  # ``import mujoco`` now fails
import numpy as np
from dvrl_marl.suction_debris.rules import CollaborativeCore
from dvrl_marl.suction_debris.task import SuctionDebrisParams

core = CollaborativeCore(SuctionDebrisParams.from_task(), 4, reward_type="dense")
core.reset(seed=0)
rng = np.random.default_rng(1)
for _ in range(200):
    rewards, terminated, truncated = core.step({a: rng.uniform(-1, 1, (4, 4)) for a in ("suction", "grasper")})
np.save(sys.argv[1], core.state())
assert "mujoco" not in {name for name, module in sys.modules.items() if module is not None}
"""


def test_the_core_steps_where_mujoco_cannot_be_imported(tmp_path):
    out = tmp_path / "state.npy"
    done = subprocess.run([sys.executable, "-c", WITHOUT_MUJOCO, str(out)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    # the same worlds, stepped through the batched env (which has MuJoCo here), end in the same state
    from dvrl_marl.envs import suction_debris_v8

    env = suction_debris_v8.batched_env(num_envs=4, reward_type="dense", autoreset_mode="disabled")
    env.reset(seed=0)
    rng = np.random.default_rng(1)
    for _ in range(200):
        env.step({a: rng.uniform(-1, 1, (4, 4)) for a in env.agents})
    np.testing.assert_array_equal(np.load(out), env.core.state())


def test_the_scene_files_text_gives_the_geometry_mujoco_compiles():
    from dvrl_marl.envs.scene_mirror import SceneMirror
    from dvrl_marl.suction_debris.scene_geometry import SceneGeometry
    from dvrl_marl.suction_debris.task import SuctionDebrisParams

    params = SuctionDebrisParams.from_task()
    read, compiled = SceneGeometry.from_scene(params.scene), SceneMirror(params).geometry()
    assert read.phantom == compiled.phantom
    np.testing.assert_allclose(read.handoff, compiled.handoff, rtol=0, atol=1e-12)
    for agent, base in read.base_positions.items():
        np.testing.assert_allclose(base, compiled.base_positions[agent], rtol=0, atol=1e-12)
