"""The collaborative scene in one folder: everything that makes suction & debris removal this task, and nothing of
how an API presents it (VMAS's split: a scenario's rules apart from the environment that drives them).

With its task file, ``tasks/suction_debris_v8.toml`` (every value with its source), this folder is where a rule is
added (docs/design.md, "Adding a rule"):

| module | what it holds |
|---|---|
| ``task`` | the task's parameters (``SuctionDebrisParams``): each field's type is its range; the task file's schema |
| ``scene_state`` | the state of N worlds as one frozen record of arrays (``SceneState``), each field named once |
| ``rules`` | the step, written once for numpy and JAX (``CollaborativeCore``): reset, moves, suction, irrigation, grasps, hand-off, rewards |
| ``phantom``, ``scene_geometry`` | the phantom and its cavities, read from the scene file |
| ``instruments``, ``sliding``, ``lean_move`` | the instruments' clearance, how a blocked move resolves, one world's fast move |
| ``layout`` | actions, observations and the global state by name |
| ``features``, ``observation_scaling`` | what a policy computes from an observation; the measured scales |
| ``guidance`` | the guided reward's shaping |
| ``scripted_team``, ``places`` | the scripted experts (the heuristic) and where the arms wait |
| ``presets``, ``start_levels``, ``scene_options``, ``appearance`` | named settings, start levels, the options' records, the endoscope's looks |

Nothing here imports MuJoCo, Gymnasium or PettingZoo: the environments in :mod:`dvrl_marl.envs` (the parallel,
batched, device and JAX forms, the surgeon seat) hold a state and call these. Users import
:mod:`dvrl_marl.envs.suction_debris_v8`; importing this package imports none of its modules.
"""
