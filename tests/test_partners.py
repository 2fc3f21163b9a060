"""A population of partners in one seat (teams.Partners, MappoConfig.surgeon as a list): who plays which world,
seeded noise, and a trainer run beside a learned and a scripted partner."""

import json
import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

pytest.importorskip("torchrl")

from dvrl_marl.envs import suction_debris_v8  # noqa: E402
from dvrl_marl.policies import NoisyPolicy  # noqa: E402
from dvrl_marl.training import mappo, mappo_config, teams  # noqa: E402


def _constant(value):
    return lambda observations: np.full((len(observations), 4), value, dtype=np.float64)


@pytest.mark.parametrize("worlds", [1, 2, 5, 8])
def test_each_world_is_played_by_one_partner_in_turn(worlds):
    population = teams.Partners([_constant(0.1), _constant(-0.2), _constant(0.3)], ["a", "b", "c"])
    actions = population(np.zeros((worlds, 7)))
    assert actions.shape == (worlds, 4)
    np.testing.assert_array_equal(actions[:, 0], [(0.1, -0.2, 0.3)[i % 3] for i in range(worlds)])


def test_partners_reset_their_members_and_refuse_an_empty_population():
    class Counting:
        resets = 0

        def __call__(self, observations):
            return np.zeros((len(observations), 4))

        def reset(self):
            Counting.resets += 1

    population = teams.Partners([Counting(), _constant(0.0), Counting()], ["x", "y", "z"])
    env = suction_debris_v8.batched_env(num_envs=3, surgeon=population, surgeon_seat="grasper")
    env.reset(seed=1)
    assert Counting.resets == 2
    with pytest.raises(ValueError, match="no partner"):
        teams.Partners([], [])


def test_a_partner_moves_only_its_own_worlds():
    """World 0's grasper is held still, world 1's drives down: only world 1's grasper tip moves."""
    population = teams.Partners([_constant(0.0), lambda o: np.tile([0.0, 0.0, -1.0, -1.0], (len(o), 1))],
                                ["still", "down"])
    env = suction_debris_v8.batched_env(num_envs=4, surgeon=population, surgeon_seat="grasper",
                                        autoreset_mode="disabled")
    observations, _ = env.reset(seed=3)
    tip = env.state_layout["grasper_tip"]
    start = env.state()[:, tip].copy()
    for _ in range(20):
        observations, *_ = env.step({"suction": np.zeros((4, 4))})
    moved = np.abs(env.state()[:, tip] - start).max(axis=1)
    assert moved[0] < 1e-9 and moved[2] < 1e-9, "the still partner's worlds changed"
    assert moved[1] > 1e-3 and moved[3] > 1e-3, "the driving partner's worlds did not move"


def test_learned_partners_act_with_seeded_noise_and_scripted_ones_without():
    env = suction_debris_v8.parallel_env()
    assert teams.partner("none", "suction") is None
    first = teams.partner(["scripted", "marl-suction"], "suction", env, noise_from=11)
    again = teams.partner(["scripted", "marl-suction"], "suction", env, noise_from=11)
    other = teams.partner(["scripted", "marl-suction"], "suction", env, noise_from=12)
    assert isinstance(first.members[1], NoisyPolicy) and not isinstance(first.members[0], NoisyPolicy)
    batched = suction_debris_v8.batched_env(num_envs=6, surgeon="scripted", surgeon_seat="grasper")
    observations, _ = batched.reset(seed=5)
    a, b, c = (p(observations["suction"]) for p in (first, again, other))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a[1::2], c[1::2]), "the learned partner's noise ignores its seed"
    np.testing.assert_array_equal(a[0::2], c[0::2])  # the scripted partner has no noise
    assert teams.partner("scripted", "suction", env) is not None


def test_trainer_runs_beside_a_population_and_validates_beside_it(tmp_path):
    config = tmp_path / "population.toml"
    config.write_text("""
[run]
total_steps = 1024
num_envs = 8
rollout_steps = 16
eval_every = 1024
eval_episodes = 4
surgeon = ["scripted", "marl-suction"]
surgeon_seat = "suction"
[env]
reward_type = "dense"
max_cycles = 40
[model]
hidden = [16, 16]
""")
    loaded = mappo.load_config(config)
    population = mappo_config.partner(loaded, None, noise_from=0)
    assert isinstance(population, teams.Partners) and population.names == ["scripted", "marl-suction"]
    run = tmp_path / "run"
    mappo.train(loaded, 0, run, progress=False, log=lambda *_: None)
    assert sorted(p.name for p in (run / "policies").iterdir()) == ["marl-grasper"]
    assert 'surgeon = ["scripted", "marl-suction"]' in (run / "config.toml").read_text()
    assert mappo.load_config(run / "config.toml").surgeon == ["scripted", "marl-suction"]
    spec = json.loads((run / "policies" / "marl-grasper" / "policy.json").read_text())
    assert spec["training"]["partners"] == ["scripted", "marl-suction"]


def test_the_thread_cap_reaches_numpy_blas_too():
    """torch_threads caps the BLAS pool as well: a learned partner's numpy forward pass runs in the trainer."""
    threadpoolctl = pytest.importorskip("threadpoolctl")
    import torch

    before_torch = torch.get_num_threads()
    pools = [pool for pool in threadpoolctl.threadpool_info() if pool["user_api"] == "blas"]
    if not pools:
        pytest.skip("numpy has no BLAS pool that threadpoolctl can see")
    before = pools[0]["num_threads"]
    try:
        mappo.limit_threads(1)
        assert torch.get_num_threads() == 1
        assert all(pool["num_threads"] == 1 for pool in threadpoolctl.threadpool_info() if pool["user_api"] == "blas")
    finally:
        torch.set_num_threads(before_torch)
        threadpoolctl.threadpool_limits(before, user_api="blas")
