"""Where a learnt team acting by its mean action fails: what each seat was doing when its test episodes ran out.

A policy that succeeds with its exploration noise and fails by its mean action (what a robot is driven by) has
resting points the noise shook it out of. For every failed test episode this prints, per seat, what its tip did over
the episode's last ``--window`` steps: ``pushing`` (it stood still while commanding a move: the command goes into
something, a wall, the workspace's face, the other instrument), ``resting`` (it stood still at a command of about
zero: the policy's own fixed point) or ``moving``; whether the grasper held a pin within reach of the hand-off point;
which cavities kept blood above the clearing mark; where the scene irrigates, what the suction's signed valve did
(``irrigating``, ``sucking``, or ``shut``: its mean command below -VALVE_OPEN, above it, or between). Counted by class,
with an example episode of each.

    python benchmarks/mean_action_failures.py baselines/results/benchmark/runs/<a run>

A run of this project's trainer (its env options: its ``config.toml``'s ``[env]``, its policies: ``policies/``) or a
BenchMARL run of ``marl_benchmark.py`` (``env_options.json`` and the final ``policy.pt`` it saves; needs BenchMARL's
environment). The test episodes are the benchmark's (seeds ``teams.EVAL_SEED`` on). ``--option KEY=VALUE`` plays the
policies on a changed scene (an env keyword argument over the run's own, the value read as JSON where it parses,
else as text), e.g. ``--option blocked_moves=climb``: what a rule's change does to a learnt team, untrained.
``--sampled SEAT:SLOT`` (a BenchMARL run) samples that part of a seat's action as in training and keeps the mean
action elsewhere, e.g. ``--sampled suction:tool``: which part of a team leans on its exploration noise.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np

#: A tip that moved less than this (normalised units, about 0.8 mm) over the window stood still.
STILL = 0.01
#: A command whose largest motion component is below this is "about zero".
ZERO_COMMAND = 0.05
#: Within this (normalised, 12 mm) of the hand-off point a held pin counts as "at the hand-off".
NEAR_HANDOFF = 0.15
#: A suction valve whose mean command over the window lies beyond this (either sign) was irrigating or sucking.
VALVE_OPEN = 0.1


def is_benchmarl_run(run: Path) -> bool:
    return (run / "policy.pt").is_file() and (run / "env_options.json").is_file()


#: The parts of a seat's action ``--sampled`` names (the action layout's slots).
SLOTS = ("move", "tool")


def team_of(run: Path, sampled: tuple = ()):
    """A run's env options and its team's mean action, ``act({agent: (N, obs)}) -> {agent: (N, 4)}``; the
    ``(seat, slot)`` pairs of ``sampled`` (a BenchMARL run's) drawn from the policy's distribution instead."""
    from dvrl_marl.envs import suction_debris_v8
    from dvrl_marl.suction_debris.layout import MOVE, TOOL

    if is_benchmarl_run(run):
        import json

        import torch
        from tensordict import TensorDict
        from torchrl.envs.utils import ExplorationType, set_exploration_type

        policy = torch.load(run / "policy.pt", weights_only=False)
        agents = suction_debris_v8.AGENTS

        def actions_of(batch, kind):
            with torch.no_grad(), set_exploration_type(kind):
                return policy(batch).get(("agents", "action")).numpy().astype(np.float64)

        def act(observations):
            stacked = torch.as_tensor(np.stack([observations[a] for a in agents], axis=1), dtype=torch.float32)
            batch = TensorDict({"agents": TensorDict({"observation": stacked}, batch_size=stacked.shape[:2])},
                               batch_size=stacked.shape[:1])
            action = actions_of(batch, ExplorationType.DETERMINISTIC)
            if sampled:
                drawn = actions_of(batch, ExplorationType.RANDOM)
                for seat, slot in sampled:
                    part = {"move": MOVE, "tool": TOOL}[slot]
                    action[:, agents.index(seat), part] = drawn[:, agents.index(seat), part]
            return {agent: action[:, index] for index, agent in enumerate(agents)}

        options = json.loads((run / "env_options.json").read_text())
    else:
        if sampled:
            raise ValueError("--sampled needs a BenchMARL run (its policy.pt keeps the distribution); this project's "
                             "exported policies act by their mean")
        from dvrl_marl import policies
        from dvrl_marl.files import read_toml

        # the run's [env] table alone: a run recorded with a trainer key retired since still names its scene
        options = dict(read_toml(run / "config.toml").get("env", {}))
        options.pop("normalize_observations", None)  # the exported policies fold it in: they read the scene's units
        team = {agent: policies.load(run / "policies" / f"marl-{agent}") for agent in suction_debris_v8.AGENTS}

        def act(observations):
            return {agent: np.asarray(team[agent](observations[agent]), dtype=np.float64) for agent in observations}
    return {k: v for k, v in options.items() if k != "reward_type"}, act


def classify(run: Path, episodes: int, window: int, changes: dict | None = None,
             sampled: tuple = ()) -> tuple[float, Counter, dict]:
    from dvrl_marl.envs import suction_debris_v8
    from dvrl_marl.suction_debris.layout import MOVE, TOOL
    from dvrl_marl.training import teams

    options, act = team_of(run, sampled)
    options = {**options, **(changes or {})}
    env = suction_debris_v8.batched_env(num_envs=episodes, autoreset_mode="disabled", **options)
    observations, _ = env.reset(seed=teams.EVAL_SEED)
    layout = env.observation_layout
    tips = {agent: [] for agent in env.agents}
    commands = {agent: [] for agent in env.agents}
    valve = []
    irrigates = env.params.irrigation_ml_s > 0.0
    done = np.zeros(episodes, dtype=bool)
    success = np.zeros(episodes, dtype=bool)
    info = {}
    scaling = env.observation_scaling  # (a run with normalize_observations: positions are read in the scene's units)

    def plain(agent, observation):
        return observation if scaling is None else scaling.plain_observation(agent, observation)

    while not done.all():
        actions = act(observations)
        for agent in env.agents:  # (only the last window is kept)
            tips[agent] = (tips[agent] + [plain(agent, observations[agent])[:, layout["own_tip"]].copy()])[-window:]
            commands[agent] = (commands[agent] + [actions[agent][:, MOVE]])[-window:]
        valve = (valve + [np.asarray(actions["suction"])[:, TOOL]])[-window:]
        observations, _, terminations, truncations, infos = env.step(actions)
        info = infos[env.agents[0]]
        success |= ~done & info["is_success"]
        done |= terminations[env.agents[0]] | truncations[env.agents[0]]
    blood = info["blood_remaining_per_cavity"]
    threshold = env.params.blood_threshold_ml
    grasper = plain("grasper", observations["grasper"])
    debris = grasper[:, layout["debris"]].reshape(episodes, -1, 6)
    holding = debris[:, :, 4] > 0.5
    held_at = (debris[:, :, :3] * holding[..., None]).sum(axis=1)
    at_handoff = holding.any(axis=1) & (np.linalg.norm(held_at - grasper[:, layout["handoff"]], axis=1) < NEAR_HANDOFF)
    jaw_closed = env.core.arms["grasper"].jaw < env.params.grasp_threshold
    classes, examples = Counter(), {}
    for world in np.flatnonzero(~success):
        parts = []
        for agent in env.agents:
            path = np.stack(tips[agent])[:, world]
            command = np.abs(np.stack(commands[agent])[:, world]).max(axis=1).mean()
            still = np.linalg.norm(path[-1] - path[0]) < STILL
            parts.append(f"{agent} {'moving' if not still else 'pushing' if command > ZERO_COMMAND else 'resting'}")
        parts.append("grasper holds a pin at the hand-off" if at_handoff[world] else
                     "grasper holds a pin" if holding[world].any() else
                     f"grasper empty, jaw {'closed' if jaw_closed[world] else 'open'}")
        if irrigates:
            mean = float(np.mean(np.stack(valve)[:, world]))
            parts.append(f"valve {'irrigating' if mean < -VALVE_OPEN else 'sucking' if mean > VALVE_OPEN else 'shut'}")
        left = [str(c) for c in range(blood.shape[1]) if blood[world, c] >= threshold]
        parts.append(f"blood left in cavity {', '.join(left)}" if left else "cavities clear")
        key = "; ".join(parts)
        classes[key] += 1
        if key not in examples:
            examples[key] = (int(world), {agent: np.round(tips[agent][-1][world], 2).tolist() for agent in env.agents},
                             {agent: np.round(commands[agent][-1][world], 2).tolist() for agent in env.agents})
    return float(success.mean()), classes, examples


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run folders (this project's trainer's, BenchMARL's)")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--window", type=int, default=50, help="steps at the end of an episode looked at")
    parser.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                        help="an env keyword argument over the run's own (repeatable), e.g. blocked_moves=climb")
    parser.add_argument("--sampled", action="append", default=[], metavar="SEAT:SLOT",
                        help="sample this part of a seat's action as in training (a BenchMARL run; repeatable), "
                             "e.g. suction:tool")
    args = parser.parse_args(argv)
    if args.episodes < 1 or args.window < 2:
        parser.error("--episodes must be >= 1 and --window >= 2")
    from dvrl_marl.envs import suction_debris_v8

    sampled = []
    for part in args.sampled:
        seat, _, slot = part.partition(":")
        if seat not in suction_debris_v8.AGENTS or slot not in SLOTS:
            parser.error(f"--sampled {part!r}: expected SEAT:SLOT with SEAT one of {list(suction_debris_v8.AGENTS)} "
                         f"and SLOT one of {list(SLOTS)}, e.g. suction:tool")
        sampled.append((seat, slot))
    changes = {}
    for option in args.option:
        key, sep, value = option.partition("=")
        if not sep or not key:
            parser.error(f"--option {option!r}: expected KEY=VALUE, e.g. blocked_moves=climb")
        try:
            changes[key] = json.loads(value)
        except json.JSONDecodeError:
            changes[key] = value
    for run in args.runs:
        if not is_benchmarl_run(run) and not ((run / "config.toml").is_file() and (run / "policies").is_dir()):
            parser.error(f"{run}: neither a run folder of this project's trainer (config.toml, policies/) nor a "
                         f"BenchMARL run of marl_benchmark.py (policy.pt, env_options.json)")
        try:
            success, classes, examples = classify(run, args.episodes, args.window, changes, tuple(sampled))
        except (TypeError, ValueError) as error:  # an option the scene refuses, named
            parser.error(f"{run}: {error}")
        on = f" on {changes}" if changes else ""
        acting = "the mean action" + (f", {', '.join(args.sampled)} sampled" if sampled else "")
        print(f"{run.name}{on}: success by {acting} {success:.2f}; {sum(classes.values())} failed")
        for key, count in classes.most_common():
            world, tip, command = examples[key]
            print(f"  {count:3d}  {key}   (e.g. episode {world}: tips {tip}, last commands {command})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
