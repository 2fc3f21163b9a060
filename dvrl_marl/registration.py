"""Registration: the single-arm environments with Gymnasium, the collaborative one with PettingZoo."""

from __future__ import annotations

import gymnasium as gym

__all__ = ["register_envs", "SINGLE_ARM_ENV_IDS", "SEAT_ENV_IDS", "MULTI_AGENT_ENV_IDS"]

_PAPER_EPISODE_STEPS = 100  # paper Sec. IV-A (also tasks/*.toml max_episode_steps)

#: id -> (entry point, kwargs). The current version of each single-arm env: p is the dVRK's measured_cp (the
#: wrist-yaw origin), as on the robot and in the original dVRL code; Pick lands its object without sinking into the
#: table (scenes/pick_lnd_v1.xml). Earlier ids (-v0) were never released; Gymnasium names the current one for them.
SINGLE_ARM_ENV_IDS = {
    "dvrl_marl/PSMReach-v1": ("dvrl_marl.envs.psm_reach:PSMReachEnv", {"reward_type": "sparse", "tip_frame": "measured_cp"}),
    "dvrl_marl/PSMReachDense-v1": ("dvrl_marl.envs.psm_reach:PSMReachEnv", {"reward_type": "dense", "tip_frame": "measured_cp"}),
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


#: One seat of the collaborative scene as a Gymnasium env, the partner inside (datasets, behaviour cloning); its
#: version is the scene's.
SEAT_ENV_IDS = {
    "dvrl_marl/SurgeonSeat-v8": ("dvrl_marl.seats.seat_env:SeatEnv", {"seat": "grasper"}),
}

#: PettingZoo ids -> (parallel entry point, AEC entry point): the current version of the collaborative scene.
MULTI_AGENT_ENV_IDS = {
    "dvrl_marl/suction_debris-v8": (
        "dvrl_marl.envs.suction_debris_v8:parallel_env",
        "dvrl_marl.envs.suction_debris_v8:env",
    ),
}


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
                         vector_entry_point="dvrl_marl.seats.seat_vector:make_seat_vector")
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
