"""The batched env on a device (JAX, compiled whole; here on the CPU): step by step the numpy env's, automatic resets,
the guided reward and the observation features included, with torch tensors in and out."""

import os

import numpy as np
import pytest

jax = pytest.importorskip("jax")
torch = pytest.importorskip("torch")

from dvrl_marl.envs import suction_debris_v8  # noqa: E402

WORLDS, STEPS = 3, 90
#: Where the device env runs: the CPU here; the device probe (benchmarks/device_probe.py) sets "cuda" on a GPU machine.
DEVICE = os.environ.get("DVRL_MARL_TEST_DEVICE", "cpu")
#: The benchmark's setting with short episodes: every world ends and restarts a few times within the run, half of
#: them easy episodes of the start levels (fewer pins, blood drawn, the grasper started by a pin).
OPTIONS = dict(preset="benchmark", max_cycles=35, start_level=0.5)


@pytest.fixture(scope="module")
def pair():
    host = suction_debris_v8.batched_env(num_envs=WORLDS, **OPTIONS)
    device = suction_debris_v8.batched_env(num_envs=WORLDS, device=DEVICE, **OPTIONS)
    return host, device


def test_the_device_env_steps_as_the_numpy_env(pair):
    host, device = pair
    observations, _ = host.reset(seed=5)
    got, _ = device.reset(seed=5)
    assert list(got) == host.possible_agents
    for agent in host.possible_agents:
        assert isinstance(got[agent], torch.Tensor) and got[agent].shape == observations[agent].shape
        np.testing.assert_allclose(got[agent].cpu().numpy(), observations[agent], rtol=0, atol=1e-9)
    rng = np.random.default_rng(0)
    ended = 0
    for step in range(STEPS):
        actions = {agent: rng.uniform(-1.2, 1.2, (WORLDS, 4)) for agent in host.possible_agents}
        expected = host.step(actions)
        got = device.step({agent: torch.from_numpy(value).to(DEVICE) for agent, value in actions.items()})
        for part, (want, have) in enumerate(zip(expected[:4], got[:4])):
            for agent in host.possible_agents:
                np.testing.assert_allclose(have[agent].cpu().numpy(), want[agent], rtol=0, atol=1e-9,
                                           err_msg=f"step {step}, output {part}, {agent}")
        done = expected[2]["suction"] | expected[3]["suction"]
        ended += int(done.sum())
        success = got[4]["suction"]["is_success"].cpu().numpy()
        np.testing.assert_array_equal(success[done], expected[4]["suction"]["is_success"][done])
    assert ended >= WORLDS * 2  # automatic resets were taken, on both sides alike
    # a level set between steps reaches the device (the next episodes of world 0 are easy ones, or not, alike)
    host.set_start_level(0.0, [0])
    device.set_start_level(0.0, [0])
    for _ in range(40):
        actions = {agent: rng.uniform(-1.0, 1.0, (WORLDS, 4)) for agent in host.possible_agents}
        expected = host.step(actions)
        got = device.step({agent: torch.from_numpy(value).to(DEVICE) for agent, value in actions.items()})
        np.testing.assert_allclose(got[0]["grasper"].cpu().numpy(), expected[0]["grasper"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(device.state().cpu().numpy(), host.state(), rtol=0, atol=1e-9)
    # the two hold one record of the worlds' state, the same one
    host_state, device_state = _arrays(host.world_state), _arrays(device.world_state)
    assert set(host_state) == set(device_state)
    for key, value in host_state.items():
        np.testing.assert_allclose(device_state[key], value, rtol=0, atol=1e-9, err_msg=key)


@pytest.fixture(scope="module")
def masked_pair():
    """A numpy and a device env that reset ended worlds only when asked (reset_mask)."""
    return (suction_debris_v8.batched_env(num_envs=WORLDS, autoreset_mode="disabled", **OPTIONS),
            suction_debris_v8.batched_env(num_envs=WORLDS, device=DEVICE, autoreset_mode="disabled", **OPTIONS))


def _arrays(state) -> dict:
    """``{path: numpy copy}`` of every array of a state record (an EnvState pytree)."""
    return {jax.tree_util.keystr(path): np.array(value)
            for path, value in jax.tree_util.tree_flatten_with_path(state)[0]}


@pytest.mark.parametrize("check_actions", [True, False])
def test_actions_with_nan_or_inf_change_no_world_and_are_refused_as_numpy_refuses_them(pair, check_actions):
    """The numpy env's rule and words on the device: no world changes; the refusal comes at once, or with
    check_actions=False at the next call (no wait on the device per step)."""
    host, device = pair
    device.check_actions = check_actions
    try:
        for bad in (float("nan"), float("inf"), -float("inf")):
            host.reset(seed=2)
            device.reset(seed=2)
            before = _arrays(device.world_state)
            actions = {agent: np.zeros((WORLDS, 4)) for agent in host.possible_agents}
            actions["grasper"][2, 1] = bad
            expected = _refusal(host, lambda env: env.step(actions))
            torch_actions = {agent: torch.from_numpy(value).to(DEVICE) for agent, value in actions.items()}
            if check_actions:
                message = _refusal(device, lambda env: env.step(torch_actions))
            else:
                device.step(torch_actions)
                message = _refusal(device, lambda env: env.step(torch_actions))  # the earlier step's, said now
            assert message.startswith(expected) and ("changed no world" in message or "no world was changed" in message)
            for key, value in _arrays(device.world_state).items():
                np.testing.assert_array_equal(value, before[key], err_msg=key)
            calm = {agent: np.zeros((WORLDS, 4)) for agent in host.possible_agents}
            want = host.step(calm)[0]
            got = device.step({agent: torch.from_numpy(value).to(DEVICE) for agent, value in calm.items()})[0]
            for agent in host.possible_agents:  # the worlds go on as the numpy env's, which never took the step
                np.testing.assert_allclose(got[agent].cpu().numpy(), want[agent], rtol=0, atol=1e-9)
    finally:
        device.check_actions = True


def _refusal(env, call) -> str:
    with pytest.raises(ValueError) as refused:
        call(env)
    return str(refused.value)


@pytest.mark.parametrize("mask,form", [([0, 2], list), ([0, 2], torch.tensor), ([True, False, True], np.array),
                                       ([2, 2], list)])
def test_a_reset_mask_picks_the_worlds_the_numpy_env_picks(masked_pair, mask, form):
    """Integers are world indices on both backends (the device once read [0, 1] as a mask), booleans a mask."""
    host, device = masked_pair
    host.reset(seed=4)
    device.reset(seed=4)
    rng = np.random.default_rng(0)
    for _ in range(5):
        actions = {agent: rng.uniform(-1, 1, (WORLDS, 4)) for agent in host.possible_agents}
        host.step(actions)
        device.step({agent: torch.from_numpy(value).to(DEVICE) for agent, value in actions.items()})
    want, _ = host.reset(options={"reset_mask": mask})
    given = form(mask)
    got, _ = device.reset(options={"reset_mask": given.to(DEVICE) if form is torch.tensor else given})
    for agent in host.possible_agents:
        np.testing.assert_allclose(got[agent].cpu().numpy(), want[agent], rtol=0, atol=1e-9)


@pytest.mark.parametrize("mask", [[2, 3], [0.5, 0.0, 1.0], [np.nan, 0.0, 0.0], ["a", "b", "c"], [-1],
                                  np.array([True, False])])
def test_a_reset_mask_the_numpy_env_refuses_is_refused_alike_and_changes_nothing(masked_pair, mask):
    host, device = masked_pair
    host.reset(seed=4)
    device.reset(seed=4)
    before = _arrays(device.world_state)
    expected = _refusal(host, lambda env: env.reset(options={"reset_mask": mask, "level": 0.0}))
    assert _refusal(device, lambda env: env.reset(options={"reset_mask": mask, "level": 0.0})) == expected
    for key, value in _arrays(device.world_state).items():
        np.testing.assert_array_equal(value, before[key], err_msg=key)
    np.testing.assert_array_equal(device.host.levels, host.levels)


def test_bad_input_on_the_device_names_what_was_wrong(pair):
    _, device = pair
    device.reset(seed=1)
    with pytest.raises(ValueError, match=r"agent 'suction': actions must have shape \(3, 4\)"):
        device.step({"suction": torch.zeros(2, 4, device=DEVICE), "grasper": torch.zeros(3, 4, device=DEVICE)})
    with pytest.raises(ValueError, match="dict over the agents"):
        device.step({"suction": torch.zeros(3, 4, device=DEVICE)})
    nan = torch.zeros(3, 4)
    nan[1, 2] = float("nan")
    with pytest.raises(ValueError, match="NaN or inf"):
        device.step({"suction": nan.to(DEVICE), "grasper": torch.zeros(3, 4, device=DEVICE)})
    with pytest.raises(ValueError, match="reset options reset_mask and level only"):
        device.reset(options={"blood_ml": [1.0, 1.0]})
    with pytest.raises(ValueError, match="level must lie in"):
        device.set_start_level(1.5)
    with pytest.raises(ValueError, match="device must be"):
        suction_debris_v8.batched_env(num_envs=2, device="tpu-9")
    with pytest.raises(ValueError, match="surgeon= is not taken on a device"):
        suction_debris_v8.batched_env(num_envs=2, device=DEVICE, surgeon="scripted")


@pytest.mark.extended
def test_the_torchrl_env_steps_on_the_device_as_on_the_host():
    """TorchRL's adapter with backend="jax" (the default on a GPU): the same rollout, masked resets included, as the
    host's, within float32."""
    pytest.importorskip("torchrl")
    from dvrl_marl.integrations.torchrl import SuctionDebrisTorchRLEnv

    def policy(td):
        observation = td.get(("agents", "observation"))
        return td.set(("agents", "action"), torch.tanh(3.0 * (observation[..., 4:8] - observation[..., 0:4])))

    rollouts = {}
    for backend in ("numpy", "jax"):
        env = SuctionDebrisTorchRLEnv(num_envs=WORLDS, device=DEVICE, backend=backend, max_cycles=25, seed=3,
                                      reward_type="dense", start_level=0.3)
        assert env.backend == backend
        rollouts[backend] = env.rollout(70, policy, break_when_any_done=False).cpu()
    host, device = rollouts["numpy"], rollouts["jax"]
    assert int(host["next", "done"].sum()) >= WORLDS * 2  # TorchRL reset the ended worlds by their mask
    for key in (("agents", "observation"), "state", ("next", "agents", "reward"), ("next", "done"),
                ("next", "is_success")):
        np.testing.assert_allclose(device[key].float().numpy(), host[key].float().numpy(), rtol=0, atol=1e-5,
                                   err_msg=str(key))
