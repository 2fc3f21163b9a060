"""Training: DDPG + HER + behaviour cloning and configuration runs (SB3), multi-agent PPO (TorchRL), team
evaluation, demonstrations, export.

The trainers need ``pip install "dvrl-marl[train]"`` (torch, SB3, TorchRL); the names below load lazily, so the
numpy-only parts (:mod:`dvrl_marl.training.teams`, :mod:`dvrl_marl.training.plots`) work without them.
"""

from __future__ import annotations

import importlib

_LAZY = {
    "DDPGBC": "dvrl_marl.training.bc", "bc_loss": "dvrl_marl.training.bc", "q_filter_mask": "dvrl_marl.training.bc",
    "export_policy": "dvrl_marl.training.export", "RunConfig": "dvrl_marl.training.runner",
    "evaluate_policy": "dvrl_marl.training.runner", "load_config": "dvrl_marl.training.runner",
    "train": "dvrl_marl.training.runner",
}

__all__ = sorted(_LAZY)

TRAIN_EXTRA_HINT = 'pip install "dvrl-marl[train]"'


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'dvrl_marl.training' has no attribute {name!r}")
