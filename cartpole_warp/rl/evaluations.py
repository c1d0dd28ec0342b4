"""A training's evaluations (``Evaluations``), for each of its members: when one is due, where it runs (envs of their
own: ``OwnEnvsJudge``, K members' in one run; or inside the training's step: ``InStepJudge``), which policy it judges
and its verdict (``Judged``); a run's record (``rl.record.RunRecord``) enters the verdicts and keeps the best
checkpoint.

Only an evaluation decides 'solved': the deterministic policy over whole episodes (``evaluation.evaluate``: play.py's
episodes), due when an iteration's training episodes meet the task's rule (at most every ``eval.min_interval``
iterations) and at least every ``eval.max_interval``; the best so far is kept as ``model_best.pt``.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import torch

from ..engine.env import BatchedEnv
from ..evaluation.in_step import InStepEvaluation
from ..evaluation.rollouts import FirstEpisodes, FirstEpisodesRun, whole_episode_steps
from ..evaluation.statistics import EpisodeSummary, SolvedRule
from .config import TrainConfig
from .learners import Learner
from .policies import deterministic


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


class OwnEnvsJudge:
    """The members' evaluations as one run on ``eval_env`` (K x M envs, M = ``eval.num_envs``), acting with the
    learner's ``evaluation_policy`` (every member's in one batched forward where there are several): member k's block
    starts as its own evaluation env does (one member: the env reset with its seed, the episodes ``play.py --headless``
    plays of its run; several: each block restarted so, ``BatchedEnv.restart``); each block's whole first episodes are
    member k's verdict (cut, as ``evaluation.evaluate`` cuts, once every judged member's failures keep the rule from
    being met)."""

    def __init__(self, eval_env: BatchedEnv, learner: Learner, seeds: list[int], rule: SolvedRule):
        self.env, self.learner, self.seeds, self.rule = eval_env, learner, seeds, rule
        self.num_members, self.num_envs = len(seeds), eval_env.num_envs // len(seeds)
        self.steps = whole_episode_steps(eval_env)
        self._run: FirstEpisodesRun | None = None

    def prepare(self):
        """Make the run of the policy (on a GPU: capture its CUDA graph) if not made yet, so that the first evaluation
        costs no capture."""
        if self._run is None:
            self.learner.eval_mode()
            self._run = FirstEpisodesRun(self.env, self.learner.evaluation_policy())
            self.learner.train_mode()

    def _hopeless(self, members: list[int], failed_in_all: int) -> bool:
        """Whether every one of ``members`` has failed too many episodes for the rule (``failed_in_all``: the failed
        episodes of every block; several members: one read from the device)."""
        if self.num_members == 1:
            return self.rule.hopeless(failed_in_all, self.num_envs)
        tally = self._run.tally
        failed = (tally.finished & ~tally.reached).view(self.num_members, self.num_envs).sum(dim=1).tolist()
        return all(self.rule.hopeless(failed[k], self.num_envs) for k in members)

    def __call__(self, members: list[int]) -> dict[int, EpisodeSummary]:
        """Each of ``members``' verdict on its policy as the learner stands now."""
        self.prepare()
        m, hopeless = self.num_envs, (lambda failed: self._hopeless(members, failed))
        self.learner.eval_mode()
        try:
            if self.num_members == 1:
                result = self._run(self.steps, seed=self.seeds[0], hopeless=hopeless)
            else:
                for k in members:
                    self.env.restart(k * m, (k + 1) * m, self.seeds[k])
                result = self._run(self.steps, reset=False, hopeless=hopeless)
        finally:
            self.learner.train_mode()
        cap = min(self.steps, self.env.max_episode_length)
        return {k: FirstEpisodes(result.returns[k * m:(k + 1) * m], result.lengths[k * m:(k + 1) * m],
                                 result.reached_limit[k * m:(k + 1) * m], result.cut_at_step,
                                 None if result.ended is None else result.ended[k * m:(k + 1) * m]).summary(cap)
                for k in members}


class Evaluations:
    """The evaluations of the policies of ``learner``'s members (seeded with ``seeds``, member k's with its own) in a
    training of ``cfg``: on ``eval_env`` (envs of their own, ``OwnEnvsJudge``), or inside the training's step where
    ``in_step`` is given (one member); none where neither is. Each member keeps its own schedule."""

    def __init__(self, cfg: TrainConfig, learner: Learner, seeds: list[int], eval_env: BatchedEnv | None = None,
                 in_step: InStepEvaluation | None = None):
        self.limits, self.num_steps_per_env = cfg.eval, cfg.agent.num_steps_per_env
        self.rule = cfg.task_spec.solved
        self.learner = learner
        self.own_envs = OwnEnvsJudge(eval_env, learner, seeds, self.rule) if eval_env is not None else None
        self.in_step = None
        if in_step is not None:
            self.in_step = InStepJudge(in_step, learner.member_actor())
            learner.train_mode()
        self.last_iteration = [-1] * len(seeds)
        """Per member, the iteration after which its latest evaluation began."""

    @property
    def enabled(self) -> bool:
        return self.own_envs is not None or self.in_step is not None

    def prepare(self):
        """``OwnEnvsJudge.prepare``, where the evaluations run on envs of their own."""
        if self.own_envs is not None:
            self.own_envs.prepare()

    def due(self, member: int, it: int, stats: EpisodeSummary) -> bool:
        """Whether ``member``'s policy after iteration ``it`` is to be evaluated (``eval.min_interval``,
        ``max_interval``), by its training episodes' ``stats``."""
        since = it - self.last_iteration[member]
        return since >= self.limits.max_interval or (since >= self.limits.min_interval and self.rule(stats))

    def judge(self, it: int, episodes: list[EpisodeSummary], members: list[int],
              env_steps: list[int]) -> dict[int, Judged]:
        """The verdicts after iteration ``it`` (``episodes``: each member's training episodes of it; ``env_steps``: its
        env steps so far), by member: on envs of their own, where any of ``members`` is due, of every one of them, in
        one run; in the step, of the policy it froze, where its episodes are over (one is begun where it is due and
        none runs)."""
        if self.in_step is not None:
            judged = self._in_step_verdict(it, episodes[0], env_steps[0])
            return {} if judged is None else {0: judged}
        if self.own_envs is None or not any(self.due(k, it, episodes[k]) for k in members):
            return {}
        for k in members:
            self.last_iteration[k] = it
        return {k: Judged(summary, it, env_steps[k]) for k, summary in self.own_envs(members).items()}

    def _in_step_verdict(self, it: int, stats: EpisodeSummary, env_steps: int) -> Judged | None:
        judged = self.in_step.verdict(self.num_steps_per_env, self.rule) if self.in_step.running else None
        if not self.in_step.running and self.due(0, it, stats):
            self.last_iteration[0] = it
            state = self.learner.state_dict()
            actor = self.learner.member_actor()  # the actor as the learner stands now
            try:
                self.in_step.begin(actor, it, env_steps, state)
            finally:
                self.learner.train_mode()
        return judged
