"""A population's modes: what it does besides training each member to its own verdict, after each iteration of the
training loop (``rl.loop.TrainingLoop``'s ``modes``, in order).

    python train.py --task cart-two-pole-swingup --seeds 0 1 2 3 4 --population.until first-solved
    python train.py --task cart-two-pole-swingup --seeds 0 1 2 3 4 --population.exploit-interval 100

Each is a ``loop.PopulationMode``. ``UntilFirstSolved`` ends the population in the iteration its first member is
judged solved. ``Exploitation`` is population-based training (Jaderberg et al. 2017, "Population Based Training of
Neural Networks"): every ``interval`` iterations the members still training are ranked, and each of the bottom ones
takes the whole state of one of the top ones (exploit: networks, Adam state, normalisers, settings; a tensor copy,
the members being a batch dimension of one learner) and perturbs its settings (explore). Both train in one process
(not under torchrun).
"""

from __future__ import annotations

import dataclasses
import json
import random
import statistics
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..settings.config import ConfigError, require
from ..settings.files import write_text
from .learners.batched_ppo.learner import VARIABLE_SETTINGS
from .population import setting_name
from .runs import LINEAGE_FILE, save_config

if TYPE_CHECKING:
    from .loop import PopulationMode, TrainingLoop

DISCOUNTS = ("gamma", "lam")
"""Settings in [0, 1] near 1, perturbed in their horizon: 1 - x scaled, not x."""


class UntilFirstSolved:
    """Every member's run ends in the iteration the first is judged solved: 'solved' where it was too, else
    'outdone'. ``first_solved`` names that member (of several: the best by the play metric)."""

    def __init__(self):
        self.first_solved: int | None = None

    def describe(self) -> str:
        return "until its first solved member (the others then stop, 'outdone'; the population's policy is its)"

    def after_iteration(self, loop: TrainingLoop, it: int, running: list[int]) -> list[int]:
        metric = loop.config.task_spec.play_metric
        solved = [k for k in running if loop.records[k].progress.solved_at is not None]
        if not solved:
            return running
        self.first_solved = max(solved, key=lambda k: (loop.records[k].progress.best[metric] or 0.0, -k))
        for k in running:
            loop.records[k].stop_reason = "solved" if k in solved else "outdone"
        return []

    def annotate(self, loop: TrainingLoop, rows: list[dict]) -> dict:
        return {"first_solved": None if self.first_solved is None else loop.members[self.first_solved].name}


def perturbed(name: str, value: float, factor: float) -> float:
    """``value`` of setting ``name`` scaled by ``factor``; a discount's (``DISCOUNTS``) horizon 1 - value scaled,
    kept in (0, 1]."""
    if name in DISCOUNTS:
        return min(max(1.0 - (1.0 - value) * factor, 1e-3), 1.0)
    return value * factor


def default_perturbed(schedule: str) -> tuple[str, ...]:
    """The settings PBT perturbs by default: all a population's members may differ in (``VARIABLE_SETTINGS``) but the
    learning rate under the 'adaptive' schedule (it follows desired_kl) and desired_kl under 'fixed' (unused)."""
    unused = "learning_rate" if schedule == "adaptive" else "desired_kl"
    return tuple(name for name in VARIABLE_SETTINGS if name != unused)


