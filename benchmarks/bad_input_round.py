"""A round of bad input, as a careless user gives it: every case is either taken (and then behaves) or refused with a
``ValueError`` (or argparse's exit 2) whose message names the value or the option; anything else is a defect: another
exception (numpy's, ctypes', a ``KeyError``), a traceback from the command line, a refused call that changed a world,
or NaN where a number was due.

    python benchmarks/bad_input_round.py --seed 11 --json baselines/results/bad_input_round_4.json

Kinds of case: the env's options, actions and reset options (the numpy batched env, and the device env where JAX is
installed: the same rules and messages), seeds, policy files with a field broken, what a policy is called on, and
the command line's flags. Each case is seeded; the record lists the defects found, with their messages.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import io
import json
import random
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import provenance  # noqa: E402

#: Values a careless user passes where another was due.
BAD = [None, "x", "", -1, 0, 1.5, -0.5, float("nan"), float("inf"), -float("inf"), 2**64, [], [1], {}, True, False,
       "1", b"1", (1, 2), np.array([np.nan]), np.float32(2.5), object()]


class Round:
    def __init__(self):
        self.counts = {"taken": 0, "refused": 0, "defect": 0}
        self.defects: list[dict] = []
        self.kinds: dict[str, int] = {}

    def case(self, kind: str, what: str, call, named=()) -> None:
        """Run ``call``: it is taken, or refused by a ValueError naming one of ``named`` (any text, if empty)."""
        self.kinds[kind] = self.kinds.get(kind, 0) + 1
        try:
            call()
        except ValueError as error:
            message = str(error)
            if named and not any(str(name) in message for name in named):
                self._defect(kind, what, f"refused without naming {list(named)}: {message}")
            else:
                self.counts["refused"] += 1
            return
        except Defect as defect:
            self._defect(kind, what, str(defect))
            return
        except (TypeError, FileNotFoundError) as error:  # Python's own refusal of a keyword; a file named
            if "unexpected keyword argument" in str(error) or isinstance(error, FileNotFoundError):
                self.counts["refused"] += 1
            else:
                self._defect(kind, what, f"{type(error).__name__}: {error}")
            return
        except Exception as error:  # noqa: BLE001 (what the round looks for)
            if type(error).__module__.startswith("gymnasium") and "seed" in str(error).lower():
                self.counts["refused"] += 1  # (Gymnasium's own seeding refuses it, by name)
                return
            self._defect(kind, what, f"{type(error).__name__}: {error}")
            return
        self.counts["taken"] += 1

    def _defect(self, kind, what, message) -> None:
        self.counts["defect"] += 1
        self.defects.append({"kind": kind, "case": what, "message": message[:400]})


class Defect(Exception):
    """A call that was taken but did wrong (a world changed by a refusal, NaN out)."""


def _state(env) -> dict:
    """Every field of the env's state record (the numpy and the device env alike give an ``EnvState``)."""
    from dvrl_marl.suction_debris.scene_state import SPECS

    state = env.world_state
    out = {name: np.array(getattr(state.scene, name)) for name in SPECS}
    out["levels"] = np.array(state.levels)
    out.update({f"potential {agent}": np.array(value) for agent, value in (state.potential or {}).items()})
    return out


def _unchanged(before: dict, after: dict) -> bool:
    return all(np.array_equal(before[key], after[key], equal_nan=True) for key in before)


def env_options(round_: Round, rng: random.Random, count: int) -> None:
    from dvrl_marl.envs import suction_debris_v8

    options = ["num_envs", "surgeon", "surgeon_seat", "reward_type", "render_mode", "max_cycles", "autoreset_mode",
               "render_world", "task", "guidance", "observation_features", "start_level", "easy_episode_steps",
               "state_observations", "normalize_observations", "image_size", "image_depth", "image_segmentation",
               "image_stereo", "image_appearance", "image_contexts", "width", "height", "preset", "tool_speed",
               "jaw_command", "hold_until_handoff", "bleeding_ml_s", "teleop_timeout", "irrigation_ml_s", "clot_share",
               "clot_per_saline_ml", "spill_s", "no_such_option"]
    for _ in range(count):
        option, value = rng.choice(options), rng.choice(BAD)
        kwargs = {option: value}
        if option == "num_envs":
            make = lambda: suction_debris_v8.batched_env(**kwargs)  # noqa: E731
        else:
            make = lambda: suction_debris_v8.batched_env(num_envs=2, **kwargs)  # noqa: E731

        def build_and_step(make=make):
            env = make()
            observations, _ = env.reset(seed=0)
            out = env.step({agent: np.zeros((env.num_envs, 4)) for agent in env.possible_agents})
            for agent in env.possible_agents:
                vector = observations[agent]["observation"] if isinstance(observations[agent], dict) else observations[agent]
                if not np.all(np.isfinite(vector)) or not np.all(np.isfinite(out[1][agent])):
                    raise Defect(f"{option}={value!r} gave NaN or inf")
            env.close()

        round_.case("env option", f"{option}={value!r}", build_and_step, named=(option.split("_")[0],))


