"""Training: DDPG + HER + behaviour cloning, configuration runs, demonstrations, export. Imports torch and SB3.

Nothing else in :mod:`dvrl_marl` imports this package; install it with ``pip install "dvrl-marl[train]"``.
"""

from dvrl_marl.training.bc import DDPGBC, bc_loss, q_filter_mask
from dvrl_marl.training.export import export_policy
from dvrl_marl.training.runner import RunConfig, evaluate_policy, load_config, train

__all__ = ["DDPGBC", "bc_loss", "q_filter_mask", "export_policy", "RunConfig", "evaluate_policy", "load_config", "train"]
