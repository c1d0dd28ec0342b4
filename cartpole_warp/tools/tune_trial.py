"""The Ray side of ``tools.tune``: a Ray Tune trial that is a population, and the search's console lines.

``PopulationTrial`` trains the trial's members as one population (``rl.training.Training`` with members: one batched
env, one batched PPO, on the device Ray gives the trial) in a thread of the trial's actor. After each iteration in
which a member was evaluated, the thread hands Ray a result (each member's latest evaluation, the best of them as the
trial's metric) and waits until Ray asks for the next: a scheduler's stop is then a stop request, after which the
members' folders are written as any run's (status ``STOPPED``) before the actor goes.
"""

from __future__ import annotations

import queue
import threading
from pathlib import Path

from ray import tune

from ..rl.learners.batched_ppo.learner import Member
from ..rl.training import Training
from ..train import resolve_args

STOPPED = "stopped by the scheduler"
"""The status of a member whose trial the scheduler stopped."""


def trial_flags(settings: dict) -> list[str]:
    """train.py flags of a trial's settings ({flag name without dashes: value}; a value with spaces is a list)."""
    return [arg for name, value in settings.items() for arg in (f"--{name}", *str(value).split())]


def trial_members(config: dict, seeds: list[int]) -> list[Member]:
    """The members of a trial's ``config``: member k has seed ``seeds[k]`` and its draws ``config["member<k>"]``."""
    return [Member(seed, tuple(sorted(config.get(f"member{k}", {}).items()))) for k, seed in enumerate(seeds)]


class PopulationTrial(tune.Trainable):
    """One trial of a search: ``plan`` holds train.py's flags for every trial, the members' seeds, the metric (a field
    of an evaluation, ``EpisodeSummary``'s) and the search's folder, in which this trial's is ``trial_<id>``."""

    def setup(self, config: dict, plan: dict):
        self.plan, self.metric = plan, plan["metric"]
        self.results: queue.Queue = queue.Queue()
        self.resume = threading.Semaphore(0)
        self.training: Training | None = None
        self.latest: dict[str, float] = {}
        self.handed = self.stopping = False
        self.thread = threading.Thread(target=self._train, args=(config,), daemon=True)
        self.thread.start()

    def _train(self, config: dict):
        try:
            cfg, _, _, _ = resolve_args(self.plan["flags"] + trial_flags(config.get("trial", {})))
            folder = Path(self.plan["folder"]) / f"trial_{self.trial_id}"
            self.training = Training(cfg, folder, members=trial_members(config, self.plan["seeds"]))
            self.training.loop.on_iteration = self._after_iteration
            if self.stopping:  # stopped while it was being built
                self.training.loop.request_stop(STOPPED)
            population = self.training.run()
            self.results.put(("end", population))
        except BaseException as err:  # noqa: BLE001 - raised again in Ray's thread by step(): the trial fails
            self.results.put(("error", err))

    def _after_iteration(self, it: int, _summary):
        loop = self.training.loop
        judged = False
        for member, record in zip(loop.members, loop.records):
            entry = record.progress.history[-1] if record.progress.history else {}
            value = entry.get("evaluation", {}).get(self.metric) if entry.get("iteration") == it else None
            if value is not None:
                self.latest[member.name], judged = value, True
        if judged and not self.stopping:
            self.results.put(("result", self._result(it + 1)))
            self.resume.acquire()

    def _result(self, iteration: int) -> dict:
        values = list(self.latest.values())
        solved = sum(record.progress.solved_at is not None for record in self.training.loop.records)
        return {"iteration": iteration, "members": dict(self.latest), "solved": solved,
                **({self.metric: max(values)} if values else {})}

    def step(self) -> dict:
        if self.handed:
            self.resume.release()
        kind, value = self.results.get()
        self.handed = kind == "result"
        if kind == "error":
            raise value
        if kind == "end":
            iterations = max(record.progress.iterations for record in self.training.loop.records)
            return self._result(iterations) | {"finished": True, "done": True}
        return value

    def cleanup(self):
        """A trial the scheduler stops: its members stop after the iteration in progress, their folders written."""
        if self.thread.is_alive():
            self.stopping = True
            if self.training is not None:
                self.training.loop.request_stop(STOPPED)
            self.resume.release()
            self.thread.join()


class SearchLines(tune.Callback):
    """A line per trial result (the iteration, the trial's metric, its solved members), end and failure; a trial that
    ends before ``max_iterations`` and before every member's verdict was stopped by the scheduler."""

    def __init__(self, metric: str, max_iterations: int):
        self.metric, self.max_iterations = metric, max_iterations

    def on_trial_result(self, iteration, trials, trial, result, **info):
        value = result.get(self.metric)
        shown = f"{value:.3f}" if value is not None else "-"
        print(f"trial {trial.trial_id} it {result['iteration']}: {self.metric} {shown} (best member), "
              f"{result['solved']} solved", flush=True)

    def on_trial_complete(self, iteration, trials, trial, **info):
        result = trial.last_result or {}
        ran = result.get("iteration", 0)
        how = "completed" if result.get("finished") or ran >= self.max_iterations else "stopped early by the scheduler"
        print(f"trial {trial.trial_id} {how} at iteration {ran}", flush=True)

    def on_trial_error(self, iteration, trials, trial, **info):
        print(f"trial {trial.trial_id} failed (the search goes on)", flush=True)
