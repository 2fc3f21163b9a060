"""Task definitions: each environment's scene, workspace and thresholds, read from ``tasks/*.toml``.

A task file holds the paper's parameters with their sources; environments take them as defaults and every
value can be overridden by keyword. Adding a task is adding a file.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from pathlib import Path

from dvrl_marl.assets import tasks_dir

__all__ = ["TaskSpec", "load_task", "load_task_table", "available_tasks"]


@dataclass(frozen=True)
class TaskSpec:
    """A single-arm task's parameters (positions in metres, PSM base frame)."""

    name: str
    description: str
    scenes: dict[str, str]
    workspace_centre: tuple[float, float, float]
    workspace_range: float
    step_size: float
    distance_threshold: float
    max_episode_steps: int
    control_dt: float
    tip_clearance: float
    grasp_threshold: float | None = None
    initial_jaw: float | None = None
    extra: dict = field(default_factory=dict)

    def with_overrides(self, **overrides) -> "TaskSpec":
        """A copy with some parameters replaced; ``None`` values are ignored."""
        known = {f.name for f in fields(self)}
        unknown = set(overrides) - known
        if unknown:
            # TypeError, as Python raises for an unexpected keyword (clients such as TorchRL's GymEnv probe with it).
            raise TypeError(f"{self.name}() got an unexpected keyword argument {sorted(unknown)[0]!r}")
        return replace(self, **{k: v for k, v in overrides.items() if v is not None})

    def validate(self) -> "TaskSpec":
        positive = ("workspace_range", "step_size", "distance_threshold", "control_dt", "max_episode_steps")
        for key in positive:
            value = getattr(self, key)
            if not value > 0:
                raise ValueError(f"task {self.name!r}: {key} must be positive, got {value!r}")
        if self.tip_clearance < 0:
            raise ValueError(f"task {self.name!r}: tip_clearance must be >= 0, got {self.tip_clearance!r}")
        if self.grasp_threshold is not None and not 0.0 < self.grasp_threshold <= 1.0:
            raise ValueError(f"task {self.name!r}: grasp_threshold must be in (0, 1], got {self.grasp_threshold!r}")
        if len(self.workspace_centre) != 3:
            raise ValueError(f"task {self.name!r}: workspace_centre needs 3 values, got {self.workspace_centre!r}")
        return self


def available_tasks() -> list[str]:
    """Names of the task files shipped (and any a user added to ``tasks/``)."""
    return sorted(p.stem for p in tasks_dir().glob("*.toml"))


def load_task_table(name: str | Path) -> tuple[str, dict]:
    """The ``[task]`` table of a task file, by name (``"psm_reach"``) or path: (task name, table)."""
    path = Path(name)
    if path.suffix != ".toml":
        path = tasks_dir() / f"{name}.toml"
    if not path.is_file():
        raise FileNotFoundError(f"no task file {path}; available tasks: {available_tasks()}")
    from dvrl_marl.files import field, read_toml

    return path.stem, field(read_toml(path), "task", path, dict)


def load_task(name: str | Path) -> TaskSpec:
    """Read a single-arm task by name (``"psm_reach"``) or from a TOML file path."""
    task_name, table = load_task_table(name)
    known = {f.name for f in fields(TaskSpec)} - {"name", "extra"}
    values = {k: v for k, v in table.items() if k in known}
    values["workspace_centre"] = tuple(float(v) for v in values["workspace_centre"])
    extra = {k: v for k, v in table.items() if k not in known}
    return TaskSpec(name=task_name, extra=extra, **values).validate()
