"""The adapters to TorchRL (batched collaborative env) and Stable-Baselines3 (native vector envs + HER)."""

import numpy as np
import pytest

import dvrl_marl  # noqa: F401


def test_torchrl_env_passes_check_env_specs_and_resets_worlds_by_mask():
    pytest.importorskip("torchrl", reason="TorchRL is an optional extra: pip install 'dvrl-marl[torchrl]'")
    import torch
    from torchrl.envs.utils import check_env_specs

    from dvrl_marl.integrations.torchrl import SuctionDebrisTorchRLEnv

    env = SuctionDebrisTorchRLEnv(num_envs=4, max_cycles=20, seed=3)
    check_env_specs(env)
    env.set_seed(3)
    td = env.rollout(45, break_when_any_done=False)  # two resets per world through "_reset"
    assert td["agents", "observation"].shape == (4, 45, 2, env.batched.observation_space("suction").shape[0])
    assert td["next", "agents", "reward"].shape == (4, 45, 2, 1)
    assert td["next", "done"].sum() == 4 * 2
    assert td["agents", "observation"].dtype == torch.float32

    # World i equals the batched env seeded the same way (the adapter adds no behaviour of its own).
    from dvrl_marl.envs import suction_debris_v8

    reference = suction_debris_v8.batched_env(num_envs=4, max_cycles=20)
    observations, _ = reference.reset(seed=3)
    np.testing.assert_allclose(td["agents", "observation"][:, 0, 0].numpy(), observations["suction"], atol=1e-6)

    # Only the worlds named by "_reset" start over.
    env.reset()
    before = env.batched.state().copy()
    env.rand_step()
    stepped = env.batched.state().copy()
    mask = torch.tensor([[True], [False], [False], [False]])
    env.reset(_reset_td(env, mask))
    after = env.batched.state()
    np.testing.assert_array_equal(after[1:], stepped[1:])
    assert not np.array_equal(after[0], stepped[0]) and before.shape == after.shape


def _reset_td(env, mask):
    from tensordict import TensorDict

    return TensorDict({"_reset": mask}, batch_size=env.batch_size)


def test_torchrl_env_group_with_a_seated_surgeon():
    pytest.importorskip("torchrl", reason="TorchRL is an optional extra")
    from dvrl_marl.integrations.torchrl import SuctionDebrisTorchRLEnv

    env = SuctionDebrisTorchRLEnv(num_envs=2, surgeon="scripted")
    assert env.agent_names == ["suction"]
    td = env.rollout(5)
    assert td["agents", "action"].shape == (2, 5, 1, 4)


def test_sb3_her_trains_on_the_native_vector_env():
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import SAC, HerReplayBuffer

    from dvrl_marl.integrations.sb3 import make_sb3_vec_env

    venv = make_sb3_vec_env("dvrl_marl/PSMReach-v1", num_envs=4, seed=0)
    model = SAC("MultiInputPolicy", venv, replay_buffer_class=HerReplayBuffer, learning_starts=500, batch_size=32,
                seed=0, policy_kwargs={"net_arch": [32]})
    model.learn(700)
    assert model.num_timesteps == 700
    # Episodes ended inside steps hand SB3 their last observation and the truncation flag.
    venv.reset()
    for _ in range(100):
        _, _, dones, infos = venv.step(np.zeros((4, 3), dtype=np.float32))
    assert dones.all()
    assert all("terminal_observation" in info and info["TimeLimit.truncated"] for info in infos)
    rewards = venv.env_method("compute_reward", np.zeros((5, 3)), np.zeros((5, 3)), {}, indices=[0])[0]
    assert rewards.shape == (5,) and (rewards == 0).all()
