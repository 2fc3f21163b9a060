"""The batched simulation core: the state of N worlds as arrays, advanced by one array step.

Each task has a core (:mod:`~dvrl_marl.core.reach`, :mod:`~dvrl_marl.core.pick`,
:mod:`~dvrl_marl.suction_debris.rules`) that knows nothing of Gymnasium or PettingZoo; the shells in
:mod:`dvrl_marl.envs` format its arrays for their API. World ``i`` of a batch seeded ``s`` is the single environment
reset with seed ``s + i`` (Gymnasium's convention for vector environments), then reset without a seed after each
episode. The collaborative core imports no MuJoCo; importing this package imports none of its modules.
"""
