"""The learners, a folder each (``ppo``, ``batched_ppo``, ``sapg``, ``shac``, ``fast_td3``), and the seam between the
training loop and what learns: a ``Learner`` of one run or K (a population's members) runs one iteration (act, step,
learn) of them all on the env, reads out each member's figures (``Readout``), holds the state each member's checkpoint
keeps, and names the policies an evaluation judges; ``learner_class`` finds one by its name (``agent.learner``:
``train.py --learner NAME``). A learner imports no other's folder unless built on it (``sapg`` on ``batched_ppo``).

    learner = learner_class(cfg.agent.learner)(env, cfg, rsl_rl_cfg, EpisodeStats(env.device, max_episode_length))
    obs, losses = learner.iteration(obs, it)
    readout = learner.read(losses)                       # member k's episodes: readout.episodes[k]
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from collections.abc import Callable

    import torch
    from tensordict import TensorDict

    from ...engine.streams import PhaseClock
    from ...evaluation.statistics import EpisodeSummary
    from ...settings.config import EnvConfig
    from ...wrappers.rsl_rl import RslRlVecEnv
    from ..config import TrainConfig
    from ..distributed import Ranks

LEARNERS = {"ppo": f"{__name__}.ppo.learner:PpoLearner", "shac": f"{__name__}.shac.learner:ShacLearner",
            "sapg": f"{__name__}.sapg.learner:SapgLearner", "fasttd3": f"{__name__}.fast_td3.learner:FastTd3Learner"}
"""Each learner's class by name, imported when asked for (the backpropagation learner imports the differentiable
rollout, which a PPO run need not load)."""


@dataclass
class Readout:
    """Each member's figures after an iteration (``Learner.read``): member k's at index k; all but the action noise
    (a tensor) read to the host."""

    episodes: list[EpisodeSummary]
    learning_rates: list[float]
    nonfinite: list[bool]
    """The learner found a non-finite number in the member's networks (a learner that does not look says False)."""
    losses: list[dict[str, float]]
    action_std: list[torch.Tensor]

    @classmethod
    def of_one(cls, episodes: EpisodeSummary, learning_rate: float, action_std: torch.Tensor,
               losses: dict[str, float]) -> Readout:
        """A one-member learner's figures (it does not look for non-finite numbers)."""
        return cls([episodes], [learning_rate], [False], [losses], [action_std])


class Learner(Protocol):
    """What the training loop (``rl.loop.TrainingLoop``) asks of a learner of ``num_members`` runs at once (1, or a
    population's K: member k on block k of the env). A one-member learner is built as ``Learner(env, cfg, rsl_rl_cfg,
    episodes)``: the training's env, its config, rsl-rl's ``train_cfg`` dict of it (``policies.to_rsl_rl``, with
    ``multi_gpu``) and the ``EpisodeStats`` it adds each ended episode to."""

    num_members: int
    env: RslRlVecEnv
    """The env it steps."""
    clock: PhaseClock
    """The seconds of each iteration's collection and learning (its phases 0 and 1)."""
    on_step: Callable[[torch.Tensor, torch.Tensor, dict], None] | None
    """Called with each env step's rewards, dones and extras where the learner steps the env one step at a time
    (rsl-rl's console: its logger's ``process_env_step``)."""

    @staticmethod
    def env_config(cfg: TrainConfig, env_cfg: EnvConfig, ranks: Ranks) -> EnvConfig:
        """The env this learner trains on, for ``cfg`` (ConfigError, before anything is built, where it cannot)."""

    def begin(self, first_iteration: int, end_iteration: int) -> None:
        """Called as the loop starts iterations ``first_iteration`` to ``end_iteration`` (exclusive)."""

    def iteration(self, obs: TensorDict, it: int) -> tuple[TensorDict, dict]:
        """Iteration ``it`` of every member still training: collect experience (``clock.mark(0)`` before, ``mark(1)``
        after) and learn from it (``mark(2)`` after); the env's last observations and the losses (``read``'s input)
        out."""

    def read(self, losses: dict) -> Readout:
        """The iteration's figures per member on the host, its episodes' statistics among them (summed over a
        torchrun job's processes where the learner spans them), which then start afresh."""

    @property
    def episode_steps(self) -> torch.Tensor:
        """(K, N) each member's envs' steps into their running episodes, as their time-out counters count them."""

    def retire(self, member: int) -> None:
        """Stop training ``member``: its run has ended (the others go on)."""

    def member_actor(self, member: int = 0) -> torch.nn.Module:
        """``member``'s policy as the learner stands now (rsl-rl's ``MLPModel``: its mean in eval mode), in eval mode;
        ``train_mode`` after."""

    def evaluation_policy(self) -> Callable[[torch.Tensor], torch.Tensor]:
        """Every member's deterministic policy at once on K equal blocks of envs (block k member k's), acting with the
        learner's networks as they stand whenever it is called between ``eval_mode`` and ``train_mode``."""

    def train_mode(self) -> None: ...

    def eval_mode(self) -> None:
        """The networks ``evaluation_policy`` acts with, in eval mode (an evaluation follows)."""

    def state_dict(self, member: int = 0) -> dict:
        """What ``member``'s checkpoint holds besides the iteration and the progress (``actor_state_dict`` among it)."""

    def load_state_dict(self, loaded: dict, load_cfg: dict | None, strict: bool, member: int = 0) -> None:
        """Load ``state_dict``'s parts into ``member`` (``load_cfg``: rsl-rl's choice of parts, e.g. ``{"actor":
        True}``; None: all)."""

    def release_graphs(self) -> None:
        """Free captured CUDA graphs (before the process group is destroyed); the next iteration captures again."""


def learner_class(name: str) -> type[Learner]:
    """The learner named ``name`` (a key of ``LEARNERS``)."""
    if name not in LEARNERS:
        raise KeyError(f"no learner {name!r}; the learners: {', '.join(LEARNERS)}")
    module, _, attribute = LEARNERS[name].partition(":")
    return getattr(importlib.import_module(module), attribute)
