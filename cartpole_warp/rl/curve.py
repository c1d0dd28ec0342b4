"""The learning curve of a run (matplotlib's object API: no display, no global backend)."""

from __future__ import annotations

import textwrap
from pathlib import Path

from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ..evaluation.statistics import METRIC_LABELS, SolvedRule
from ..settings.files import atomic_write
from ..tasks import Task

TRAINING_LINE_LEFT_OUT = {"time_limit_fraction": "training episodes not drawn: in training an episode ends early\n"
                                                 "by failing, so few reach the time limit until the policy is good"}
"""The panels without a line of the training episodes, and why: their figure is not comparable with the
evaluations'."""
NO_TRAINING_EPISODE = {"full_reward_per_step": "no training episode has run the whole time limit yet"}
"""Why a panel has no training line yet, where it is not that no training episode has ended."""


def curve_panels(task: Task) -> list[str]:
    """The ``EpisodeSummary`` means the curve draws, one panel each: the reward per step that the task's rule judges
    (of full-length episodes where it counts those), the fraction of episodes that reached the time limit where the
    rule or the play metric is that, and the task's play metric."""
    rule = task.solved
    panels = ["full_reward_per_step" if rule.full_episodes_only else "mean_reward_per_step"]
    if rule.min_time_limit_fraction or task.play_metric == "time_limit_fraction":
        panels.append("time_limit_fraction")
    return panels + [task.play_metric] * (task.play_metric not in panels)


def metric_text(key: str, value: float | None) -> str:
    """A metric's value as the curve and the console say it: a fraction of episodes in percent."""
    if value is None:
        return "none"
    return f"{value:.0%}" if key == "time_limit_fraction" else f"{value:.3f}"


def verdict(history: list[dict], rule: SolvedRule) -> tuple[bool, str]:
    """Whether the run in ``history`` was solved, and in words: at which iteration, or which of the rule's conditions
    its last evaluation missed (and which it met)."""
    solved = next((h for h in history if h.get("solved")), None)
    if solved is not None:
        return True, (f"SOLVED at iteration {solved['iteration'] + 1} ({solved['train_time_s']:.1f} s of training): "
                      "its evaluation met every dashed line")
    last = next((h for h in reversed(history) if "evaluation" in h), None)
    if last is None:
        return False, f"NOT SOLVED: no evaluation in {len(history)} iterations"
    evaluation = last["evaluation"]
    parts = [f"{METRIC_LABELS[key]} {metric_text(key, value)} "
             f"({'met: >=' if met else 'needs >='} {metric_text(key, minimum)})"
             for key, value, minimum, met in rule.conditions(evaluation)]
    policy = evaluation.get("policy_iteration", last["iteration"]) + 1
    return False, f"NOT SOLVED: the last evaluation (iteration {policy}): {'; '.join(parts)}"


def learning_curve_figure(history: list[dict], task: Task, title: str) -> Figure:
    """``curve_panels`` over the iterations run: the training episodes finished in each iteration as lines (where
    comparable with the evaluations: ``TRAINING_LINE_LEFT_OUT``), the deterministic evaluations as dots, the
    thresholds of the task's solved rule as dashed lines, the legends beside the panels; iterations counted from 1.
    ``title`` names the run; the verdict (``verdict``) and the rule stand under it."""
    panels = curve_panels(task)
    thresholds = {"time_limit_fraction": task.solved.min_time_limit_fraction or None,
                  panels[0]: task.solved.min_reward_per_step}
    solved, words = verdict(history, task.solved)
    figure = Figure(figsize=(8, 6), layout="constrained")
    figure.suptitle(f"{title}\n{textwrap.fill(words, 80, break_on_hyphens=False)}",
                    color="darkgreen" if solved else "darkred")
    axes_list = figure.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    axes_list[0].set_title(textwrap.fill(f"solved = one evaluation meets every dashed line: {task.solved.describe()}",
                                         90), fontsize="small")
    for axes, key in zip(axes_list, panels):
        trained = [h for h in history if h.get(key) is not None]
        if key in TRAINING_LINE_LEFT_OUT:
            axes.text(0.02, 0.5, TRAINING_LINE_LEFT_OUT[key], transform=axes.transAxes, fontsize="small",
                      color="dimgray", va="center")
        elif trained:
            axes.plot([h["iteration"] + 1 for h in trained], [h[key] for h in trained], color="tab:blue",
                      label="training episodes")
        else:
            axes.text(0.02, 0.5, NO_TRAINING_EPISODE.get(key, "no training episode has ended yet"),
                      transform=axes.transAxes, fontsize="small", color="dimgray", va="center")
        evaluated = [h for h in history if (h.get("evaluation") or {}).get(key) is not None]
        if evaluated:
            axes.plot([h["evaluation"].get("policy_iteration", h["iteration"]) + 1 for h in evaluated],
                      [h["evaluation"][key] for h in evaluated], "o-", linewidth=0.8,
                      color="tab:green", label="evaluation\n(deterministic policy)")
        if thresholds.get(key) is not None:
            axes.axhline(thresholds[key], color="tab:red", linestyle="--", label=f"solved: >= {thresholds[key]:g}")
        axes.grid(alpha=0.3)
        label = METRIC_LABELS[key] + (" (play metric)" if key == task.play_metric else "")
        axes.set_ylabel(textwrap.fill(label, 24))
        if axes.get_legend_handles_labels()[0]:
            axes.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
    axes_list[-1].set_xlabel("iteration")
    axes_list[-1].set_xlim(0.5, (history[-1]["iteration"] + 1 if history else 1) + 0.5)
    axes_list[-1].xaxis.set_major_locator(MaxNLocator(integer=True))
    return figure


def plot_learning_curve(path: Path, history: list[dict], task: Task, title: str) -> Path:
    """``learning_curve_figure`` as a PNG at ``path``."""
    figure = learning_curve_figure(history, task, title)
    return atomic_write(path, lambda tmp: figure.savefig(tmp, format="png", dpi=100))
