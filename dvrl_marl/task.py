"""Task definitions: each environment's scene, workspace and thresholds, read from ``tasks/*.toml``.

A task file holds the paper's parameters with their sources; environments take them as defaults and every
value can be overridden by keyword. Adding a task is adding a file.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from pathlib import Path

from dvrl_marl.assets import tasks_dir

__all__ = ["TaskSpec", "load_task", "load_task_table", "available_tasks", "DISTRIBUTIONS"]

#: Start and goal distributions: the paper's ("uniform" in the workspace) or the original dVRL code's.
DISTRIBUTIONS = ("uniform", "original")


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
    #: Where this library departs from the original dVRL code, the original behaviour on request (docs/deviations.md):
    dense_scale: float = 1.0  # dense reward -dense_scale * d (original: 100)
    workspace_margin: float = 0.0  # p is clipped to p_c +/- (rho + margin) (original: 0.01 m)
    start_distribution: str = "uniform"  # Reach p_0: "uniform" in the workspace (paper) or "original" (p_c)
    goal_distribution: str = "uniform"  # "uniform" in the workspace (paper) or "original" (the original's box)
    original_goal_floor: float | None = None  # "original" goals start this far above the table (original code)

    def with_overrides(self, **overrides) -> "TaskSpec":
        """A copy with some parameters replaced; ``None`` values are ignored."""
        known = {f.name for f in fields(self)}
        unknown = set(overrides) - known
        if unknown:
            # TypeError, as Python raises for an unexpected keyword (clients such as TorchRL's GymEnv probe with it).
            raise TypeError(f"{self.name}() got an unexpected keyword argument {sorted(unknown)[0]!r}")
        return replace(self, **{k: v for k, v in overrides.items() if v is not None})

    def validate(self, source: str | None = None) -> "TaskSpec":
        """Every parameter checked against the declared schema (:class:`dvrl_marl.schemas.SingleArmTask`: finite
        numbers in range, known distributions); returns a copy with the checked values."""
        from dvrl_marl.schemas import SingleArmTask, validated

        values = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "name"}
        values["workspace_centre"] = tuple(values["workspace_centre"]) if isinstance(
            values["workspace_centre"], (list, tuple)) else values["workspace_centre"]
        checked = validated(SingleArmTask, values, source or f"task {self.name!r}", table="task" if source else None)
        if checked.goal_distribution == "original" and checked.original_goal_floor is None:
            raise ValueError(f"task {self.name!r}: goal_distribution='original' needs original_goal_floor in the "
                             "task file")
        return replace(self, **{key: getattr(checked, key) for key in values})


def available_tasks() -> list[str]:
    """Names of the task files shipped (and any a user added to ``tasks/``)."""
    return sorted(p.stem for p in tasks_dir().glob("*.toml"))


def load_task_table(name: str | Path, _chain: tuple[str, ...] = ()) -> tuple[str, dict]:
    """The ``[task]`` table of a task file, by name (``"psm_reach"``) or path: (task name, table). A file may
    ``extends = "<task>"`` another, key by key overriding it; a chain that comes back to a file is an error naming the
    chain."""
    path = Path(name)
    if path.suffix != ".toml":
        path = tasks_dir() / f"{name}.toml"
    if not path.is_file():
        raise FileNotFoundError(f"no task file {path}; available tasks: {available_tasks()}")
    from dvrl_marl.files import field, read_toml

    table = dict(field(read_toml(path), "task", path, dict))
    if "extends" in table:
        # A new version of a task: the task it extends, key by key overridden by this file's.
        base = str(table.pop("extends"))
        chain = (*_chain, str(path.resolve()))
        base_path = Path(base) if Path(base).suffix == ".toml" else tasks_dir() / f"{base}.toml"
        if base == path.stem or str(base_path.resolve()) in chain:
            names = " -> ".join(Path(link).stem for link in chain)
            raise ValueError(f"{path}: extends = {base!r} comes back to a file of its own chain ({names} -> {base}); "
                             "a task cannot extend itself")
        table = {**load_task_table(base, chain)[1], **table}
    return path.stem, table


def load_task(name: str | Path) -> TaskSpec:
    """Read a single-arm task by name (``"psm_reach"``) or from a TOML file path."""
    task_name, table = load_task_table(name)
    from dvrl_marl.schemas import SingleArmTask, validated

    path = Path(name) if Path(name).suffix == ".toml" else tasks_dir() / f"{name}.toml"
    checked = validated(SingleArmTask, table, str(path), table="task")  # unknown keys (typos) included
    return TaskSpec(name=task_name, **checked.model_dump()).validate()