@dataclasses.dataclass
class Exploitation:
    """Population-based training, every ``interval`` iterations of the members still training (iterations counted
    from the first: the ``interval``-th, the 2 ``interval``-th, ...). Ranking: by the play metric of each member's
    latest evaluation where every one was judged within the last ``interval`` iterations, else by its training
    episodes' mean return over them. Each of the bottom ``fraction`` (at least one, at most half) takes the state of
    one of the top ``fraction``, drawn at random, where that one ranks strictly higher (``Learner.exploit``), then
    scales each of its ``perturb`` settings by ``factor`` or 1 / ``factor``, at random (``perturbed``; a setting at 0
    stays 0). Draws from ``seed``. Each exploit is a line on the console and an entry of the member's lineage: its
    run folder's ``lineage.json`` (iteration, whose state it took, the two scores, its settings after) and the
    population's ``members.md``; its checkpoint of that iteration then holds the state it took and its
    ``config.yaml`` the settings it trains with since, so that its folder resumes with both (a folder named for a
    ``--population.vary`` value keeps its name)."""

    interval: int
    fraction: float = 0.25
    factor: float = 1.2
    perturb: Sequence[str] = ()
    seed: int = 0

    def __post_init__(self):
        require(self.interval >= 1, f"--population.exploit-interval {self.interval}: members exploit every N >= 1 "
                                    "iterations (leave it out for none)")
        require(0 < self.fraction <= 0.5, f"--population.exploit-fraction {self.fraction}: the share of members "
                                          "that take others' state, in (0, 0.5]")
        require(self.factor > 1, f"--population.perturb-factor {self.factor}: settings are scaled by it or its "
                                 "inverse, so it must be > 1")
        unknown = [name for name in self.perturb if setting_name(name) not in VARIABLE_SETTINGS]
        require(not unknown, f"--population.perturb {' '.join(unknown)}: PBT perturbs only settings members may "
                             f"differ in, {', '.join(VARIABLE_SETTINGS)}")
        self.perturb = tuple(setting_name(name) for name in self.perturb)
        self._random = random.Random(self.seed)
        self.events: list[dict] = []
        """Every exploit, in order."""

    def describe(self) -> str:
        perturb = ", ".join(self.perturb) if self.perturb else "the default settings"
        return (f"population-based training every {self.interval} iterations: the bottom {self.fraction:.0%} take a "
                f"top one's state, then scale {perturb} by {self.factor:g} or 1/{self.factor:g}")

    def after_iteration(self, loop: TrainingLoop, it: int, running: list[int]) -> list[int]:
        training = [k for k in running if loop.records[k].stop_reason is None]
        if (it + 1) % self.interval or len(training) < 2:
            return running
        scores = self.scores(loop, training)
        ranked = sorted(training, key=lambda k: (scores[k], -k), reverse=True)
        count = min(max(1, round(self.fraction * len(ranked))), len(ranked) // 2)
        perturb = self.perturb or default_perturbed(loop.config.agent.algorithm.schedule)
        for target in reversed(ranked[-count:]):
            source = self._random.choice(ranked[:count])
            if scores[source] <= scores[target]:
                continue
            loop.learner.exploit(source, target)
            settings = loop.learner.member_settings(target)
            settings |= {name: perturbed(name, settings[name], self._random.choice((self.factor, 1 / self.factor)))
                         for name in perturb}
            loop.learner.set_member_settings(target, settings)
            self._record(loop, it, source, target, (scores[source], scores[target]), settings)
        return running

    def scores(self, loop: TrainingLoop, members: list[int]) -> dict[int, float]:
        """Each member's ranking score (the class's rule) over the last ``interval`` iterations."""
        metric = loop.config.task_spec.play_metric
        recent = {k: loop.records[k].progress.history[-self.interval:] for k in members}
        judged = {k: [h["evaluation"][metric] for h in history if h.get("evaluation", {}).get(metric) is not None]
                  for k, history in recent.items()}
        if all(judged.values()):
            return {k: values[-1] for k, values in judged.items()}
        returns = {k: [h["mean_return"] for h in history if h["mean_return"] is not None]
                   for k, history in recent.items()}
        return {k: statistics.fmean(values) if values else float("-inf") for k, values in returns.items()}

    def _record(self, loop: TrainingLoop, it: int, source: int, target: int, scores: tuple[float, float],
                settings: dict[str, float]):
        """An exploit's entry in the lineage, its line, and the target's ``config.yaml`` and ``lineage.json``."""
        names = [member.name for member in loop.members]
        event = {"iteration": it + 1, "member": names[target], "took": names[source],
                 "scores": {"took": round(scores[0], 6), "own": round(scores[1], 6)},
                 "settings": {name: round(value, 8) for name, value in settings.items()}}
        self.events.append(event)
        print(f"{loop.prefix}  pbt, iteration {it + 1}: {names[target]} ({scores[1]:.4g}) takes {names[source]}'s "
              f"state ({scores[0]:.4g}); " + ", ".join(f"{name} {value:.4g}" for name, value in settings.items()),
              flush=True)
        record = loop.records[target]
        record.config = dataclasses.replace(record.config, agent=dataclasses.replace(
            record.config.agent, algorithm=dataclasses.replace(record.config.agent.algorithm, **settings)))
        if record.run_dir is not None:  # its checkpoint of the state it took, then the settings it goes on with
            record.save(record.run_dir / f"model_{it}.pt")
            save_config(record.run_dir, record.config)
            lineage = [entry for entry in self.events if entry["member"] == names[target]]
            write_text(record.run_dir / LINEAGE_FILE, json.dumps(lineage, indent=2) + "\n")

    def annotate(self, loop: TrainingLoop, rows: list[dict]) -> dict:
        for row in rows:
            row["lineage"] = [(event["iteration"], event["took"]) for event in self.events
                              if event["member"] == row["member"]]
        return {"exploitation": {"interval": self.interval, "fraction": self.fraction, "factor": self.factor,
                                 "perturb": list(self.perturb or default_perturbed(
                                     loop.config.agent.algorithm.schedule)), "exploits": len(self.events)}}


def check_modes(modes: Sequence[PopulationMode], members: int, distributed: bool):
    """ConfigError in one line where a population of ``members`` cannot run its ``modes``."""
    if not modes:
        return
    names = ", ".join("--population.until first-solved" if isinstance(mode, UntilFirstSolved)
                      else "--population.exploit-interval" for mode in modes)
    if members < 2:
        raise ConfigError(f"{names} compares a population's members: give two or more (--seeds 0 1 ...)")
    if distributed:
        raise ConfigError(f"{names} compares every member each iteration, in one process: run it without torchrun")
