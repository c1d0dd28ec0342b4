"""``--learner sapg``: split and aggregate policy gradients (after SAPG: Singla, Agarwal and Pathak, ICML 2024).

The run's env is ``agent.sapg.num_blocks`` blocks of ``env.num_envs`` envs, block k policy k's. Every policy learns
rsl-rl's PPO on its own block, all as one batched computation (``batched_ppo.BatchedPpoLearner``); policy 0, the leader,
also learns from one follower's block per iteration (``LeaderFollowerPPO``). The leader is the run's policy: the
loop judges, saves and exports it (``SapgLearner``), so the run's folder plays and exports as a PPO run's.
"""

from __future__ import annotations

from ....wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
import dataclasses
import functools

import torch
from tensordict import TensorDict

from ....evaluation.rollouts import Policy
from ....evaluation.statistics import EpisodeStats
from ....settings.config import ConfigError, EnvConfig, refuse_present
from ....wrappers.rsl_rl import RslRlVecEnv
from ...config import TrainConfig
from ...distributed import Ranks
from ...policies import deterministic
from .. import Readout
from ..batched_ppo.learner import BatchedPpoLearner, Member, batched_ppo_problems
from ..batched_ppo.update import BatchedActorCritic, PopulationPPO

OPTIMIZER_STATE = ("exp_avg", "exp_avg_sq", "adam_steps", "learning_rate")
"""``PopulationPPO``'s per-member optimiser state besides the model: Adam's moments and steps, the learning rate."""

FOLLOWER_SEED_STRIDE = 1 << 20
"""Follower k of a run of seed s initialises its networks as a run of seed s + k * FOLLOWER_SEED_STRIDE would."""