def actions(round_: Round, rng: random.Random, count: int, device: bool) -> None:
    from dvrl_marl.envs import suction_debris_v8

    env = suction_debris_v8.batched_env(num_envs=3, **({"device": "cpu"} if device else {}))
    env.reset(seed=1)
    kind = "device actions" if device else "actions"
    for _ in range(count):
        agent = rng.choice(env.possible_agents)
        form = rng.randrange(6)
        good = np.zeros((3, 4))
        if form == 0:
            bad = np.full((3, 4), rng.choice([np.nan, np.inf, -np.inf]))
        elif form == 1:
            bad = good.copy()
            bad[rng.randrange(3), rng.randrange(4)] = rng.choice([np.nan, np.inf, -np.inf])
        elif form == 2:
            bad = np.zeros((rng.choice([1, 2, 4]), rng.choice([3, 4, 5])))
        elif form == 3:
            bad = rng.choice(BAD)
        elif form == 4:
            bad = np.array([["a"] * 4] * 3)
        else:
            bad = good.astype(np.float32) + np.float32(rng.uniform(-3, 3))  # taken (clipped), as the box says
        given = {a: (bad if a == agent else good) for a in env.possible_agents}
        if rng.random() < 0.1:
            given = {agent: bad}  # an agent missing
        before = _state(env)

        def step(given=given, before=before):
            try:
                env.step(given)
            except ValueError:
                if not _unchanged(before, _state(env)):
                    raise Defect("a refused step changed the worlds") from None
                raise

        round_.case(kind, f"{agent}: {type(bad).__name__} {np.shape(bad) if hasattr(bad, 'shape') else bad!r}", step,
                    named=("agent", "actions", "dict over the agents"))


def reset_options(round_: Round, rng: random.Random, count: int, device: bool) -> None:
    from dvrl_marl.envs import suction_debris_v8

    env = suction_debris_v8.batched_env(num_envs=3, autoreset_mode="disabled", **({"device": "cpu"} if device else {}))
    env.reset(seed=1)
    keys = ["reset_mask", "level", "blood_ml", "debris_count", "tip_positions", "no_such_option"]
    masks = [[0, 1], [2, 0], [3], [-1], [0.5, 0.0, 1.0], [True, False], [True, False, True], ["a", "b", "c"],
             [np.nan, 0, 0], np.array([1, 0, 1], dtype=bool), [[0, 1]], "all", 1]
    kind = "device reset" if device else "reset"
    for _ in range(count):
        key = rng.choice(keys)
        value = rng.choice(masks) if key == "reset_mask" else rng.choice(BAD)
        options = {key: value}
        if device and key not in ("reset_mask", "level"):
            options = {"reset_mask": [0], key: value}
        before = _state(env)

        def reset(options=options, before=before):
            try:
                env.reset(options=options)
            except ValueError:
                if not _unchanged(before, _state(env)):
                    raise Defect("a refused reset changed the worlds") from None
                raise

        round_.case(kind, f"{options!r}", reset, named=(key.split("_")[0], "reset", "level", "mask", "option", "world"))


def seeds(round_: Round, rng: random.Random, count: int) -> None:
    import gymnasium as gym

    from dvrl_marl.envs import suction_debris_v8

    makers = [lambda: suction_debris_v8.batched_env(num_envs=2), lambda: suction_debris_v8.parallel_env(),
              lambda: gym.make("dvrl_marl/PSMReach-v1"), lambda: gym.make("dvrl_marl/SurgeonSeat-v8")]
    envs = [make() for make in makers]
    values = [-1, 2**64, 2**64 - 1, 2**63, 1.5, "3", None, 0, [0, 1], [0, 2**64], float("nan"), True, np.int64(4),
              np.uint64(2**64 - 2)]
    for _ in range(count):
        env, seed = rng.choice(envs), rng.choice(values)
        round_.case("seed", f"{type(env).__name__} seed={seed!r}", lambda env=env, seed=seed: env.reset(seed=seed),
                    named=("seed", "must"))


