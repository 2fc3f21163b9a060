"""The multi-agent trainer on a Ray cluster (two nodes of ``ray.cluster_utils.Cluster``): collectors spread over
both nodes, training, checkpoints, resume, export, a collector killed mid-run; and what local and Ray runs share."""

from __future__ import annotations

import json

import numpy as np
import pytest

ray = pytest.importorskip("ray", reason='training on Ray needs the extra: pip install "dvrl-marl[ray]"')
pytest.importorskip("torchrl")

from ray.cluster_utils import Cluster  # noqa: E402

from dvrl_marl import policies  # noqa: E402
from dvrl_marl.training import mappo, models  # noqa: E402
from dvrl_marl.training.collectors import RolloutCollector, _merge, split_worlds  # noqa: E402

TINY = """
[run]
algorithm = "mappo"
total_steps = {total}
num_envs = 16
rollout_steps = 16
eval_every = 512
eval_episodes = 2
checkpoint_every = 512
torch_threads = 1
[env]
reward_type = "guided"
max_cycles = 40
[model]
hidden = [16, 16]
[curriculum]
levels = [[0.0, 0.0], [1.0, 0.5]]
"""


def tiny(tmp_path, total=1024):
    path = tmp_path / f"tiny_ray_{total}.toml"
    path.write_text(TINY.format(total=total))
    return mappo.load_config(path)


@pytest.fixture(scope="module")
def cluster():
    """Two Ray nodes on this machine, one CPU each: a collector on each."""
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    ray.init(address=cluster.address, log_to_driver=False)
    yield cluster
    ray.shutdown()
    cluster.shutdown()


def test_worlds_split_among_collectors():
    assert split_worlds(16, 2) == [8, 8] and split_worlds(10, 3) == [4, 3, 3] and split_worlds(5, 1) == [5]
    with pytest.raises(ValueError, match="collectors"):
        split_worlds(2, 3)


def test_two_collectors_return_what_one_collector_of_all_the_worlds_returns(tmp_path):
    """Semantics: a rollout from two shares is the rollout of one collector over all the worlds, world by world,
    when both act deterministically (same weights, same seeds, same first worlds)."""
    torch = pytest.importorskip("torch")
    config = tiny(tmp_path)
    one = RolloutCollector(config, 3, num_envs=16)
    halves = [RolloutCollector(config, 3, index=i, num_envs=8, first_world=8 * i) for i in range(2)]
    for collector in halves:  # same weights everywhere, and no sampling noise: the means alone
        collector.actor.load_state_dict(one.actor.state_dict())
    for collector in (one, *halves):
        with torch.no_grad():
            collector.actor.module[0].module.log_std.fill_(-30.0)
        collector.first_cut[:] = 10**6  # no random first-episode cuts (each collector draws its own)
    first = one.env.state()
    np.testing.assert_array_equal(first, np.concatenate([c.env.state() for c in halves]))
    whole, parts = one.rollout(None, 0.0), _merge([c.rollout(None, 0.0) for c in halves])
    for key in ("observation", "state", "reward", "done"):
        np.testing.assert_allclose(whole[key], parts[key], atol=1e-5, err_msg=key)


@pytest.mark.extended
def test_training_on_two_nodes_survives_a_killed_collector_checkpoints_resumes_and_exports(cluster, tmp_path):
    # (one run for all of it: each run starts collectors on both nodes, the slowest part here)
    run, messages, seen = tmp_path / "run", [], {}

    def kill_one(iteration, collectors):  # (the run's two iterations are numbered 1 and 2)
        if iteration == 1:
            seen["before"] = collectors.where()
            ray.kill(collectors.actors[0], no_restart=False)  # as a crashed worker process would
        elif iteration == 2:
            seen["after"] = collectors.where()

    final = mappo.train(tiny(tmp_path, 512), 0, run, progress=False, log=messages.append, ray_address="auto",
                        num_collectors=2, on_iteration=kill_one)
    assert final["steps"] == 512
    assert any("2 collectors on 2 node(s)" in m for m in messages), messages
    before, after = seen["before"], seen["after"]
    assert after[0]["pid"] != before[0]["pid"], "the killed collector came back as a new process"
    assert after[1]["pid"] == before[1]["pid"], "the other collector was left alone"
    assert (run / "checkpoint.pt").is_file()
    saved = models.require_torch().load(run / "checkpoint.pt", weights_only=False)
    assert len(saved["collector_rng"]) == 2

    messages.clear()
    final = mappo.train(tiny(tmp_path, 1024), 0, run, progress=False, log=messages.append, resume=True,
                        ray_address="auto", num_collectors=2)
    assert final["steps"] == 1024 and any("resumed" in m and "512" in m for m in messages)
    rows = (run / "progress.csv").read_text().splitlines()
    assert [int(r.split(",")[0]) for r in rows[1:]] == [512, 1024]
    for agent in ("suction", "grasper"):
        policy = policies.load(run / "policies" / f"marl-{agent}")
        assert policy(np.zeros(policy.weights[0][0].shape[1])).shape == (4,)
    assert json.loads((run / "result.json").read_text())["steps"] == 1024
