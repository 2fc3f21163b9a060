"""Pipelines: single-arm policies (Reach, Pick), scripted steps or teleop composed into the collaborative task.

As on the real robot in the paper (Sec. IV-D), an arm's work is an ordered list of stages. Each stage runs a
single-arm policy in a frame re-centred on its sub-goal (states relative to a centre p_c let a policy trained at
one place run anywhere, paper Sec. III-A), until its done condition holds, then hands over to the next stage.
Pipelines are data (``pipelines/*.toml`` inside the package, or a user's file); see :func:`load_pipeline`.

>>> from dvrl_marl.envs import suction_debris_v8
>>> from dvrl_marl.pipeline import ArmPipeline
>>> env = suction_debris_v8.parallel_env(surgeon=...)                     # doctest: +SKIP
>>> surgeon = ArmPipeline.from_file("learned_team", "grasper", env)       # fills the surgeon seat
>>> env = suction_debris_v8.parallel_env(surgeon=surgeon)                 # doctest: +SKIP
"""

from dvrl_marl.pipeline.core import (
    ArmPipeline,
    RecentredFrame,
    StageSpec,
    available_pipelines,
    load_pipeline,
    pipeline_policies,
)

__all__ = ["ArmPipeline", "RecentredFrame", "StageSpec", "load_pipeline", "available_pipelines", "pipeline_policies"]
