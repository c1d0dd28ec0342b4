"""A training run's evaluations (``Evaluations``): when one is due, where it runs (envs of its own, or inside the
training's step: ``InStepJudge``), which policy it judges, its verdict (``Judged``) and the best checkpoint.

Only an evaluation decides 'solved': the deterministic policy over whole episodes (``evaluation.evaluate``: play.py's
episodes), due when an iteration's training episodes meet the task's rule (at most every ``eval.min_interval``
iterations) and at least every ``eval.max_interval``; the best so far is kept as ``model_best.pt``.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch

from ..engine.env import BatchedEnv
from ..evaluation.in_step import InStepEvaluation
from ..evaluation.rollouts import FirstEpisodesRun, evaluate
from ..evaluation.statistics import EpisodeSummary
from .config import TrainConfig
from .learners import Learner
from .policies import deterministic
from .runs import BEST_CHECKPOINT, Progress


@dataclass
class Judged:
    """An evaluation's verdict on the policy after iteration ``iteration``, trained on ``env_steps``."""

    summary: EpisodeSummary
    iteration: int
    env_steps: int
    state: dict | None = None
    """The policy's checkpoint state (``Learner.state_dict``), where it is no longer the learner's own (None: it is)."""


class InStepJudge:
    """The evaluation inside the training's step (``InStepEvaluation``: the env's last envs), on the learner's side:
    the frozen copy of the actor those envs act with, and which policy it is (iteration, env steps, state) until its
    verdict. One evaluation at a time."""

    def __init__(self, in_step: InStepEvaluation, actor: torch.nn.Module):
        self.in_step = in_step
        self.frozen_actor = copy.deepcopy(actor).eval().requires_grad_(False)
        in_step.policy = deterministic(self.frozen_actor)  # weights copied in place: a CUDA graph may hold it
        self.judged_policy: tuple[int, int, dict] | None = None
        """The iteration, env steps and checkpoint state of the policy the running evaluation plays."""

    @property
    def running(self) -> bool:
        return self.in_step.running

    def begin(self, actor: torch.nn.Module, iteration: int, env_steps: int, state: dict):
        """Freeze ``actor`` (the policy after ``iteration``, whose checkpoint state is ``state``) and restart the
        evaluation's envs."""
        self.frozen_actor.load_state_dict(actor.state_dict())
        self.judged_policy = (iteration, env_steps, copy.deepcopy(state))
        self.in_step.begin()

    def verdict(self, steps: int, rule) -> Judged | None:
        """After ``steps`` more env steps: the running evaluation's verdict where its episodes are over."""
        summary = self.in_step.verdict(steps, rule)
        return Judged(summary, *self.judged_policy) if summary is not None else None


class Evaluations:
    """The evaluations of ``learner``'s policy in a run of ``cfg``: on ``eval_env`` (envs of their own, seeded with
    the run's seed), or inside the training's step where ``in_step`` is given; none where neither is."""

    def __init__(self, cfg: TrainConfig, learner: Learner, eval_env: BatchedEnv | None = None,
                 in_step: InStepEvaluation | None = None):
        self.limits, self.seed, self.num_steps_per_env = cfg.eval, cfg.env.seed, cfg.agent.num_steps_per_env
        self.rule, self.play_metric = cfg.task_spec.solved, cfg.task_spec.play_metric
        self.learner, self.eval_env = learner, eval_env
        self.in_step = InStepJudge(in_step, learner.actor) if in_step is not None else None
        self._run: FirstEpisodesRun | None = None
        self._given: EpisodeSummary | None = None
        self.last_iteration = -1
        """The iteration after which the latest evaluation began."""

    @property
    def enabled(self) -> bool:
        return self.eval_env is not None or self.in_step is not None

    def prepare(self):
        """Make the run of the policy on ``eval_env`` (on a GPU: capture its CUDA graph) if not made yet, so that the
        first evaluation costs no capture."""
        if self.eval_env is not None and self._run is None:
            self.learner.eval_mode()
            self._run = FirstEpisodesRun(self.eval_env, deterministic(self.learner.actor))
            self.learner.train_mode()

    def give(self, summary: EpisodeSummary):
        """The verdict on the policy after the iteration now ending, from an evaluation run elsewhere (a population's,
        which judges its members together): ``judge`` returns it."""
        self._given = summary

    def due(self, it: int, stats: EpisodeSummary) -> bool:
        """Whether the policy after iteration ``it`` is to be evaluated (``eval.min_interval``, ``max_interval``)."""
        since = it - self.last_iteration
        return since >= self.limits.max_interval or (since >= self.limits.min_interval and self.rule(stats))

    def judge(self, it: int, stats: EpisodeSummary, env_steps: int) -> Judged | None:
        """The verdict of an evaluation after iteration ``it``: on ``eval_env``, of the policy after ``it`` where one is
        due; in the step, of the policy it froze, where its episodes are over (one is begun where it is due and none
        runs); a verdict ``give``n for it. None otherwise."""
        if self._given is not None:
            self.last_iteration, summary, self._given = it, self._given, None
            return Judged(summary, it, env_steps)
        if self.in_step is not None:
            return self._in_step_verdict(it, stats, env_steps)
        if self.eval_env is None or not self.due(it, stats):
            return None
        self.last_iteration = it
        self.prepare()
        self.learner.eval_mode()
        try:
            return Judged(evaluate(self._run, self.seed, self.rule), it, env_steps)
        finally:
            self.learner.train_mode()

    def _in_step_verdict(self, it: int, stats: EpisodeSummary, env_steps: int) -> Judged | None:
        judged = self.in_step.verdict(self.num_steps_per_env, self.rule) if self.in_step.running else None
        if not self.in_step.running and self.due(it, stats):
            self.last_iteration = it
            state = self.learner.state_dict()
            self.learner.eval_mode()  # the actor as the learner stands now
            try:
                self.in_step.begin(self.learner.actor, it, env_steps, state)
            finally:
                self.learner.train_mode()
        return judged

    def record(self, judged: Judged, solved: bool, progress: Progress, run_dir: Path | None,
               write: Callable[[Path, dict, int, dict], None]):
        """Enter a verdict in ``progress``: the first solved one as ``solved_at`` (the judged policy's iterations and
        env steps, the training seconds until the verdict); the best so far (solved first, then the play metric) as
        ``best``, its policy written (``write``) as ``model_best.pt`` in ``run_dir`` with the progress as it stood
        after its iteration, so that a resume from it continues there."""
        metric = self.play_metric
        if solved and progress.solved_at is None:
            progress.solved_at = {"iterations": judged.iteration + 1, "env_steps": judged.env_steps,
                                  "train_time_s": round(progress.train_time_s, 3),
                                  metric: getattr(judged.summary, metric)}
        score = (solved, getattr(judged.summary, self.play_metric) or 0.0)
        best = progress.best
        if best is not None and score <= (best["solved"], best[self.play_metric] or 0.0):
            return
        progress.best = {"iteration": judged.iteration, "solved": solved, self.play_metric: score[1]}
        if run_dir is not None:
            state = judged.state if judged.state is not None else self.learner.state_dict()
            infos = progress.as_of(judged.iteration) if judged.state is not None else progress.infos()
            write(run_dir / BEST_CHECKPOINT, state, judged.iteration, infos)
