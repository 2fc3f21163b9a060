"""The environments: single-arm Gymnasium goal envs and the collaborative PettingZoo env."""

from dvrl_marl.envs import suction_debris_v0
from dvrl_marl.envs.psm_pick import PSMPickEnv
from dvrl_marl.envs.psm_reach import PSMReachEnv

__all__ = ["PSMReachEnv", "PSMPickEnv", "suction_debris_v0"]