def policy_files(round_: Round, rng: random.Random, count: int, folder: Path) -> None:
    from dvrl_marl import policies

    names = ["reach-lnd", "marl-grasper", "marl-suction-pixels", "benchmark-suction"]
    for index in range(count):
        name = rng.choice(names)
        target = folder / f"policy{index}"
        shutil.copytree(policies.shipped_dir() / name, target)
        spec = json.loads((target / "policy.json").read_text())
        path = _pick_path(spec, rng)
        value = rng.choice(BAD)
        try:
            _set_path(spec, path, value)
            text = json.dumps(spec, allow_nan=True)
        except (TypeError, ValueError):
            text = json.dumps(spec, default=str, allow_nan=True)
        (target / "policy.json").write_text(text)

        def load_and_act(target=target, name=name):
            import gymnasium as gym

            policy = policies.load(target)
            if not policy.spec.get("agent") and policy.spec["env_id"] not in gym.registry:
                return  # (loaded: a numpy policy acts on what it is given; `dvrl-marl evaluate` names the env id)
            observation = _observation_for(policy)
            action = policy(observation)
            if not np.all(np.isfinite(action)):
                raise Defect("a policy file taken at load gave NaN actions")

        round_.case("policy file", f"{name}: {'/'.join(map(str, path))} = {value!r}", load_and_act,
                    named=("policy.json", "policy", "features", "keep_clear", "image", "observation"))
        shutil.rmtree(target)


def _pick_path(spec, rng):
    path, node = [], spec
    while True:
        if isinstance(node, dict) and node:
            key = rng.choice(list(node))
        elif isinstance(node, list) and node:
            key = rng.randrange(len(node))
        else:
            return path
        path.append(key)
        node = node[key]
        if rng.random() < 0.45:
            return path


def _set_path(spec, path, value):
    node = spec
    for key in path[:-1]:
        node = node[key]
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, (type(None), str, int, float, list, dict, bool)):
        value = str(value)
    node[path[-1]] = value


_OBSERVATIONS: dict = {}


def _observation_for(policy):
    """An observation of the env a policy names (made once per kind)."""
    import gymnasium as gym

    from dvrl_marl.envs import suction_debris_v8

    key = (policy.spec.get("env_id"), policy.spec.get("preset"), json.dumps(policy.image_options))
    if key not in _OBSERVATIONS:
        if policy.spec.get("agent"):
            env = suction_debris_v8.batched_env(num_envs=2, **(policy.image_options or {}),
                                                **({"preset": policy.spec["preset"]} if policy.spec.get("preset") else {}))
            observations, _ = env.reset(seed=0)
            _OBSERVATIONS[key] = observations[policy.spec["agent"]]
        else:
            _OBSERVATIONS[key] = gym.make(policy.spec["env_id"]).reset(seed=0)[0]
    return _OBSERVATIONS[key]


def policy_calls(round_: Round, rng: random.Random, count: int) -> None:
    from dvrl_marl import policies

    loaded = {name: policies.load(name) for name in ("reach-lnd", "marl-grasper", "marl-suction-pixels")}
    for _ in range(count):
        name = rng.choice(list(loaded))
        policy = loaded[name]
        observation = copy.deepcopy(_observation_for(policy))
        form = rng.randrange(6)
        if isinstance(observation, dict):
            key = rng.choice(list(observation))
            value = np.asarray(observation[key])
            changed = [value.astype(np.float64) / 255.0 if value.dtype == np.uint8 else value * np.nan,
                       value[..., :-1], value.astype(np.uint16) if value.dtype == np.uint8 else value[:, None],
                       None, value[:1], value.tolist()][form]
            if changed is None:
                observation.pop(key)
            else:
                observation[key] = changed
        else:
            value = np.asarray(observation)
            observation = [value * np.nan, value[..., :-1], np.zeros((2, value.shape[-1] + 3)), "x", value[None],
                           value.tolist()][form]
        round_.case("policy call", f"{name}: form {form}", lambda policy=policy, observation=observation: _act(policy, observation),
                    named=("policy", "observation", "image", "reads"))


def _act(policy, observation):
    action = policy(observation)
    if not np.all(np.isfinite(action)):
        raise Defect("NaN action")


