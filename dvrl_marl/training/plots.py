"""Learning curves in the style of the paper's Fig. 4: success rate against environment steps, mean and spread
over seeds, one line per configuration."""

from __future__ import annotations

import csv
from collections import defaultdict
from pathlib import Path

import numpy as np

__all__ = ["read_progress", "aggregate", "plot_learning_curves", "plot_team_curves", "summary_table"]


def read_progress(run_dir, required: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """A run folder's ``progress.csv``, or such a file itself (``results/marl/<label>-progress.csv``); a file without
    one of the ``required`` columns, or with a value that is not a number, is an error naming the file."""
    path = Path(run_dir)
    path = path if path.suffix == ".csv" else path / "progress.csv"
    if not path.is_file():
        raise FileNotFoundError(f"{run_dir}: no progress.csv there (give a run folder or its progress.csv)")
    with path.open() as handle:
        reader = csv.DictReader(handle)
        rows = list(reader)
        missing = [column for column in required if column not in (reader.fieldnames or [])]
    if missing:
        raise ValueError(f"{path}: no column {', '.join(missing)} (its columns: {', '.join(reader.fieldnames or [])}); "
                         "give a run folder's progress.csv")
    try:
        return {key: np.array([float(r[key]) if r[key] != "" else np.nan for r in rows]) for key in rows[0]} if rows else {}
    except (TypeError, ValueError) as error:
        raise ValueError(f"{path}: a value is not a number ({error})") from None


def _label(run_dir: Path) -> str:
    """Runs named ``<config>-seed<N>`` group by config."""
    name = run_dir.name.removesuffix("-progress.csv")
    return name.rsplit("-seed", 1)[0] if "-seed" in name else name


def aggregate(run_dirs) -> dict[str, dict[str, np.ndarray]]:
    """Per configuration: timesteps, mean and std of success over seeds (on the common evaluation steps)."""
    groups: dict[str, list] = defaultdict(list)
    for run in map(Path, run_dirs):
        progress = read_progress(run, required=("timesteps", "success_rate"))
        if progress:
            groups[_label(run)].append(progress)
    result = {}
    for label, runs in sorted(groups.items()):
        length = min(len(r["timesteps"]) for r in runs)
        success = np.stack([r["success_rate"][:length] for r in runs])
        result[label] = {"timesteps": runs[0]["timesteps"][:length], "mean": success.mean(0), "std": success.std(0),
                         "seeds": np.array(len(runs))}
    return result


def plot_learning_curves(run_dirs, out) -> tuple[Path, Path]:
    """Write ``<out>.png`` (the figure) and ``<out>.csv`` (the numbers behind it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    curves = aggregate(run_dirs)
    # One panel per task (Reach runs are 10x shorter than Pick runs), like the paper's Fig. 4.
    tasks = sorted({label.split("_")[0] for label in curves}) or ["runs"]
    figure, axes = plt.subplots(1, len(tasks), figsize=(6.5 * len(tasks), 4.2), squeeze=False)
    rows = []
    line_styles = ("-", "--", "-.", ":")  # curves that coincide (the same run on two tools) stay visible
    for axis, task in zip(axes[0], tasks):
        task_curves = [(label, curve) for label, curve in curves.items() if label.split("_")[0] == task]
        for index, (label, curve) in enumerate(task_curves):
            steps, mean, std = curve["timesteps"], curve["mean"], curve["std"]
            axis.plot(steps, mean, line_styles[index % len(line_styles)], linewidth=1.8,
                      label=f"{label} ({int(curve['seeds'])} seeds)")
            axis.fill_between(steps, np.clip(mean - std, 0, 1), np.clip(mean + std, 0, 1), alpha=0.2)
            rows += [(label, int(s), float(m), float(d), int(curve["seeds"])) for s, m, d in zip(steps, mean, std)]
        axis.set_xlabel("environment steps")
        axis.set_ylabel("success rate (50 evaluation episodes)")
        axis.set_ylim(-0.02, 1.02)
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8, loc="lower right")
        axis.set_title(f"dvrl-marl: PSM {task.capitalize()} (mean and std over seeds)")
    return _save(figure, out, ["config", "timesteps", "success_mean", "success_std", "seeds"], rows, dpi=120)


def _save(figure, out: Path, header: list, rows: list, dpi: int, layout_rect=(0, 0, 1, 1)) -> tuple[Path, Path]:
    """Write the figure as ``<out>.png`` and the numbers behind it as ``<out>.csv`` (the axes laid out inside
    ``layout_rect``, figure fractions: room for a legend below them)."""
    import matplotlib.pyplot as plt

    figure.tight_layout(rect=layout_rect)
    png = out.with_suffix(".png")
    figure.savefig(png, dpi=dpi)
    plt.close(figure)
    csv_path = out.with_suffix(".csv")
    with csv_path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        writer.writerows(rows)
    return png, csv_path


def summary_table(run_dirs, out) -> Path:
    """``<out>.csv``: per configuration, seeds, final and best mean success, first step the mean reached 0.9/0.95."""
    out = Path(out).with_suffix(".csv")
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["config", "seeds", "steps", "final_success_mean", "final_success_std", "best_success_mean",
                         "first_step_mean_ge_0.90", "first_step_mean_ge_0.95"])
        for label, curve in aggregate(run_dirs).items():
            steps, mean, std = curve["timesteps"], curve["mean"], curve["std"]

            def first(threshold):
                hits = np.flatnonzero(mean >= threshold)
                return int(steps[hits[0]]) if len(hits) else ""

            writer.writerow([label, int(curve["seeds"]), int(steps[-1]), f"{mean[-1]:.3f}", f"{std[-1]:.3f}",
                             f"{mean.max():.3f}", first(0.9), first(0.95)])
    return out


def plot_team_curves(run_dirs, out) -> tuple[Path, Path]:
    """The collaborative runs of :mod:`dvrl_marl.training.mappo`: success and blood removed against environment
    steps (validation episodes), one line per configuration, mean and spread over seeds. Writes ``<out>.png`` and
    ``<out>.csv``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    groups: dict[str, list] = defaultdict(list)
    for run in map(Path, run_dirs):
        progress = read_progress(run, required=("steps", "success_rate", "blood_removed_ml"))
        if progress:
            groups[_label(run)].append(progress)
    # Many configurations: distinct colours (tab20) and line styles, the legend below both panels, not over them.
    columns, legend_rows = 3, -(-len(groups) // 3)
    legend_inches = 0.18 * legend_rows + 0.55  # the legend's rows and the axis labels above them
    figure, axes = plt.subplots(1, 2, figsize=(13, 4.0 + legend_inches))
    colours = plt.get_cmap("tab20").colors
    rows = []
    for index, (label, runs) in enumerate(sorted(groups.items())):
        length = min(len(r["steps"]) for r in runs)
        steps = runs[0]["steps"][:length]
        style = {"color": colours[index % len(colours)], "linestyle": ("-", "--", ":")[index // len(colours) % 3]}
        for axis, key, title in ((axes[0], "success_rate", "success rate"),
                                 (axes[1], "blood_removed_ml", "blood removed (ml of 16)")):
            values = np.stack([r[key][:length] for r in runs])
            mean, std = values.mean(0), values.std(0)
            axis.plot(steps / 1e6, mean, label=f"{label} ({len(runs)} seed{'s' if len(runs) > 1 else ''})",
                      linewidth=1.4, marker="." if length < 3 else None, **style)
            if len(runs) > 1:
                axis.fill_between(steps / 1e6, mean - std, mean + std, alpha=0.12, color=style["color"])
            axis.set_xlabel("environment steps (millions, parallel)")
            axis.set_ylabel(title)
            axis.grid(alpha=0.3)
            for step, m, s in zip(steps, mean, std):
                rows.append((label, key, int(step), float(m), float(s), len(runs)))
    axes[0].set_ylim(-0.02, 1.02)
    handles, labels = axes[0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="lower center", ncol=columns, fontsize=8, frameon=False)
    figure.suptitle("The collaborative scene: multi-agent PPO (validation episodes)")
    return _save(figure, out, ["configuration", "metric", "steps", "mean", "std", "seeds"], rows, dpi=110,
                 layout_rect=(0, (legend_inches - 0.3) / (4.0 + legend_inches), 1, 1))
