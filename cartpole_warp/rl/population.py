"""Populations: K trainings of one task in one process, on one batched env, learning as one batched computation.

    python train.py --task cartpole-swingup --seeds 0 1 2 3 4 5 6 7 8 9 --device cuda
    python train.py --seeds 0 1 --population.vary agent.algorithm.learning-rate=1e-3,3e-4     # 4 members

Member k (``Member``: a seed and the settings it differs in) owns envs [k N, (k+1) N) of one env of K x N envs,
restarted as a solo run of its seed starts them (``BatchedEnv.restart``: the same start states and physics draws), and
networks initialised as that run's. ``PopulationLearner`` (``learners.batched_ppo``) runs the members' iterations
together: one rollout of the whole env, then one batched PPO update (per member rsl-rl's PPO) of the members still
training. Everything else is per member, an ordinary ``TaskRunner`` over a ``MemberLearner`` (a view of member k):
its progress, evaluations (on envs of their own, with its seed), verdicts, ``model_best.pt``, checkpoints, exports,
curve and ``summary.json`` in a run folder of its own, which ``play.py --run`` and ``train.py --resume`` take as any
run's.
"""

from __future__ import annotations

from ..wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
import itertools

import torch

from ..engine.env import BatchedEnv
from ..evaluation.rollouts import FirstEpisodes, FirstEpisodesRun, whole_episode_steps
from ..evaluation.statistics import EpisodeSummary, SolvedRule
from ..settings.config import ConfigError, refuse_present
from ..settings.deprecation import moved_names
from .config import TrainConfig
from .learners.batched_ppo.learner import VARIABLE_SETTINGS, Member, PopulationLearner, batched_ppo_problems


def parse_vary(vary: list[str]) -> dict[str, list[float]]:
    """``--population.vary`` entries (``agent.algorithm.learning-rate=1e-3,3e-4``) as {setting: values};
    ConfigError in one line for a setting members cannot differ in, a value that is not a number, or a setting named
    twice."""
    grid: dict[str, list[float]] = {}
    for entry in vary:
        name, sep, values = entry.partition("=")
        setting = name.strip().replace("-", "_").removeprefix("agent.algorithm.")
        flag = f"--population.vary {entry!r}"
        if not sep or not values:
            raise ConfigError(f"{flag}: write name=value1,value2 (agent.algorithm.learning-rate=1e-3,3e-4)")
        if setting not in VARIABLE_SETTINGS:
            raise ConfigError(f"--population.vary {name}: members share one env and their networks' shapes, so they "
                              f"may differ only in agent.algorithm's {', '.join(VARIABLE_SETTINGS)}")
        if setting in grid:
            raise ConfigError(f"--population.vary names {setting} twice: give all its values in one entry")
        try:
            grid[setting] = [float(value) for value in values.split(",")]
        except ValueError:
            raise ConfigError(f"{flag}: the values must be numbers, comma-separated") from None
    return grid


def members_of(seeds: list[int], vary: list[str] = ()) -> list[Member]:
    """One member per combination of the values of the ``vary`` settings (``--population.vary``) and seed;
    ConfigError in one line for no seeds or a seed given twice."""
    if not seeds:
        raise ConfigError("a population needs seeds: --seeds 0 1 2 ...")
    if len(set(seeds)) != len(seeds):
        twice = sorted({seed for seed in seeds if seeds.count(seed) > 1})
        raise ConfigError(f"--seeds names seed {', '.join(map(str, twice))} twice: each member needs its own seed")
    grid = parse_vary(list(vary))
    combinations = itertools.product(*[[(name, value) for value in values] for name, values in grid.items()])
    return [Member(seed, tuple(settings)) for settings in combinations for seed in seeds]


def check_population(cfg: TrainConfig, members: list[Member]):
    """ConfigError in one line where ``cfg`` cannot train as a population (``batched_ppo_problems``)."""
    problems = {f"--learner {cfg.agent.learner} (populations train with PPO)": cfg.agent.learner != "ppo",
                **batched_ppo_problems(cfg)}
    refuse_present(f"a population of {cfg.task} cannot train", problems)
    if len(members) < 1:
        raise ConfigError("a population needs at least one member")


class PopulationEvaluation:
    """The members' evaluations as one run on ``eval_env`` (K x M envs, M = ``eval.num_envs``): member k's block
    restarts as its own evaluation env starts (``BatchedEnv.restart`` with its seed: the episodes ``play.py --headless``
    plays of its run) and acts with member k's deterministic policy, all members' in one batched forward; each block's
    whole first episodes are member k's verdict (cut, as a solo evaluation is, once every judged member's failures keep
    the rule from being met)."""

    def __init__(self, eval_env: BatchedEnv, learner: PopulationLearner, seeds: list[int], rule: SolvedRule):
        self.env, self.learner, self.seeds, self.rule = eval_env, learner, seeds, rule
        self.num_members, self.num_envs = len(seeds), eval_env.num_envs // len(seeds)
        self.steps = whole_episode_steps(eval_env)
        self._run = FirstEpisodesRun(eval_env, self._policy)

    def _policy(self, obs: torch.Tensor) -> torch.Tensor:
        return self.learner.ppo.model.action_mean(obs.view(self.num_members, self.num_envs, -1)).flatten(0, 1)

    def _hopeless(self, members: list[int]) -> bool:
        """Whether every one of ``members`` has failed too many episodes for the rule (one read from the device)."""
        tally = self._run.tally
        failed = (tally.finished & ~tally.reached).view(self.num_members, self.num_envs).sum(dim=1).tolist()
        return all(self.rule.hopeless(failed[k], self.num_envs) for k in members)

    def __call__(self, members: list[int]) -> dict[int, EpisodeSummary]:
        """Each of ``members``' verdict on its policy as it stands."""
        m = self.num_envs
        for k in members:
            self.env.restart(k * m, (k + 1) * m, self.seeds[k])
        result = self._run(self.steps, reset=False, hopeless=lambda failed: self._hopeless(members))
        cap = min(self.steps, self.env.max_episode_length)
        return {k: FirstEpisodes(result.returns[k * m:(k + 1) * m], result.lengths[k * m:(k + 1) * m],
                                 result.reached_limit[k * m:(k + 1) * m], result.cut_at_step,
                                 None if result.ended is None else result.ended[k * m:(k + 1) * m]).summary(cap)
                for k in members}


__getattr__ = moved_names(__name__, f"{__package__}.learners.batched_ppo.learner")
"""The learner's parts that lived here (``PopulationLearner``, ``MemberLearner``, ...), until
``settings.deprecation.REMOVED_IN``."""