def command_line(round_: Round, rng: random.Random, count: int, folder: Path) -> None:
    from dvrl_marl.cli import main

    cases = [
        ["render", "--out", "{tmp}/x"], ["render", "--out", "{tmp}/x.gif"], ["render", "--width", "0"],
        ["render", "--width", "30000", "--height", "8", "--out", "{tmp}/w.png"], ["render", "--scene", "nope"],
        ["render", "--height", "-3"], ["evaluate", "nope"], ["evaluate", "reach-lnd", "--episodes", "0"],
        ["evaluate", "reach-lnd", "--env", "dvrl_marl/Nope-v9", "--episodes", "1"],
        ["evaluate", "reach-lnd", "--tool", "scalpel"], ["evaluate", "reach-lnd", "--seed", "-1"],
        ["evaluate", "pick-lnd", "--tool", "suction_irrigation", "--episodes", "1"],
        ["evaluate", "marl-grasper", "--video", "{tmp}/v.mp4", "--episodes", "1"],
        ["evaluate-team", "--suction", "nope", "--episodes", "1"],
        ["evaluate-team", "--suction", "marl-grasper", "--episodes", "1"],
        ["evaluate-team", "--suction", "benchmark-suction", "--grasper", "marl-grasper", "--episodes", "1"],
        ["evaluate-team", "--preset", "nope"], ["evaluate-team", "--json", "{tmp}"],
        ["evaluate-team", "--grasper", "yielding", "--episodes", "1"],
        ["train", "nope"], ["train", "suction_debris_mappo", "--trainer", "tpu"],
        ["train", "suction_debris_mappo", "--trainer", "torchrl", "--device", "cuda"],
        ["train", "suction_debris_mappo", "--trainer", "jax", "--device", "cuda:x"],
        ["train", "suction_debris_mappo", "--trainer", "jax", "--device", "cpu:0"],
        ["train", "suction_debris_mappo", "--steps", "0"], ["train", "suction_debris_mappo", "--seed", "x"],
        ["train", "suction_debris_mappo", "--out", "{file}"], ["train", "reach_lnd_ddpg_her", "--validators", "2"],
        ["train", "reach_lnd_ddpg_her", "--export", "{file}"], ["train", "suction_debris_mappo", "--resume",
                                                                "--out", "{tmp}/nothing"],
        ["demo", "--surgeon", "nobody"], ["demo", "--max-cycles", "0"], ["demo", "--record", "{tmp}"],
        ["demo", "--out", "{file}"], ["demo", "--pipeline", "nope", "--no-video", "--max-cycles", "2"],
        ["teleop", "--port", "70000"], ["teleop", "--host", "no.such.host.invalid"], ["teleop", "--seat", "scalpel"],
        ["plot", "{tmp}/missing"], ["plot", "{file}"], ["nothing"], [],
    ]
    for _ in range(count):
        argv = [part.replace("{tmp}", str(folder)).replace("{file}", str(folder / "a_file")) for part in rng.choice(cases)]
        (folder / "a_file").write_text("x")

        def run(argv=argv):
            stderr = io.StringIO()
            with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
                try:
                    status = main(argv)
                except SystemExit as exit_:
                    status = exit_.code
            if status not in (2,) or "Traceback" in stderr.getvalue():
                raise Defect(f"exit {status}: {stderr.getvalue()[-300:]}")
            raise ValueError(stderr.getvalue())

        round_.case("command line", " ".join(argv), run)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scale", type=float, default=1.0, help="cases per kind, times this")
    parser.add_argument("--json", help="write the round's record here")
    args = parser.parse_args(argv)
    code = provenance.code_state()  # (as the run starts)
    rng = random.Random(args.seed)
    round_ = Round()
    began = time.perf_counter()
    scale = lambda n: max(1, int(n * args.scale))  # noqa: E731
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        env_options(round_, rng, scale(200))
        actions(round_, rng, scale(200), device=False)
        reset_options(round_, rng, scale(150), device=False)
        try:
            import jax  # noqa: F401
            device = True
        except ImportError:
            device = False
        if device:
            actions(round_, rng, scale(100), device=True)
            reset_options(round_, rng, scale(100), device=True)
        seeds(round_, rng, scale(100))
        policy_files(round_, rng, scale(200), folder)
        policy_calls(round_, rng, scale(150))
        command_line(round_, rng, scale(120), folder)
    total = sum(round_.counts.values())
    print(f"{total} cases ({', '.join(f'{kind} {n}' for kind, n in round_.kinds.items())}): "
          f"{round_.counts['taken']} taken, {round_.counts['refused']} refused by name, "
          f"{round_.counts['defect']} defects ({time.perf_counter() - began:.0f} s)")
    for defect in round_.defects[:40]:
        print(f"  DEFECT [{defect['kind']}] {defect['case']}: {defect['message'][:200]}")
    if args.json:
        Path(args.json).write_text(json.dumps({
            "cases": total, "kinds": round_.kinds, **round_.counts, "defects": round_.defects,
            "device": device, "seed": args.seed,
            "command": "python benchmarks/bad_input_round.py " + " ".join(sys.argv[1:]),
            "code": code}, indent=1) + "\n")
    return 1 if round_.defects else 0


if __name__ == "__main__":
    sys.exit(main())
