"""The learners, a folder each (``ppo``, ``batched_ppo``, ``sapg``, ``shac``), and the seam between the training loop
and what learns: a ``Learner`` runs one iteration (act, step, learn) on the env, holds the state a checkpoint keeps,
and names the policy an evaluation judges; ``learner_class`` finds one by its name (``agent.learner``: ``train.py
--learner NAME``). A learner imports no other's folder unless built on it (``sapg`` on ``batched_ppo``).

    learner = learner_class(cfg.agent.learner)(env, cfg, rsl_rl_cfg, EpisodeStats(env.device, max_episode_length))
    obs, losses = learner.iteration(obs, it)
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from collections.abc import Callable

    import torch
    from tensordict import TensorDict

    from ...engine.streams import PhaseClock
    from ...evaluation.statistics import EpisodeStats
    from ...settings.config import EnvConfig
    from ...wrappers.rsl_rl import RslRlVecEnv
    from ..config import TrainConfig
    from ..distributed import Ranks

LEARNERS = {"ppo": f"{__name__}.ppo.learner:PpoLearner", "shac": f"{__name__}.shac.learner:ShacLearner",
            "sapg": f"{__name__}.sapg.learner:SapgLearner"}
"""Each learner's class by name, imported when asked for (the backpropagation learner imports the differentiable
rollout, which a PPO run need not load)."""


class Learner(Protocol):
    """What the runner (``TaskRunner``) asks of a learner. Built as ``Learner(env, cfg, rsl_rl_cfg, episodes)``: the
    training's env, its config, rsl-rl's ``train_cfg`` dict of it (``policies.to_rsl_rl``, with ``multi_gpu``) and the
    ``EpisodeStats`` it adds each ended episode to."""

    env: RslRlVecEnv
    """The envs whose episodes ``episodes`` holds (the console line counts them): the training's env, or its
    leader's block (``batched_ppo.learner.MemberEnv``)."""
    episodes: EpisodeStats
    actor: torch.nn.Module
    """The policy an evaluation judges and the exports hold (rsl-rl's ``MLPModel``: its mean when in eval mode)."""
    clock: PhaseClock
    """The seconds of each iteration's collection and learning (its phases 0 and 1)."""
    on_step: Callable[[torch.Tensor, torch.Tensor, dict], None] | None
    """Called with each env step's rewards, dones and extras where the learner steps the env one step at a time
    (rsl-rl's console: its logger's ``process_env_step``)."""

    @staticmethod
    def env_config(cfg: TrainConfig, env_cfg: EnvConfig, ranks: Ranks) -> EnvConfig:
        """The env this learner trains on, for ``cfg`` (ConfigError, before anything is built, where it cannot)."""

    def begin(self, first_iteration: int, end_iteration: int) -> None:
        """Called as ``learn`` starts iterations ``first_iteration`` to ``end_iteration`` (exclusive)."""

    def iteration(self, obs: TensorDict, it: int) -> tuple[TensorDict, dict]:
        """Iteration ``it``: collect experience (``clock.mark(0)`` before, ``mark(1)`` after) and learn from it
        (``mark(2)`` after); the env's last observations and the losses out."""

    @property
    def learning_rate(self) -> float: ...

    @property
    def action_std(self) -> torch.Tensor:
        """The training actions' standard deviation, per action."""

    @property
    def episode_steps(self) -> torch.Tensor:
        """(N,) each of ``env``'s envs' steps into its running episode, as its time-out counter counts them."""

    def train_mode(self) -> None: ...

    def eval_mode(self) -> None:
        """``actor`` as the learner stands now, in eval mode (an evaluation, a checkpoint or an export follows)."""

    def state_dict(self) -> dict:
        """What a checkpoint holds besides the iteration and the progress (``actor_state_dict`` among it)."""

    def load_state_dict(self, loaded: dict, load_cfg: dict | None, strict: bool) -> None:
        """Load ``state_dict``'s parts (``load_cfg``: rsl-rl's choice of parts, e.g. ``{"actor": True}``; None: all)."""

    def release_graphs(self) -> None:
        """Free captured CUDA graphs (before the process group is destroyed); the next iteration captures again."""


def learner_class(name: str) -> type[Learner]:
    """The learner named ``name`` (a key of ``LEARNERS``)."""
    if name not in LEARNERS:
        raise KeyError(f"no learner {name!r}; the learners: {', '.join(LEARNERS)}")
    module, _, attribute = LEARNERS[name].partition(":")
    return getattr(importlib.import_module(module), attribute)
