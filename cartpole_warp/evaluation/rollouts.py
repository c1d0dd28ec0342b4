"""Running a policy on a batched env (trained, zero, random or multisine policies) and the deterministic evaluation
that decides 'solved'.

A policy is any ``policy(obs) -> actions`` callable on torch tensors, obs (N, num_obs) -> actions (N, num_actions).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from ..engine.env import BatchedEnv
from ..engine.streams import TorchGraph
from ..settings.deprecation import renamed
from .statistics import EpisodeStats, EpisodeSummary, SolvedRule

STEPS_WITHOUT_TIME_LIMIT = 1000
"""Env steps an evaluation or play runs where the task has no time limit."""
HOPELESS_CHECK_STEPS = 25
"""How often (env steps) a run asks whether it can stop (``FirstEpisodesRun``'s ``hopeless``): each ask reads a
count back from the device."""
Policy = Callable[[torch.Tensor], torch.Tensor]
"""``policy(obs (N, num_obs)) -> actions (N, num_actions)``, torch tensors on one device."""


def zero_policy(obs: torch.Tensor, num_actions: int = 1) -> torch.Tensor:
    """Never acts."""
    return torch.zeros(obs.shape[0], num_actions, dtype=torch.float32, device=obs.device)


class HostPolicy:
    """A policy whose actions come from the host, step after step (a seeded generator, a clock): a CUDA graph would
    replay one step's actions, so ``FirstEpisodesRun`` launches it op by op (``capturable``)."""

    capturable = False


class RandomPolicy(HostPolicy):
    """Uniform random actions in [-1, 1] from a seeded generator."""

    def __init__(self, num_actions: int, seed: int = 0):
        self.num_actions = num_actions
        self.generator = torch.Generator().manual_seed(seed)

    def __call__(self, obs: torch.Tensor) -> torch.Tensor:
        return (torch.rand(obs.shape[0], self.num_actions, generator=self.generator) * 2 - 1).to(obs.device)


EXCITATION = ((0.75, 0.5), (1.4, 0.3), (2.7, 0.2))
"""(frequency Hz, amplitude) of ``MultisinePolicy``'s cosines: the first near the swing-up's hanging pole's own
frequency, amplitudes summing to the full push."""


class MultisinePolicy(HostPolicy):
    """The same action in every env, a sum of cosines of the time since the first call (``components``: (frequency
    Hz, amplitude) pairs): an excitation for a recording that ``tools.sysid`` fits. Cosines start at their peak, so
    the cart's mean velocity stays 0 and it swings about a point near its start instead of drifting to a stop."""

    def __init__(self, num_actions: int, env_dt_s: float, components: tuple = EXCITATION):
        self.num_actions, self.env_dt_s, self.components = num_actions, env_dt_s, components
        self.steps = 0

    def __call__(self, obs: torch.Tensor) -> torch.Tensor:
        t_s = self.steps * self.env_dt_s
        self.steps += 1
        action = sum(amplitude * math.cos(2 * math.pi * hz * t_s) for hz, amplitude in self.components)
        return torch.full((obs.shape[0], self.num_actions), action, dtype=torch.float32, device=obs.device)


@dataclass
class FirstEpisodes:
    """Each env's first episode in a run: (N,) tensors on the env's device."""

    returns: torch.Tensor
    lengths: torch.Tensor
    """Env steps (the run's step cap for an episode still running at its end)."""
    reached_limit: torch.Tensor
    """bool: the episode reached the time limit (or the step cap) instead of failing."""
    cut_at_step: int | None = None
    """The env step a run stopped at before its step count (``FirstEpisodesRun``'s ``hopeless``), None: it ran
    them all."""
    ended: torch.Tensor | None = None
    """bool: where a run was cut, the episodes that had ended (the others are not counted)."""

    def summary(self, max_episode_length: int) -> EpisodeSummary:
        """Means over the episodes (full: those of ``max_episode_length`` steps; of a cut run, those that ended)."""
        stats = EpisodeStats(self.returns.device, max_episode_length)
        counted = torch.ones_like(self.reached_limit) if self.ended is None else self.ended
        stats.add(counted, self.returns, self.lengths, self.reached_limit)
        return dataclasses.replace(stats.summary(), cut_at_step=self.cut_at_step)


class FirstEpisodeTally:
    """Each of ``num_envs`` envs' first episode since ``restart``, counted on the device step by step on persistent
    tensors (a CUDA graph may hold them): its return, its length and whether it reached the time limit. Steps after
    the first ``cap`` count for nothing; an episode still running then has reached the limit."""

    def __init__(self, num_envs: int, device: str):
        self.finished = torch.ones(num_envs, dtype=torch.bool, device=device)
        """bool: the episode has ended (all, until ``restart``: nothing is counted)."""
        self.reached = torch.ones_like(self.finished)
        self.lengths = torch.zeros(num_envs, dtype=torch.int64, device=device)
        self.returns = torch.zeros(num_envs, dtype=torch.float32, device=device)
        self.steps = torch.zeros((), dtype=torch.int64, device=device)
        self.cap = torch.zeros((), dtype=torch.int64, device=device)

    def restart(self, cap: int):
        """Count first episodes anew, for at most ``cap`` env steps."""
        self.finished.zero_()
        self.reached.fill_(True)
        self.lengths.fill_(cap)
        self.returns.zero_()
        self.steps.zero_()
        self.cap.fill_(cap)

    def add(self, reward: torch.Tensor, terminated: torch.Tensor, truncated: torch.Tensor):
        """One env step's rewards and ends (device work only)."""
        self.steps += 1
        counting = ~self.finished & (self.steps <= self.cap)
        self.returns += torch.where(counting, reward, 0.0)
        ended = (terminated | truncated) & counting
        self.lengths.copy_(torch.where(ended, self.steps, self.lengths))
        self.reached.copy_(torch.where(ended, truncated, self.reached))
        self.finished |= ended

    def counts(self) -> list[int]:
        """Episodes that have ended, and those that ended before the time limit (one read from the device)."""
        return torch.stack([self.finished.sum(), (self.finished & ~self.reached).sum()]).tolist()

    def result(self, cut_at_step: int | None = None) -> FirstEpisodes:
        """The episodes (copies); where ``cut_at_step``, a run stopped there, counting those that had ended."""
        ended = self.finished.clone() if cut_at_step is not None else None
        return FirstEpisodes(self.returns.clone(), self.lengths.clone(), self.reached.clone(), cut_at_step, ended)


class FirstEpisodesRun:
    """Runs of each env's first episode under ``policy`` (``first_episodes``) on persistent tensors. On CUDA (where
    ``capture``) one step of it, the policy, the env step and the episode bookkeeping, is captured as a CUDA graph when
    the run is made (two throw-away steps: every run then starts from a reset) and replayed: a run costs one launch
    per env step, and training's evaluations and play.py compute with the same graph."""

    def __init__(self, env: BatchedEnv, policy: Policy, capture: bool = True):
        self.env, self.policy = env, policy
        self._obs = env.get_observations()
        self.tally = FirstEpisodeTally(env.num_envs, env.device)
        """The run's episodes as they are counted (a ``hopeless`` may read them by block)."""
        capture = capture and getattr(policy, "capturable", True) and torch.device(env.device).type == "cuda"
        self._graph = TorchGraph(env.device) if capture else None
        if self._graph is not None:
            self._advance()  # op by op (allocations, cuBLAS on the graph's stream)
            self._advance()  # captured

    def _step(self):
        obs, reward, terminated, truncated, _ = self.env.step(self.policy(self._obs).to(torch.float32))
        self.tally.add(reward, terminated, truncated)
        self._obs.copy_(obs)

    def _advance(self):
        with torch.inference_mode():
            if self._graph is None:
                self._step()
            else:
                self._graph(self._step)

    def __call__(self, steps: int, on_step: Callable[[int], None] | None = None, reset: bool = True,
                 seed: int | None = None, hopeless: Callable[[int], bool] | None = None) -> FirstEpisodes:
        """Reset the env (re-seeded with ``seed`` where given: the same starts each time; unless ``reset`` is False:
        the episodes it has just begun) and run the policy for ``steps`` env steps without gradients; ``on_step(k)``
        is called after the reset (k = 0) and after each step k (to record pictures). An episode still running after
        ``steps`` counts as having reached the time limit. ``hopeless(failed)``, asked every ``HOPELESS_CHECK_STEPS``
        steps with the count of episodes that ended before the time limit, stops the run where it says True (the
        result then counts the episodes that had ended)."""
        self._obs.copy_(self.env.reset(seed)[0] if reset else self.env.get_observations())
        self.tally.restart(steps)
        if on_step is not None:
            on_step(0)
        for step in range(1, steps + 1):
            self._advance()
            if on_step is not None:
                on_step(step)
            if (hopeless is not None and step % HOPELESS_CHECK_STEPS == 0 and step < steps
                    and hopeless(self.tally.counts()[1])):
                return self.tally.result(cut_at_step=step)
        return self.tally.result()


def first_episodes(env: BatchedEnv, policy: Policy, steps: int, on_step: Callable[[int], None] | None = None,
                   reset: bool = True, seed: int | None = None) -> FirstEpisodes:
    """``FirstEpisodesRun(env, policy)(steps, on_step, reset, seed)``: one run (captured on CUDA unless ``reset`` is
    False, since capturing takes steps)."""
    return FirstEpisodesRun(env, policy, capture=reset)(steps, on_step, reset, seed)


def rollout(env: BatchedEnv, policy: Policy, steps: int, on_step: Callable[[int], None] | None = None,
            seed: int | None = None) -> EpisodeSummary:
    """``first_episodes`` summarised: statistics over each env's first episode; an episode still running after
    ``steps`` counts as full (the run's step cap), which only happens when ``steps`` < max_episode_length."""
    return first_episodes(env, policy, steps, on_step, seed=seed).summary(min(steps, env.max_episode_length))


def whole_episode_steps(env: BatchedEnv) -> int:
    """Env steps that play every first episode to its end: the time limit, or STEPS_WITHOUT_TIME_LIMIT without one."""
    return env.max_episode_length if env.cfg.task.has_time_limit else STEPS_WITHOUT_TIME_LIMIT


def evaluate(run: FirstEpisodesRun, seed: int, rule: SolvedRule | None = None) -> EpisodeSummary:
    """Each env's first episode from a reset seeded with ``seed`` to its end (``whole_episode_steps``): what
    ``play.py --headless`` plays with that env count and seed (the evaluation that decides 'solved'). With the task's
    ``rule``, cut where enough episodes have failed that the rule cannot be met (``SolvedRule.hopeless``;
    ``EpisodeSummary.cut_at_step``): a verdict of 'solved' still takes every episode to its end."""
    steps, n = whole_episode_steps(run.env), run.env.num_envs
    hopeless = None if rule is None else (lambda failed: rule.hopeless(failed, n))
    return run(steps, seed=seed, hopeless=hopeless).summary(min(steps, run.env.max_episode_length))


__getattr__ = renamed(__name__, {"NO_LIMIT_STEPS": "STEPS_WITHOUT_TIME_LIMIT"})
"""The old name, until ``settings.deprecation.REMOVED_IN``."""
