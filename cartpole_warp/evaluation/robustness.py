"""Robustness of a policy to the physics: play it over a grid of physical parameters (factors on the stage's values)
and count, per cell, the episodes that succeed; write the table (CSV) and a heatmap (PNG).

One batched env holds every cell: ``episodes`` envs per cell, each set (``set_physical_params``) to its cell's
parameters, all played once from the task's random starts. An episode succeeds when it reaches the time limit and,
where the task's solved rule is over full-length episodes (the swing-up), its reward per step meets that rule.
"""

from __future__ import annotations

import csv
import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from matplotlib.figure import Figure

from ..engine.env import BatchedEnv
from ..settings.config import ConfigError
from ..settings.files import atomic_write
from .rollouts import Policy, first_episodes
from .statistics import SolvedRule


@dataclass(frozen=True)
class Axis:
    """A physical parameter (a name of ``physical_params``) and the factors on its stage value to try; where the
    stage's value is 0 (damping, friction, action delay), the values themselves."""

    name: str
    factors: tuple[float, ...]

    def labels(self, relative: bool) -> list[str]:
        return [f"x{f:g}" if relative else f"{f:g}" for f in self.factors]


@dataclass
class GridResult:
    """Success rate per cell, indexed like ``itertools.product`` of the axes' factors."""

    axes: list[Axis]
    relative: list[bool]
    """Per axis: factors on the stage's value (else the values themselves)."""
    success: np.ndarray
    """Fraction of successful episodes, shape (len(factors) of each axis)."""
    episodes: int
    """Per cell."""


def stage_values(env: BatchedEnv, axes: list[Axis]) -> list[float]:
    """The stage's value of each axis' parameter; ConfigError for a name that cannot be set."""
    nominal, settable = env.physics.stage_values(), env.physics.settable()
    for axis in axes:
        if axis.name not in settable:
            raise ConfigError(f"robustness axis {axis.name!r} is not a settable physical parameter; those are: "
                              f"{', '.join(settable)}")
    return [nominal[axis.name][0].item() for axis in axes]


def cell_params(env: BatchedEnv, axes: list[Axis], episodes: int, stage: list[float]) -> dict[str, torch.Tensor]:
    """Each env's values of the axes' parameters: cell after cell (``itertools.product`` order), ``episodes`` envs
    each."""
    cells = list(itertools.product(*(axis.factors for axis in axes)))
    dtypes = {name: value.dtype for name, value in env.physical_params().items()}
    values = {}
    for i, (axis, base) in enumerate(zip(axes, stage, strict=True)):
        factors = torch.tensor([cell[i] for cell in cells], dtype=torch.float64).repeat_interleave(episodes)
        values[axis.name] = (factors * (base or 1.0)).to(device=env.device, dtype=dtypes[axis.name])
    return values


def evaluate_grid(env: BatchedEnv, policy: Policy, axes: list[Axis], episodes: int, rule: SolvedRule
                  ) -> GridResult:
    """Play ``policy`` once in every env of ``env`` (``num_envs`` = cells x ``episodes``, no randomization but an
    action history as long as the longest delay on an axis) with each cell's parameters, from a reset; the success
    rate per cell."""
    shape = tuple(len(axis.factors) for axis in axes)
    if env.num_envs != int(np.prod(shape)) * episodes:
        raise ConfigError(f"the grid needs {int(np.prod(shape)) * episodes} envs, the env has {env.num_envs}")
    stage = stage_values(env, axes)
    env.reset()
    try:
        env.set_physical_params(**cell_params(env, axes, episodes, stage))
    except ValueError as err:
        raise ConfigError(f"robustness grid: {err}") from None
    played = first_episodes(env, policy, env.max_episode_length, reset=False)
    success = rule.episode_success(played.returns, played.lengths, played.reached_limit)
    rates = success.to(torch.float64).reshape(-1, episodes).mean(dim=1)
    return GridResult(axes, [value != 0 for value in stage], rates.cpu().numpy().reshape(shape), episodes)


def write_table(path: Path, result: GridResult) -> Path:
    """CSV: one row per cell, the factor of each axis and the success rate."""
    def write(tmp: str):
        with open(tmp, "w", newline="") as f:
            out = csv.writer(f)
            out.writerow([axis.name + (" factor" if relative else "")
                          for axis, relative in zip(result.axes, result.relative)] + ["success_rate"])
            for index in np.ndindex(result.success.shape):
                factors = [f"{axis.factors[i]:g}" for axis, i in zip(result.axes, index)]
                out.writerow(factors + [f"{result.success[index]:.4f}"])
    return atomic_write(path, write)


def format_table(result: GridResult) -> str:
    """The first two axes as a text table of percentages (the worst over any further axis)."""
    rates = worst_over_rest(result.success)
    x, y = result.axes[0], result.axes[1]
    x_labels, y_labels = x.labels(result.relative[0]), y.labels(result.relative[1])
    lines = [f"success rate, {y.name} (rows) x {x.name} (columns)" + worst_over(result)]
    lines.append(f"{'':>8}" + "".join(f"{label:>8}" for label in x_labels))
    for j, label in enumerate(y_labels):
        lines.append(f"{label:>8}" + "".join(f"{rates[i, j]:>8.0%}" for i in range(len(x.factors))))
    return "\n".join(lines)


def worst_over(result: GridResult) -> str:
    """', worst over <third axis> <its values>' where there is one."""
    if len(result.axes) < 3:
        return ""
    return f", worst over {result.axes[2].name} {', '.join(result.axes[2].labels(result.relative[2]))}"


def worst_over_rest(success: np.ndarray) -> np.ndarray:
    """The first two axes' rates, each the minimum over the further axes."""
    return success.reshape(*success.shape[:2], -1).min(axis=2)


def plot_heatmap(path: Path, result: GridResult, title: str) -> Path:
    """PNG heatmap of the first two axes' success rates (the worst over any further axis), red 0% to green 100%,
    each cell labelled."""
    rates = worst_over_rest(result.success)
    x, y = result.axes[0], result.axes[1]
    figure = Figure(figsize=(1.0 + 0.9 * len(x.factors), 1.4 + 0.7 * len(y.factors)), layout="constrained")
    ax = figure.subplots()
    ax.imshow(rates.T, cmap="RdYlGn", vmin=0.0, vmax=1.0, origin="lower", aspect="auto")
    for i, j in np.ndindex(rates.shape):
        ax.text(i, j, f"{rates[i, j]:.0%}", ha="center", va="center", fontsize=9)
    ax.set_xticks(range(len(x.factors)), x.labels(result.relative[0]))
    ax.set_yticks(range(len(y.factors)), y.labels(result.relative[1]))
    ax.set_xlabel(x.name)
    ax.set_ylabel(y.name)
    ax.set_title(title + worst_over(result).replace(", ", ",\n", 1), fontsize=9)
    return atomic_write(path, lambda tmp: figure.savefig(tmp, format="png", dpi=110))
