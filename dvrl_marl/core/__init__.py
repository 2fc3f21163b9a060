"""The batched simulation core: the state of N worlds as arrays, advanced by one array step.

Each task has a core (:class:`ReachCore`, :class:`PickCore`, :class:`CollaborativeCore`) that knows nothing of
Gymnasium or PettingZoo; the vector shells in :mod:`dvrl_marl.envs` format its arrays for their API. A core is built
from a single-world environment (its *template*), so every parameter is validated and derived in one place, and
world ``i`` of a batch seeded ``s`` is the single environment reset with seed ``s + i`` (Gymnasium's convention
for vector environments), then reset without a seed after each episode.
"""

from dvrl_marl.core.arms import ArmBatch
from dvrl_marl.core.collaborative import CollaborativeCore
from dvrl_marl.core.pick import PickCore
from dvrl_marl.core.reach import ReachCore
from dvrl_marl.core.worlds import WorldRandom, check_action_batch

__all__ = ["ArmBatch", "ReachCore", "PickCore", "CollaborativeCore", "WorldRandom", "check_action_batch"]
