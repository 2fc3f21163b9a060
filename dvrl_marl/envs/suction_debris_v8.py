"""Suction & debris removal: two PSMs clear a surgical phantom together (PettingZoo parallel environment).

```python
from dvrl_marl.envs import suction_debris_v8
env = suction_debris_v8.parallel_env()                      # both arms learn
env = suction_debris_v8.parallel_env(preset="benchmark")    # the benchmark's setting
env = suction_debris_v8.parallel_env(surgeon="scripted")    # the LND is driven by a scripted surgeon
env = suction_debris_v8.batched_env(num_envs=4096)          # N worlds as arrays
```

## Description
The paper's collaborative experiment (Sec. IV-D, Figs. 1, 6, 7) in one MuJoCo scene (``scenes/collaborative.xml``).
A Suction & Irrigation PSM (agent ``"suction"``) removes fake blood from the two cavities of a gelatin phantom; as
the blood level falls it reveals debris, 3 x 28 mm spring pins lying on the cavity floors, which a Large Needle
Driver PSM (agent ``"grasper"``) grasps by the paper's grasp rule and hands to the first assistant by holding
them within delta of the hand-off point. Arms are kinematic (eta steps through the closed-form IK, as in the
single-arm environments); debris moves only with the gripper (released elsewhere, it drops onto the surface
below it).

The **surgeon seat**: ``surgeon=None`` (default) leaves both arms to the learning agents. ``"scripted"`` puts the
built-in expert in ``surgeon_seat`` (``"grasper"`` by default, as in the paper where the surgeon worked the LND;
``"suction"`` also works), a callable ``policy(observation) -> action`` puts a learned surgeon there, and a
:mod:`dvrl_marl.teleop` device puts a human there. A bound seat leaves ``possible_agents`` and is driven inside
``step()``. A device that raises, returns an unusable action or misses ``teleop_timeout`` holds its seat still
that step (zero Delta, jaw or valve unchanged) and every agent's info gets ``teleop_lost=True``.

**A person in the seat** (``render_mode="human"`` with a ``human_operated`` device such as
:class:`~dvrl_marl.teleop.KeyboardDevice`): ``reset()`` opens the scene's window (:mod:`dvrl_marl.viewer`), shows
the first frame and waits until the person presses ENTER; steps then run in real time, one per 20 ms control
period (frames are dropped before steps are; ``realtime_stats()`` gives steps late and the worst lag). The window's
overlay shows the blood left per cavity, debris found and delivered, elapsed time and the key map. Closing the
window (or ESC) ends the episode at that step: every agent truncates with ``infos[agent]["viewer_closed"] = True``.

## Agents and Action Spaces
| agent | tool | action ``Box(-1, 1, (4,), float32)`` |
|---|---|---|
| ``"suction"`` | Suction & Irrigation | [Delta (3), valve: sucks when > 0; irrigates when < -0.5 where the scene irrigates] |
| ``"grasper"`` | Large Needle Driver | [Delta (3), phi: jaw j = (phi + 1) / 2] |

The tool is set at once, as in the paper, unless ``tool_speed`` (an option; 1, the default, is
the paper's instant tool) gives it a finite speed: the jaw moves towards j, and the valve's stroke (0 closed .. 1
open) towards open or closed, by at most ``tool_speed`` per step (:mod:`dvrl_marl.core.tools`); the valve draws while
more than half open. Exploration noise on the tool dimension then averages out over a stroke, and the mean action
and a sampled one move the tool alike (``benchmarks/tool_noise.py``). Two more options (off by
default: the paper's jaw) make the grasp one decision, as the valve is: ``jaw_command="switch"`` sets the jaw's target
by the command's sign (closed when phi <= 0, open when phi > 0) instead of j = (phi + 1) / 2, and
``hold_until_handoff=True`` keeps a held pin's jaw shut, whatever phi says, until the pin is handed off (it is never
dropped; the jaw follows phi again from the step after the hand-off).

``p <- p + eta * Delta`` (eta = 1 mm), projected into the workspace box, above the phantom, cavity floors and
table, and within the joint limits. A blocked move slides instead of stopping (:mod:`dvrl_marl.suction_debris.sliding`):

- a move into a cavity's wall has its component into the bowl taken away and slides along it (a frictionless
  contact: a tip pushed sideways against the wall rides up it and over the rim);
- a descending move that the wall leaves less than a tenth of its length the way it heads is made level instead, so
  the tip rides up the wall the way it was heading;
- the suction's descent still without headway over a cavity slides down the bowl, to the last of the blood (the
  grasper's does not: a grasper pressing down onto a pin stays over it);
- a move that the other instrument or the joint limits block falls back to its free components (the smallest given
  up first); a move that would make the instruments intersect is never made and counts as a contact.

Why: a policy acting by its mean action (what a robot is driven by) that pushed into a blocker saw the same
observation again and sent the same action for the rest of the episode (measured: the commonest end of the test
episodes that learnt teams failed; the results pages give the figures). A scripted expert never pushes into a
blocker, so its episodes are as if moves stopped. Values outside [-1, 1] are clipped; a missing or unknown agent key, NaN/inf or a wrong
shape raises ``ValueError`` naming the agent.

## Observation Space
Per agent, a flat ``Box(float64)`` with finite bounds; positions are normalised as in the paper,
x~ = (x - p_c) / rho with the scene's p_c and rho (``tasks/suction_debris_v8.toml``):

| slice | content |
|---|---|
| 0:3 | own tip~ |
| 3 | own tool: jaw 2j - 1 (grasper) or valve +1 open / -1 closed (suction; 2 x stroke - 1 with ``tool_speed``) |
| 4:7 | other arm's tip~ |
| 7:7+C | blood fraction left in each of the C = 2 cavities |
| then 6 per debris | [position~ (zeros while hidden), visible, held, delivered] |
| then 3 | hand-off point~ |
| with fluids, last 1 + 4C | irrigating side (-1 shut .. +1 open); per cavity its liquid, its blood's share of that liquid (concentration), its clot (liquid and clot as shares of its capacity), and its spill's time left (share) |

The fluids' slots (``observation_layout["irrigation"]``, ``["liquid"]``, ``["concentration"]``, ``["clot"]``,
``["spill"]``; :data:`dvrl_marl.suction_debris.layout.FLUID_FIELDS`) come only in a scene with irrigation or clots
(``irrigation_ml_s``, ``clot_share`` or ``clotting_ml_s`` above 0): elsewhere the observation is as before.

``state()`` / ``state_space`` give the global state for centralised critics: both tips, jaw, valve, blood
fractions, every debris with its true position (hidden ones included) and flags, the hand-off point.
``observation_layout`` and ``state_layout`` name the slices. With ``state_observations=True`` (an option, off by
default) every arm's observation, its features included, follows (``state_layout["suction_observation"]``,
``["grasper_observation"]``): a critic per arm then reads what its actor reads beside the state (the agent-specific
global state of Yu et al. 2022), as this project's trainer's MAPPO critic does.

**Image observations** (``image_size=S``, 32 to 256; off by default): each agent's observation becomes a ``Dict``:
``"observation"`` (the Box above, the arm's own proprioception among it), ``"image"`` (``Box(0, 255, (S, S, 3), uint8)``,
the ``endoscope`` camera's view, rows top to bottom; one camera, so both agents see the same image), with
``image_stereo=True`` ``"image_right"`` (the same Box: the stereo endoscope's right eye, the ``endoscope`` camera being
its left, 5 mm to its right and looking the same way, ``endoscope.STEREO_BASELINE_MM``; the pair shifts and turns as one
in every look) and, with ``image_depth=True``, ``"depth"`` (``Box(0, inf, (S, S), float32)``, metres along the left
camera's axis; a world's depth is the same in every batch to 1e-5 m, not bit for bit: the OpenGL interpolates
depth per place in its framebuffer, 4 um apart seen, where colour and segmentation are exact). They are drawn
for learning (:mod:`dvrl_marl.envs.endoscope`): what one drawing of the scene gives without shadows, reflections,
multisampling or marks, the blood opaque. On a software renderer the still phantom is drawn once, then per world only
what moves (exactly the one drawing); about 1,000 frames/s at 84 x 84 with 64 worlds or more on a 2-core CPU, 7x a
bare ``mujoco.Renderer``. On a GPU each world's whole scene is drawn in its own tile (about 10,000 frames/s on an
H200, 1.5x the bare renderer; ``docs/speed.md``). ``image_contexts=N`` draws with N GL contexts at once, each in a
thread of its own: two pay on a CPU (1.2-1.3x from 64 worlds), none on a GPU (``benchmarks/endoscope_speed.py``).
``image_segmentation=True`` adds ``"segmentation"`` (``(S, S) uint8``: 0
background, 1 tissue, 2 blood, 3 pin, 4 instrument; the left eye's). The batched env's ``images(parts=...)`` draws
any of ``"image"``, ``"image_right"``, ``"depth"`` and ``"segmentation"`` of every world now, whether or not the
observations carry it (the right eye costs a drawing of its own): a
dataset takes the segmentation on the steps it records alone (a segmentation alone is one drawing of what moves).
``image_appearance`` randomises each world's look per episode (domain randomisation, from the world's own stream:
a function of its seed and episode, like every reset draw): ``"train"`` draws within the training range below,
``"held_out"`` outside it (up to the second column), to test a pixel policy on looks it never met,
``"held_out_colour"`` (``_light``, ``_camera``, ``_noise``) that one quantity
held out and the rest drawn as in training; an ``endoscope.Appearance`` is a range of one's own:

| quantity | ``"train"``: at most | ``"held_out"``: between |
|---|---|---|
| tissue and blood colour (a clot, the mix and saline too), per channel (gain) | 1 +/- 0.15 | 0.15 and 0.3 off 1 |
| instruments' colour (gain) | 1 +/- 0.15 | 0.15 and 0.3 off 1 |
| light brightness (gain) / direction | 1 +/- 0.2 / 15 degrees | 0.2-0.4 off 1 / 15-30 degrees |
| endoscope position, per axis / direction | 3 mm / 2 degrees | 3-6 mm / 2-4 degrees |
| image noise (standard deviation, of 255) | 0-4 | 4-8 |
| worlds in the scene's own colours (the rest of their look drawn) | 25 % | none |

In the parallel, AEC and batched env, the seat env (``dvrl_marl/SurgeonSeat-v8``; its partner reads the
``"observation"``) and TorchRL's adapter (``"pixels"``, ``"depth"``, ``"segmentation"`` at the root, one camera for
both agents); the device env refuses them (they are drawn by OpenGL on the host). A seat that acts from them, the
image and its own tip and valve alone, is trained by ``dvrl-marl train suction_pixels_dagger`` or
``suction_pixels_estimates`` (:mod:`dvrl_marl.training.pixel_seat`; its figures on the results page).

## Rewards
``reward_type="sparse"`` (default): the team gets -1 per step until the task is complete, 0 on completion.
``"dense"``: shaped: +1 per ml of blood removed, +2 for each debris first lifted, +5 for each delivered, and
10 x the decrease of each agent's own distance (m) to what it should work on next (potential-based shaping).
``"guided"``: the dense reward plus the potential-based terms that made the task learnable from scratch
(:mod:`dvrl_marl.suction_debris.guidance`: the grasper's path over a pin to the hand-off, centred grasps, a hold bonus and a
waiting place; the suction's route over the cavities still to clear, a clearing bonus and a parking place, and
where there are clots 1 per ml of clot broken up; all measured around the phantom's rims); ``guidance={...}`` changes its settings (:class:`~dvrl_marl.suction_debris.guidance.Guidance`,
defaults: the configuration of record). Potential-based terms leave the optimal policy unchanged, and success is
the sparse rule in every case. All: each agent in an instrument-instrument contact gets ``-contact_penalty``, and
each agent ``-waste_penalty`` per ml of saline wasted, irrigated into no cavity (0 unless asked;
``suction_debris_mappo_irrigation_frugal.toml`` learns the irrigation level with 0.5).

## The scene's physics
- **Released pins fall** under gravity (one 20 ms step at a time) onto the surface below them, never through it; a
  falling pin can be caught again. A pin released beyond the phantom lands 5 mm inside the nearest edge of its top,
  in the endoscope's view and within reach.
- **Suction needs the surface**: the valve draws the full 2.5 ml/s while the tube's tip is at or under the blood
  surface of its cavity, less the higher it is above it, and nothing from ``suction_reach`` (2 mm) up.
- **The hand-off is judged where the jaws hold the pin**: the point of the pin's axis nearest the jaw's control point
  when it was grasped, carried with the tip, must come within delta (3 mm) of the hand-off point. A held pin is
  observed (and carried, in the dense reward) at that point.
- **A bleeding field** (``bleeding_ml_s``, off by default): each cavity starts bleeding at a seeded time in
  ``[0, bleeding_onset_s]`` (10 s) at a seeded rate in ``[0.5, 1] x bleeding_ml_s`` ml/s, up to its capacity. Success
  is unchanged, so the suction must keep the field clear while the grasper works.
- **Clotting** (``clotting_ml_s``, off by default; the worked example of "Adding a rule" in the design page): liquid
  blood clots at that rate in every cavity, up to the blood there, and suction draws none of a clot, so a cavity
  whose clot passes ``blood_threshold_ml`` cannot be cleared by suction alone (irrigation breaks clots up).
- **Irrigation** (``irrigation_ml_s``, off by default; ``preset="irrigation"`` turns it on at 1 ml/s with
  ``clot_share=0.5``): the Suction & Irrigation valve is signed: a command above 0 sucks, one below -0.5 irrigates,
  and between them the valve is shut (a script's "shut" is 0 there; without irrigation every command not above 0
  shuts it, as ever). The irrigating side has a stroke of its own, moved by ``tool_speed`` as the valve's is. Saline
  flows from the tip at ``irrigation_ml_s``: over a cavity with the tip below the phantom's top it enters that
  cavity, mixes with the liquid blood and breaks ``clot_per_saline_ml`` (1) ml of clot into liquid blood per ml of
  flow; anywhere else it is wasted. Suction draws the mix: blood in proportion to its share of the liquid (what the
  dense reward counts is the blood). A cavity filled past its capacity overflows: the rest spills over, counted, and
  the spill covers the phantom around the cavity (a pin's length beyond its mouth) for ``spill_s`` (2 s) after it
  stops, hiding the pins there from the observations (the endoscope draws it as the mix spread over the phantom). A
  clot settles on the floor: ``clot_share`` of each cavity's blood starts clotted, and a pin under the clot's level
  is not revealed until irrigation has broken it up. The endoscope draws each cavity's fluid by what it holds: dark
  clot, red blood, pink mix, clear saline.

## Starting State
Tips near their own side above the phantom (seeded jitter of +/-5 mm), grasper jaw open, valve closed; blood
``blood_ml`` per cavity; ``debris_count`` pins placed at seeded random slots and orientations on the cavity
floors, hidden under the blood. ``reset(options={"blood_ml": [v0, v1]})`` sets the blood for that episode (and
the ones after it); other keys are ignored with a warning.

Start levels (:mod:`dvrl_marl.suction_debris.start_levels`): ``reset(options={"level": x})`` (``start_level=x`` when made;
``"easy"`` = 0, ``"default"`` = 1, the default) draws an easy episode with probability ``1 - x``: cavities
emptier, fewer debris, the grasper starting near a visible pin (receding from it as ``x`` rises), 300 steps at
most (``easy_episode_steps``; ``None`` or 0: the task's own limit, so that every easy episode can be completed). Level
1 is the default task, bit for bit. The level holds for later episodes until set again, so a
library's curriculum can drive it at each reset (the batched env also takes one level per world, and
``set_start_level``).

## Episode End
Complete (every cavity below ``blood_threshold_ml`` and every debris delivered, at the same time): all agents terminate.
``max_cycles`` steps: all agents truncate. The person closed the window (``render_mode="human"``): all agents
truncate, with ``viewer_closed``. ``infos[agent]``: ``blood_remaining`` (ml, total),
``blood_remaining_per_cavity``, ``debris_delivered``, ``collision``, ``is_success``; in a scene with fluids also
the episode's figures as CRESSim reports its irrigation agents': ``clot_remaining`` (ml), ``saline_used_ml``,
``saline_wasted_ml`` (irrigated anywhere but into a cavity), ``overflow_events`` (overflows begun), ``overflow_s``
(time with a cavity overflowing) and ``overflow_ml`` (spilt).

## Arguments
Every form spells out the keywords it takes (``inspect.signature``, what ``help()`` and IPython show and complete;
generated below, form by form, with the task's parameters and their ranges):
``surgeon``, ``surgeon_seat``, ``reward_type``, ``render_mode`` ("rgb_array" | "human": a window, stepped in
real time at 50 Hz), ``max_cycles``,
``blood_ml``, ``blood_threshold_ml``, ``suction_rate_ml_s``, ``debris_count``, ``contact_penalty``,
``teleop_timeout`` and the paper's ``workspace_centre``, ``workspace_range``, ``step_size``,
``distance_threshold``, ``grasp_threshold``; defaults in ``tasks/suction_debris_v8.toml``.
Options that help learning (off by default; ``preset="benchmark"`` sets them): ``reward_type="guided"`` and ``guidance``,
``start_level``, and ``observation_features`` (a name in :data:`dvrl_marl.suction_debris.features.SCENE_FEATURE_SETS`): each
agent's observation gets those features appended (relative targets computed from the observation alone: the pin
to collect, the carry, the routes out of the cavities, zoomed offsets, a bleeding field's levels in thresholds and
the last pin; ``observation_layout["features"]``), the ones the learned seats read. ``tool_speed`` (above): a tool that a Gaussian policy's noise cannot flick open;
``jaw_command`` and ``hold_until_handoff`` (above): a grasp a Gaussian policy decides once and cannot undo by noise;
``state_observations`` (above): both arms' observations in the state, for a library's centralised critics.
``normalize_observations``: every agent's observation (features included) and the state as ``(x - centre) / spread``
per dimension, fixed centres and spreads measured on the scripted team's and random episodes
(:mod:`dvrl_marl.suction_debris.observation_scaling`; ``observation_scaling`` maps back): inputs at one scale for a library
whose networks do not normalise their own (the pins' y and a carry's offsets vary 25-100 times less than a tip's
position). The surgeon seat reads the scene's units either way.

## Batched form
``batched_env(num_envs=N, **same keyword arguments)`` steps N worlds as arrays (observations ``(N, obs_dim)``,
rewards and flags ``(N,)``, automatic per-world reset); world ``i`` seeded ``s`` is this environment seeded
``s + i`` (:mod:`dvrl_marl.envs.suction_debris_batched`). ``dvrl_marl.integrations.torchrl.SuctionDebrisTorchRLEnv``
exposes it to TorchRL.

## Presets
``preset="benchmark"`` is the setting of the benchmark table, the configurations of record and the reference team
(:data:`dvrl_marl.suction_debris.presets.PRESETS`): ``reward_type="guided"``,
``observation_features="suction_debris_cleared_pins_zoom"``, ``state_observations=True``, ``contact_penalty=0.1``,
``tool_speed=0.1``, ``jaw_command="switch"``, ``hold_until_handoff=True``. Keywords given beside it win.
``preset="irrigation"`` is the benchmark's setting on a clotted field, the benchmark's irrigation level:
``irrigation_ml_s=1.0``, ``clot_share=0.5``, ``max_cycles=2500`` (the scripted irrigating
team needs about 1,500 steps; the suction-only plan of the other levels finishes none: ``benchmarks/irrigation_field.py``).
``preset="default"`` (the default) is the task file as it is. Every form takes it (parallel, AEC, batched, the seat
env, the TorchRL and BenchMARL tasks).

**In JaxMARL's form** (``pip install "dvrl-marl[jax]"``): ``jax_env(**same keyword arguments)`` is one world as pure
functions, ``reset(key) -> (observations, state)`` and ``step(key, state, actions) -> (observations, state, rewards,
dones, infos)`` with ``dones["__all__"]``, for ``jax.jit(jax.vmap(env.step))`` over any number of worlds; the same step
as every other form, world i of a vmapped batch equal to world i of the batched env seeded ``seed_of(key_i)``
(:mod:`dvrl_marl.envs.suction_debris_jax`).

## Version History
- v8: the one current version. Its rules are v7's of the unreleased 0.1.0 (blocked moves slide and settle, the
  hand-off judged at the grip, pins that stay in view, falling pins, graded suction, optional bleeding); the
  benchmark's setting became ``preset="benchmark"``. Earlier versions (v0-v7) were never released; commit 36a42a0
  reproduces their records (``docs/migration.md`` maps their names).
"""

from __future__ import annotations

from dvrl_marl.envs.suction_debris import (AGENTS, PRESETS, TASK, SceneLayout, SuctionDebrisEnv, SuctionDebrisParams,
                                           batched_env, env, jax_env, parallel_env, raw_env)

__all__ = ["parallel_env", "env", "raw_env", "batched_env", "jax_env", "AGENTS", "TASK", "PRESETS",
           "SuctionDebrisEnv", "SuctionDebrisParams", "SceneLayout"]