class LeaderFollowerPPO(PopulationPPO):
    """``PopulationPPO`` whose member 0, the leader, also learns from member j's rollout, j drawn among the followers
    1 .. K-1 each iteration:

        L_leader = L_PPO(own rollout) + off_policy_coef * (L_surrogate + value_loss_coef * L_value)(j's rollout)

    On j's samples the ratio is pi_leader(a|s) / pi_j(a|s) (j's policy acted), clipped as PPO's with the leader's
    ``clip_param``; the value targets are one-step targets of the leader's critic as the rollout ended, r + gamma (1 -
    done) V(s'), the advantages their TD errors minus V(s), normalised over the rollout (as PPO's, unless
    ``normalize_advantage_per_mini_batch``), the value loss clipped around V(s) as PPO's; r is j's reward as stored (a
    time-out bootstrapped with j's critic). The mini-batches of j's samples are a permutation of their own, as many
    and as large as the leader's. The followers learn PPO alone; with ``off_policy_coef`` 0 the update is
    ``PopulationPPO``'s."""

    def __init__(self, model: BatchedActorCritic, num_envs: int, num_steps: int, *, off_policy_coef: float = 1.0,
                 dual_clip: float | None = None, **settings):
        if model.num_members < 2:
            raise ValueError("a leader needs at least one follower: two members or more")
        super().__init__(model, num_envs, num_steps, **settings)
        self.off_policy_coef, self.dual_clip = off_policy_coef, dual_clip
        device = model.params.device
        self.leader_index = torch.zeros(1, dtype=torch.long, device=device)
        self.follower = torch.ones(1, dtype=torch.long, device=device)
        """(1,) the follower whose rollout the leader learns from in this iteration (drawn by ``compute_returns``)."""
        self.off_policy = torch.zeros(num_steps, num_envs, self.rollout.shape[-1], device=device)
        """(T, N, F) laid out as a member's ``rollout``: the follower's observations, actions, log-probabilities,
        means and stds, with the leader's values, targets and advantages."""
        self._off_permutation = torch.arange(num_steps * num_envs, device=device)
        self._off_policy_sums = torch.zeros(2, model.num_members, device=device)

    @torch.no_grad()
    def compute_returns(self, last_obs: torch.Tensor):
        """``PopulationPPO``'s returns, then a follower drawn and the leader's targets and advantages on its rollout."""
        super().compute_returns(last_obs)
        self.follower.random_(1, self.model.num_members)
        self.off_policy.copy_(self.rollout.index_select(0, self.follower)[0])
        obs, _, values, returns, advantages, *_ = (t.squeeze(-1) for t in self.off_policy.split(self._fields, -1))
        steps, envs = self.num_steps, self.num_envs
        values.copy_(self.model.values(obs.reshape(1, steps * envs, -1), self.leader_index).view(steps, envs))
        last_values = self.model.values(last_obs.index_select(0, self.follower), self.leader_index)
        rewards, dones = (t.index_select(0, self.follower)[0] for t in (self.rewards, self.dones))
        returns.copy_(rewards + (1.0 - dones) * self.gamma[0] * torch.cat((values[1:], last_values)))
        advantages.copy_(returns - values)
        if not self.normalize_advantage_per_mini_batch:
            advantages.copy_((advantages - advantages.mean()) / (advantages.std() + 1e-8))

    def update(self, permutation: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """``PopulationPPO.update``, the leader's mini-batches of the follower's rollout drawn first; its mean losses
        on them are added as ``off_policy_surrogate`` and ``off_policy_value`` (K,), 0 for the followers."""
        self._off_permutation.copy_(torch.rand(self.num_steps * self.num_envs, device=self.rollout.device).argsort())
        self._off_policy_sums.zero_()
        losses = super().update(permutation)
        surrogate, value = self._off_policy_sums / (self.num_learning_epochs * self.num_mini_batches)
        return losses | {"off_policy_surrogate": surrogate, "off_policy_value": value}

    def _step(self, loss: torch.Tensor, mini_batch: int):
        """The leader's loss on mini-batch ``mini_batch`` of the follower's rollout added to its own, then the step."""
        size = self.num_envs * self.num_steps // self.num_mini_batches
        rows = self._off_permutation[mini_batch * size:(mini_batch + 1) * size]
        batch = self.off_policy.flatten(0, 1)[rows][None]
        surrogate, value, _ = self._losses(batch, self.leader_index, self.dual_clip)
        self._off_policy_sums[:, 0] += torch.cat((surrogate, value)).detach()
        off_policy_loss = self.off_policy_coef * (surrogate + self.value_loss_coef[self.leader_index] * value)
        super()._step(torch.cat((loss[:1] + off_policy_loss, loss[1:])), mini_batch)


class SapgLearner:
    """The leader of a ``LeaderFollowerPPO`` population as the run's learner (``rl.learners.Learner``, of one member):
    the run's episodes, losses, learning rate and action noise are the leader's block's, its evaluations judge the
    leader, and a checkpoint holds the leader in rsl-rl's format (``play.py`` and the exports read it as a PPO run's)
    with every policy's state besides (``sapg_state_dict``, which ``--resume`` restores). A follower whose networks
    go non-finite starts again from the leader's."""

    num_members = 1

    @staticmethod
    def env_config(cfg: TrainConfig, env_cfg: EnvConfig, ranks: Ranks) -> EnvConfig:
        """``num_blocks`` times the envs; ConfigError where the run cannot train this way."""
        problems = {"torchrun (its blocks learn in one process)": ranks.distributed,
                    "a task that observes camera frames (its batches of the followers' samples keep no frames)":
                        cfg.env.camera.enabled, **batched_ppo_problems(cfg)}
        refuse_present("--learner sapg cannot train", problems)
        return dataclasses.replace(env_cfg, num_envs=env_cfg.num_envs * cfg.agent.sapg.num_blocks)

    def __init__(self, env: RslRlVecEnv, cfg: TrainConfig, rsl_rl_cfg: dict, episodes: EpisodeStats):
        sapg, seed = cfg.agent.sapg, cfg.env.seed
        entropy = sapg.follower_entropy_coefs or [cfg.agent.algorithm.entropy_coef] * (sapg.num_blocks - 1)
        members = [Member(seed)] + [Member(seed + k * FOLLOWER_SEED_STRIDE, (("entropy_coef", coef),))
                                    for k, coef in enumerate(entropy, start=1)]
        self.batched = BatchedPpoLearner(
            env, [member.config(cfg) for member in members], rsl_rl_cfg, seed,
            ppo_class=functools.partial(LeaderFollowerPPO, off_policy_coef=sapg.off_policy_coef,
                                        dual_clip=sapg.dual_clip))
        self.env, self.clock, self.on_step = env, self.batched.clock, None
        self.actor = self.batched.actors[0]
        """The leader's rsl-rl actor (its weights copied in by ``eval_mode``)."""

    @property
    def episode_steps(self) -> torch.Tensor:
        return self.batched.episode_steps[:1]

    def begin(self, first_iteration: int, end_iteration: int):
        """Nothing: every policy trains from the first iteration."""

    def iteration(self, obs: TensorDict, it: int) -> tuple[TensorDict, dict]:
        """Every policy's iteration; the leader's losses out. A follower whose networks went non-finite starts again
        from the leader's state (else the leader would learn from its non-finite samples), with a line saying so."""
        obs, losses = self.batched.iteration(obs, it)
        readout = self.batched.read(losses)
        for k in range(1, self.batched.num_members):
            if readout.nonfinite[k]:
                self._restart_follower(k)
                print(f"follower {k}'s networks went non-finite in iteration {it + 1}: it starts again from the "
                      "leader's", flush=True)
        return obs, readout.losses[0]

    def read(self, losses: dict) -> Readout:
        """The leader's figures (``iteration`` read every policy's)."""
        readout = self.batched.readout
        return Readout([readout.episodes[0]], [readout.learning_rates[0]], [readout.nonfinite[0]], [losses],
                       [readout.action_std[0]])

    def retire(self, member: int):
        """Nothing: the run ends with its leader."""

    @torch.no_grad()
    def _restart_follower(self, k: int):
        """Follower ``k`` given the leader's networks, normalisers, Adam state and learning rate."""
        ppo = self.batched.ppo
        ppo.model.load_member_state_dicts(k, *ppo.model.member_state_dicts(0))
        for name in OPTIMIZER_STATE:
            getattr(ppo, name)[k] = getattr(ppo, name)[0]

    def member_actor(self, member: int = 0) -> torch.nn.Module:
        return self.batched.member_actor(0)

    def evaluation_policy(self) -> Policy:
        """The leader's, through its rsl-rl actor (``eval_mode`` copies its weights in)."""
        return deterministic(self.actor)

    def train_mode(self):
        self.batched.train_mode()

    def eval_mode(self):
        self.batched.member_actor(0)

    def state_dict(self, member: int = 0) -> dict:
        """The leader's checkpoint as a PPO run's, and every policy's networks, normalisers and optimiser state."""
        ppo = self.batched.ppo
        state = {"model": ppo.model.state_dict()} | {name: getattr(ppo, name) for name in OPTIMIZER_STATE}
        return self.batched.state_dict(0) | {"sapg_state_dict": state}

    @torch.no_grad()
    def load_state_dict(self, loaded: dict, load_cfg: dict | None, strict: bool, member: int = 0):
        """Every policy's state (``load_cfg`` None: a resume, of a sapg checkpoint only), or the leader's networks that
        ``load_cfg`` names (rsl-rl's choice of parts: the best policy loaded for the exports)."""
        ppo = self.batched.ppo
        if load_cfg is None:
            if "sapg_state_dict" not in loaded:
                raise ConfigError("--learner sapg resumes only a sapg run's checkpoint (it holds every policy's state)")
            state = loaded["sapg_state_dict"]
            ppo.model.load_state_dict(state["model"], strict=strict)
            for name in OPTIMIZER_STATE:
                getattr(ppo, name).copy_(state[name])
        else:
            self.batched.load_state_dict(loaded, load_cfg, strict, 0)
        self.batched.member_actor(0)  # the leader's rsl-rl networks hold what was loaded

    def release_graphs(self):
        self.batched.release_graphs()
