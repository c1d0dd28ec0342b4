"""The evaluation inside the training's own step (``InStepEvaluation``): the last ``num_envs`` envs of the training's
``BatchedEnv`` act with a frozen copy of the deterministic policy and never enter the rollout.

An evaluation begins between two iterations: the block restarts as play.py's envs start (``BatchedEnv.restart`` with
the run's seed: the same start states and physics draws) and the learner freezes its policy into ``policy``; every
training step then steps the block too, and the verdict comes once every first episode has ended (or the rule can no
longer be met), a few iterations later, over the same whole episodes ``evaluate`` plays.
"""

from __future__ import annotations

import torch

from ..engine.env import BatchedEnv
from .rollouts import FirstEpisodeTally, Policy, whole_episode_steps
from .statistics import EpisodeSummary, SolvedRule


class InStepEvaluation:
    """Envs [start, env.num_envs) of ``env`` evaluate ``policy`` (set by the learner: a frozen actor whose weights are
    copied in place when an evaluation begins, so a CUDA graph of the step may hold it) from resets seeded with
    ``seed``. Between evaluations the block keeps stepping and counts for nothing."""

    def __init__(self, env: BatchedEnv, num_envs: int, seed: int):
        if not 0 < num_envs < env.num_envs:
            raise ValueError(f"an in-step evaluation takes 1 to {env.num_envs - 1} of the env's {env.num_envs} envs")
        self.env, self.num_envs, self.seed = env, num_envs, seed
        self.start = env.num_envs - num_envs
        self.policy: Policy | None = None
        self.steps = whole_episode_steps(env)
        """Env steps an evaluation plays (play.py's: the time limit)."""
        self.steps_run: int | None = None
        """Env steps of the evaluation in progress (None: none is)."""
        self._obs = env.get_observations()[self.start:].clone()
        self._tally = FirstEpisodeTally(num_envs, env.device)

    @property
    def running(self) -> bool:
        return self.steps_run is not None

    def begin(self):
        """Restart the block from the seed's resets and count its first episodes from now."""
        self._obs.copy_(self.env.restart(self.start, self.env.num_envs, self.seed)[self.start:])
        self._tally.restart(self.steps)
        self.steps_run = 0

    def actions(self) -> torch.Tensor:
        """The block's actions for the next step (device work only)."""
        return self.policy(self._obs).to(torch.float32)

    def after_step(self, obs: torch.Tensor, reward: torch.Tensor, terminated: torch.Tensor, truncated: torch.Tensor):
        """The block's rows of a step's results (device work only)."""
        self._tally.add(reward, terminated, truncated)
        self._obs.copy_(obs)

    def verdict(self, steps: int, rule: SolvedRule) -> EpisodeSummary | None:
        """After ``steps`` more env steps (the host's count): the evaluation's summary once every episode has ended or
        the rule can no longer be met (``SolvedRule.hopeless``: then cut, counting the episodes that had ended); None
        while it runs on. A read from the device."""
        self.steps_run += steps
        ended, failed = self._tally.counts() if self.steps_run < self.steps else (self.num_envs, 0)
        if ended == self.num_envs:
            result = self._tally.result()
        elif rule.hopeless(failed, self.num_envs):
            result = self._tally.result(cut_at_step=self.steps_run)
        else:
            return None
        self.steps_run = None
        return result.summary(min(self.steps, self.env.max_episode_length))
