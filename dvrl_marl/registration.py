"""Registration: the single-arm environments with Gymnasium, the collaborative one with PettingZoo."""

from __future__ import annotations

import gymnasium as gym

__all__ = ["register_envs", "SINGLE_ARM_ENV_IDS", "SEAT_ENV_IDS", "MULTI_AGENT_ENV_IDS"]

_PAPER_EPISODE_STEPS = 100  # paper Sec. IV-A (also tasks/*.toml max_episode_steps)

#: id -> (entry point, kwargs)
SINGLE_ARM_ENV_IDS = {
    "dvrl_marl/PSMReach-v0": ("dvrl_marl.envs.psm_reach:PSMReachEnv", {"reward_type": "sparse"}),
    "dvrl_marl/PSMReachDense-v0": ("dvrl_marl.envs.psm_reach:PSMReachEnv", {"reward_type": "dense"}),
    "dvrl_marl/PSMPick-v0": ("dvrl_marl.envs.psm_pick:PSMPickEnv", {"reward_type": "sparse"}),
    "dvrl_marl/PSMPickDense-v0": ("dvrl_marl.envs.psm_pick:PSMPickEnv", {"reward_type": "dense"}),
    # v1: p is the dVRK's measured_cp (wrist-yaw origin), as on the robot and in the original dVRL code.
    "dvrl_marl/PSMReach-v1": ("dvrl_marl.envs.psm_reach:PSMReachEnv", {"reward_type": "sparse", "tip_frame": "measured_cp"}),
    "dvrl_marl/PSMReachDense-v1": ("dvrl_marl.envs.psm_reach:PSMReachEnv", {"reward_type": "dense", "tip_frame": "measured_cp"}),
    # Pick v1 also lands its object without sinking into the table (scenes/pick_lnd_v1.xml).
    "dvrl_marl/PSMPick-v1": ("dvrl_marl.envs.psm_pick:PSMPickEnv",
                             {"reward_type": "sparse", "tip_frame": "measured_cp", "scenes": {"lnd": "pick_lnd_v1"}}),
    "dvrl_marl/PSMPickDense-v1": ("dvrl_marl.envs.psm_pick:PSMPickEnv",
                                  {"reward_type": "dense", "tip_frame": "measured_cp", "scenes": {"lnd": "pick_lnd_v1"}}),
}

#: entry point -> the native batched form (``gym.make_vec(..., vectorization_mode="vector_entry_point")``)
_VECTOR_ENTRY_POINTS = {
    "dvrl_marl.envs.psm_reach:PSMReachEnv": "dvrl_marl.envs.vector:make_reach_vector",
    "dvrl_marl.envs.psm_pick:PSMPickEnv": "dvrl_marl.envs.vector:make_pick_vector",
}


#: One seat of the collaborative scene as a Gymnasium env, the partner inside (datasets, behaviour cloning).
SEAT_ENV_IDS = {
    "dvrl_marl/SurgeonSeat-v1": ("dvrl_marl.envs.seat:SeatEnv", {"seat": "grasper", "version": "v1"}),
    "dvrl_marl/SurgeonSeat-v2": ("dvrl_marl.envs.seat:SeatEnv", {"seat": "grasper", "version": "v2"}),
}

#: PettingZoo ids -> (parallel entry point, AEC entry point)
MULTI_AGENT_ENV_IDS = {
    "dvrl_marl/suction_debris-v0": (
        "dvrl_marl.envs.suction_debris_v0:parallel_env",
        "dvrl_marl.envs.suction_debris_v0:env",
    ),
    "dvrl_marl/suction_debris-v1": (
        "dvrl_marl.envs.suction_debris_v1:parallel_env",
        "dvrl_marl.envs.suction_debris_v1:env",
    ),
    "dvrl_marl/suction_debris-v2": (
        "dvrl_marl.envs.suction_debris_v2:parallel_env",
        "dvrl_marl.envs.suction_debris_v2:env",
    ),
    "dvrl_marl/suction_debris-v3": (
        "dvrl_marl.envs.suction_debris_v3:parallel_env",
        "dvrl_marl.envs.suction_debris_v3:env",
    ),
    "dvrl_marl/suction_debris-v4": (
        "dvrl_marl.envs.suction_debris_v4:parallel_env",
        "dvrl_marl.envs.suction_debris_v4:env",
    ),
    "dvrl_marl/suction_debris-v5": (
        "dvrl_marl.envs.suction_debris_v5:parallel_env",
        "dvrl_marl.envs.suction_debris_v5:env",
    ),
    "dvrl_marl/suction_debris-v6": (
        "dvrl_marl.envs.suction_debris_v6:parallel_env",
        "dvrl_marl.envs.suction_debris_v6:env",
    ),
    "dvrl_marl/suction_debris-v7": (
        "dvrl_marl.envs.suction_debris_v7:parallel_env",
        "dvrl_marl.envs.suction_debris_v7:env",
    ),
}
#: The collaborative scene's task files, one per version (v0's is ``suction_debris``; ``tasks/<name>.toml``).
COLLABORATIVE_TASKS = tuple("suction_debris" if env_id.endswith("-v0") else "suction_debris_" + env_id.rsplit("-", 1)[1]
                            for env_id in MULTI_AGENT_ENV_IDS)


def register_envs() -> None:
    """Register every single-arm id with Gymnasium and, where PettingZoo has a registry, the collaborative one."""
    for env_id, (entry_point, kwargs) in SINGLE_ARM_ENV_IDS.items():
        if env_id in gym.registry:
            continue
        gym.register(id=env_id, entry_point=entry_point, kwargs=kwargs, max_episode_steps=_PAPER_EPISODE_STEPS,
                     vector_entry_point=_VECTOR_ENTRY_POINTS[entry_point])
    for env_id, (entry_point, kwargs) in SEAT_ENV_IDS.items():
        if env_id not in gym.registry:  # the scene truncates its own episodes (max_cycles)
            gym.register(id=env_id, entry_point=entry_point, kwargs=kwargs,
                         vector_entry_point="dvrl_marl.envs.seat_vector:make_seat_vector")
    try:
        import pettingzoo
    except ImportError:  # pragma: no cover - pettingzoo is a dependency, but registration must never break import
        return
    if not hasattr(pettingzoo, "register"):  # PettingZoo releases before its registry
        return
    for env_id, (parallel_entry, aec_entry) in MULTI_AGENT_ENV_IDS.items():
        if env_id not in pettingzoo.parallel_registry:
            pettingzoo.register("parallel", env_id, entry_point=parallel_entry)
        if env_id not in pettingzoo.aec_registry:
            pettingzoo.register("aec", env_id, entry_point=aec_entry)
