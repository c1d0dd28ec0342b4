"""The Ray side of ``tools.tune``: a Ray Tune trial that is a population, the scheduler that stops it, and the
search's console lines.

``PopulationTrial`` trains the trial's members as one population (``rl.training.Training`` with members: one batched
env, one batched PPO, on the device Ray gives the trial) in a thread of the trial's actor. After each iteration in
which a member was evaluated, the thread hands Ray a result (each member's latest evaluation, the best of them as the
trial's metric) and waits until Ray asks for the next. ASHA's stop reaches the trial as a request (``GracefulASHA``,
``StopBoard``): its members stop after the iteration in progress, their folders written as any run's (status
``STOPPED``), and the trial then ends itself. (Ray's own stop ends the trial's actor, and at a search's end it gives a
stopping actor 10 s, fewer than a population's exports can take.)
"""

from __future__ import annotations

import queue
import threading
from pathlib import Path

import ray
from ray import tune
from ray.tune.schedulers import ASHAScheduler

from ..rl.learners.batched_ppo.learner import Member
from ..rl.training import Training
from ..train import resolve_args

STOPPED = "stopped by the scheduler"
"""The status of a member whose trial the scheduler stopped."""


def trial_flags(settings: dict) -> list[str]:
    """train.py flags of a trial's settings ({flag name without dashes: value}; a value with spaces is a list)."""
    return [arg for name, value in settings.items() for arg in (f"--{name}", *str(value).split())]


def completed(last_result: dict) -> bool:
    """Whether a trial whose last result is ``last_result`` ran to its own end (its iterations, or every member's
    verdict), rather than being stopped by the scheduler or by Ray."""
    return bool(last_result.get("finished")) and not last_result.get("stopped")


def trial_members(config: dict, seeds: list[int]) -> list[Member]:
    """The members of a trial's ``config``: member k has seed ``seeds[k]`` and its draws ``config["member<k>"]``."""
    return [Member(seed, tuple(sorted(config.get(f"member{k}", {}).items()))) for k, seed in enumerate(seeds)]


@ray.remote(num_cpus=0)
class StopBoard:
    """The trials the scheduler has stopped: each asks at its next step."""

    def __init__(self):
        self.stopped: set[str] = set()

    def stop(self, trial_id: str):
        self.stopped.add(trial_id)

    def is_stopped(self, trial_id: str) -> bool:
        return trial_id in self.stopped


class GracefulASHA(ASHAScheduler):
    """ASHA (``ASHAScheduler``'s arguments) whose stop is posted on ``board`` for the trial to carry out, the trial
    going on meanwhile; a trial at ASHA's ``max_t`` iterations is left to end itself."""

    def __init__(self, board, **asha):
        super().__init__(**asha)
        self.board = board

    def on_trial_result(self, tune_controller, trial, result: dict) -> str:
        action = super().on_trial_result(tune_controller, trial, result)
        if action != self.STOP or result[self._time_attr] >= self._max_t:  # at its end the trial ends itself
            return self.CONTINUE
        ray.get(self.board.stop.remote(trial.trial_id))  # posted before the trial's next step asks
        return self.CONTINUE


class PopulationTrial(tune.Trainable):
    """One trial of a search: ``plan`` holds train.py's flags for every trial, the members' seeds, the metric (a field
    of an evaluation, ``EpisodeSummary``'s), the search's folder, in which this trial's is ``trial_<id>``, and the
    scheduler's ``StopBoard``."""

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
            if ray.get(self.plan["board"].is_stopped.remote(self.trial_id)):
                self._stop()
            self.resume.release()
        kind, value = self.results.get()
        self.handed = kind == "result"
        if kind == "error":
            raise value
        if kind == "end":
            iterations = max(record.progress.iterations for record in self.training.loop.records)
            return self._result(iterations) | {"finished": True, "stopped": self.stopping, "done": True}
        return value

    def _stop(self):
        """The members stop after the iteration in progress (or the first, if they are being built)."""
        self.stopping = True
        if self.training is not None:
            self.training.loop.request_stop(STOPPED)

    def cleanup(self):
        """A trial Ray ends before its training did (the search interrupted): its members stop as ``_stop`` says,
        their folders written while Ray waits."""
        if self.thread.is_alive():
            self._stop()
            self.resume.release()
            self.thread.join()


class SearchLines(tune.Callback):
    """A line per trial result (the iteration, the trial's metric, its solved members), end and failure."""

    def __init__(self, metric: str):
        self.metric = metric

    def on_trial_result(self, iteration, trials, trial, result, **info):
        if result.get("finished"):  # the trial's end, which on_trial_complete says
            return
        value = result.get(self.metric)
        shown = f"{value:.3f}" if value is not None else "-"
        print(f"trial {trial.trial_id} it {result['iteration']}: {self.metric} {shown} (best member), "
              f"{result['solved']} solved", flush=True)

    def on_trial_complete(self, iteration, trials, trial, **info):
        result = trial.last_result or {}
        ran = result.get("iteration", 0)
        how = "completed" if completed(result) else "stopped early by the scheduler"
        print(f"trial {trial.trial_id} {how} at iteration {ran}", flush=True)

    def on_trial_error(self, iteration, trials, trial, **info):
        print(f"trial {trial.trial_id} failed (the search goes on)", flush=True)
