"""``ShacLearner``: training by short-horizon analytic policy gradients through the simulator (SHAC: Xu et al.,
"Accelerated Policy Learning with Parallel Differentiable Simulation", ICLR 2022), for any state task on
SolverFeatherstone.

    python train.py --task cartpole-balance --learner shac --num-envs 256

Each iteration runs every env ``agent.num_steps_per_env`` env steps on ``gradients.DifferentiableRollout`` under the
actor's actions and ascends, by the gradient through the simulator's adjoints, the window's discounted rewards plus
the discounted value (a target critic's) of where each env's window ends: after an episode's end the window's later
steps count for nothing, and a termination's value is 0. The critic then fits TD(lambda) targets of the window. Envs
carry their states from window to window; an env whose episode ended starts its next one from the task's reset
distribution (drawn by the training env, whose physics, randomized or not, the rollout simulates). The actor and
critic are rsl-rl's networks, built as PPO's are (``policies.build_networks``); the loop around the learner is the
runner's (``TaskRunner``): episode statistics, evaluations and the solved rule, checkpoints, exports, ``summary.json``.
"""

from __future__ import annotations

import copy
import dataclasses

import torch
from tensordict import TensorDict

from ....engine.streams import PhaseClock
from ....evaluation.rollouts import Policy
from ....evaluation.statistics import EpisodeStats
from ....gradients.rollout import DifferentiableRollout, Trajectory
from ....settings.config import ConfigError, EnvConfig, refuse_present
from ....settings.deprecation import renamed
from ....wrappers.rsl_rl import RslRlVecEnv
from ...config import TrainConfig
from ...distributed import Ranks
from ...policies import build_networks, deterministic
from .. import Readout


def window_targets(rewards: torch.Tensor, next_values: torch.Tensor, terminated: torch.Tensor, ended: torch.Tensor,
                   gamma: float, lam: float) -> torch.Tensor:
    """TD(lambda) returns (H, N) of a window's steps: reward + gamma * the value after it, where the episode ends at the
    step (``ended``; the value 0 where ``terminated``), else mixed with the next step's return by ``lam`` (the window's
    last step bootstraps from its value). ``next_values[t]`` is the value of the state after step t."""
    bootstrap = torch.where(terminated, 0.0, next_values)
    targets = torch.empty_like(rewards)
    following = next_values[-1]  # the window's last step: (1 - lam) V + lam V
    for t in reversed(range(rewards.shape[0])):
        mixed = (1 - lam) * next_values[t] + lam * following
        following = rewards[t] + gamma * torch.where(ended[t], bootstrap[t], mixed)
        targets[t] = following
    return targets


SHAC_ADAM_BETAS = (0.7, 0.95)
"""SHAC's Adam betas for both networks (its released configs)."""


def check_shac(cfg: TrainConfig):
    """ConfigError, before anything is built, where ``--learner shac`` cannot train ``cfg`` as asked."""
    problems = {
        "a task that observes camera frames (the renderer has no adjoint)": cfg.env.camera.enabled,
        "env.sim.solver other than featherstone (mujoco-warp's adjoints are not here)":
            cfg.env.sim.solver != "featherstone",
        "env.randomization.action_delay_steps (the rollout has no action history)":
            cfg.env.randomization.action_delay_steps > 0,
        "env.randomization.obs_noise_std (the rollout observes without noise)": cfg.env.randomization.obs_noise_std > 0,
        "agent.torch_compile_mode (the learner steps the networks itself)": cfg.agent.torch_compile_mode is not None,
        "eval.in_step (the learner steps its envs itself; evaluations run on envs of their own)": cfg.eval.in_step,
    }
    refuse_present(f"--learner shac cannot train {cfg.task}", problems)


class ShacLearner:
    """SHAC's iterations (module docstring) on ``env`` (``rl.learners.Learner``, of one member)."""

    num_members = 1

    @staticmethod
    def env_config(cfg: TrainConfig, env_cfg: EnvConfig, ranks: Ranks) -> EnvConfig:
        """``env_cfg`` with Newton's modules compiled with their adjoints (``sim.gradients``) for every env of the
        process, the evaluation's too (the option is Newton's, per module: envs built without it would compile them
        again); ConfigError where the learner cannot train ``cfg`` (``check_shac``) or under torchrun."""
        check_shac(cfg)
        if ranks.distributed:
            raise ConfigError("--learner shac trains in one process (not under torchrun)")
        return dataclasses.replace(env_cfg, sim=dataclasses.replace(env_cfg.sim, gradients=True))

    def __init__(self, env: RslRlVecEnv, cfg: TrainConfig, rsl_rl_cfg: dict, episodes: EpisodeStats):
        check_shac(cfg)
        self.env, self.episodes, self.device = env, episodes, env.device
        self.clock = PhaseClock(self.device, phases=2)
        self.settings = s = cfg.agent.shac
        self.horizon = cfg.agent.num_steps_per_env
        self.rollout = DifferentiableRollout(env.env, self.horizon)
        self.actor, self.critic = build_networks(env, rsl_rl_cfg)
        self.target_critic = copy.deepcopy(self.critic).requires_grad_(False)
        self.actor_optimizer = torch.optim.Adam(self.actor.parameters(), lr=s.actor_learning_rate,
                                                betas=SHAC_ADAM_BETAS)
        self.critic_optimizer = torch.optim.Adam(self.critic.parameters(), lr=s.critic_learning_rate,
                                                 betas=SHAC_ADAM_BETAS)
        self.learning_rate = s.actor_learning_rate
        self.on_step = None
        """rsl-rl's console's per-step hook: a window has no env steps of its own to report."""
        self.q = self.qd = self.params = None
        n = env.num_envs
        self.episode_length = torch.zeros(n, dtype=torch.long, device=self.device)
        """Env steps each env's episode has run (the statistics' episode lengths)."""
        self.time_out_count = self.episode_length.clone()
        """Each env's time-out counter (the episode is truncated when it reaches the time limit; learn() may start it
        at random: ``init_at_random_ep_len``)."""
        self.episode_return = torch.zeros(n, device=self.device)
        self._end_iteration = 1

    def begin(self, first_iteration: int, end_iteration: int):
        self._end_iteration = end_iteration
        self.train_mode()

    def train_mode(self):
        self.actor.train()
        self.critic.train()

    def eval_mode(self):
        self.actor.eval()
        self.critic.eval()

    def member_actor(self, member: int = 0) -> torch.nn.Module:
        self.eval_mode()
        return self.actor

    def evaluation_policy(self) -> Policy:
        return deterministic(self.actor)

    def retire(self, member: int):
        """Nothing: the run ends with its one member."""

    def read(self, losses: dict) -> Readout:
        return Readout.of_one(self.episodes.pop(), self.learning_rate, self.action_std, losses)

    def release_graphs(self):
        """Nothing: the rollout's graphs belong to it and stay valid."""

    def _observations(self, obs: torch.Tensor) -> TensorDict:
        return TensorDict({"policy": obs}, batch_size=obs.shape[:1], device=obs.device)

    def _act(self, obs: torch.Tensor) -> torch.Tensor:
        actions = self.actor(self._observations(obs))
        if self.settings.action_noise_std > 0:
            actions = actions + self.settings.action_noise_std * torch.randn_like(actions)
        if actions.requires_grad:  # an env whose state ran away (NaN adjoints) must not cancel the others' update
            actions.register_hook(torch.nan_to_num)
        return actions

    def _starts(self, ended: torch.Tensor | None = None):
        """New episodes from the training env's reset draw where ``ended`` (every env at first): joint states and
        physics (randomized where the env randomizes at resets)."""
        base = self.env.env
        if ended is None:  # the time-out counters learn() set (init_at_random_ep_len), before the reset zeroes them
            self.time_out_count = self.env.episode_length_buf.to(self.device, torch.long).clone()
        base.reset()
        q, qd = base.joint_state()
        drawn = base.physical_params()
        params = {name: drawn[name].to(torch.float32) for name in self.rollout.parameter_names}
        if ended is None:
            self.q, self.qd, self.params = q, qd, params
            return
        self.q = torch.where(ended[:, None], q, self.q)
        self.qd = torch.where(ended[:, None], qd, self.qd)
        self.params = {name: torch.where(ended, value, self.params[name]) for name, value in params.items()}
        self.episode_length = torch.where(ended, 0, self.episode_length)
        self.time_out_count = torch.where(ended, 0, self.time_out_count)
        self.episode_return = torch.where(ended, 0.0, self.episode_return)

    def iteration(self, obs: TensorDict, it: int) -> tuple[TensorDict, dict]:
        if self.q is None:
            self._starts()
        self._set_learning_rates(it)
        self.clock.mark(0)
        window = self.rollout(self.q, self.qd, policy=self._act, params=self.params, episode_steps=self.time_out_count)
        terminated, ended = window.terminated, window.ended
        alive = (torch.cumsum(ended, 0) - ended.long()) == 0  # the steps that count: up to the episode's end
        self.clock.mark(1)
        actor_loss, next_values = self._actor_step(window, alive, ended, terminated)
        states = window.obs[:-1].detach()
        sound = alive & torch.isfinite(states).all(-1)  # not a diverged env's states
        seen = self._observations(states[sound])
        self.actor.update_normalization(seen)  # where the networks normalise their inputs (obs_normalization)
        self.critic.update_normalization(seen)
        critic_loss = self._critic_step(window, sound, ended, terminated, next_values)
        self.clock.mark(2)
        self._carry_on(window, alive)
        return obs, {"actor": actor_loss, "value_function": critic_loss}

    def _actor_step(self, window: Trajectory, alive, ended, terminated) -> tuple[float, torch.Tensor]:
        s = self.settings
        discount = s.gamma ** torch.arange(self.horizon, device=self.device, dtype=torch.float32)[:, None]
        next_values = self.target_critic(self._observations(window.obs[1:].flatten(0, 1))).view(self.horizon, -1)
        last = alive & (ended | (torch.arange(self.horizon, device=self.device)[:, None] == self.horizon - 1))
        rewards = torch.where(alive, window.rewards, 0.0)
        tails = torch.where(last & ~terminated, next_values, 0.0)
        objective = (discount * (rewards + s.gamma * tails)).sum(0).mean() / self.horizon
        self.actor_optimizer.zero_grad(set_to_none=True)
        (-objective).backward()
        norm = torch.nn.utils.clip_grad_norm_(self.actor.parameters(), s.max_grad_norm)
        if torch.isfinite(norm):
            self.actor_optimizer.step()
        return -objective.item(), next_values.detach()

    def _critic_step(self, window: Trajectory, sound, ended, terminated, next_values) -> float:
        """The critic fitted to the TD(lambda) targets of the ``sound`` steps (counted and finite), then the target
        critic moved towards it."""
        s = self.settings
        targets = window_targets(window.rewards.detach(), next_values, terminated, ended, s.gamma, s.lam)
        sound = sound & torch.isfinite(targets)
        targets, obs = targets[sound], window.obs[:-1].detach()[sound]
        batches = max(1, min(s.critic_mini_batches, len(obs)))
        total, steps = 0.0, 0
        for _ in range(s.critic_iterations):
            for batch in torch.randperm(len(obs), device=self.device).tensor_split(batches):
                loss = (self.critic(self._observations(obs[batch])).squeeze(-1) - targets[batch]).square().mean()
                self.critic_optimizer.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(self.critic.parameters(), s.max_grad_norm)
                self.critic_optimizer.step()
                total, steps = total + loss.detach(), steps + 1
        with torch.no_grad():
            for target, value in zip(self.target_critic.parameters(), self.critic.parameters()):
                target.lerp_(value, 1 - s.target_critic_alpha)
            for target, value in zip(self.target_critic.buffers(), self.critic.buffers()):
                target.copy_(value)  # the input normaliser's statistics (obs_normalization)
        return (total / steps).item()

    def _carry_on(self, window: Trajectory, alive):
        """Episode statistics of the window's ended episodes; states on to the next window, new starts where ended."""
        done = (window.ended & alive).any(0)
        self.episode_return += torch.where(alive, window.rewards.detach(), 0.0).sum(0)
        self.episode_length += alive.sum(0)
        self.time_out_count += alive.sum(0)
        timed_out = (window.truncated & alive).any(0)
        self.episodes.add(done, self.episode_return, self.episode_length, timed_out)
        self.q, self.qd = window.q[-1].detach(), window.qd[-1].detach()
        if done.any():
            self._starts(done)

    def _set_learning_rates(self, it: int):
        """The settings' rates at iteration ``it`` (a resumed optimizer keeps its saved ones otherwise), decayed where
        ``linear_decay``."""
        left = max(0.0, 1.0 - it / self._end_iteration) if self.settings.linear_decay else 1.0
        for optimizer, rate in ((self.actor_optimizer, self.settings.actor_learning_rate),
                                (self.critic_optimizer, self.settings.critic_learning_rate)):
            for group in optimizer.param_groups:
                group["lr"] = rate * left
        self.learning_rate = self.settings.actor_learning_rate * left

    @property
    def action_std(self) -> torch.Tensor:
        return torch.full((self.env.num_actions,), self.settings.action_noise_std, device=self.device)

    @property
    def episode_steps(self) -> torch.Tensor:
        return self.time_out_count[None]

    def state_dict(self, member: int = 0) -> dict:
        """The networks as rsl-rl's checkpoints hold them, and the learner's optimizers and target critic (under
        ``apg_state_dict``, the key of the checkpoints written before the learner's name was ``shac``)."""
        return {"actor_state_dict": self.actor.state_dict(), "critic_state_dict": self.critic.state_dict(),
                "apg_state_dict": {"actor_optimizer": self.actor_optimizer.state_dict(),
                                   "critic_optimizer": self.critic_optimizer.state_dict(),
                                   "target_critic": self.target_critic.state_dict()}}

    def load_state_dict(self, loaded: dict, load_cfg: dict | None, strict: bool, member: int = 0):
        """``state_dict``'s parts (``load_cfg``: rsl-rl's choice, e.g. ``{"actor": True}``; None: all). A checkpoint of
        another learner, or only some of its networks: the target critic is the critic loaded."""
        parts = load_cfg if load_cfg is not None else {"actor": True, "critic": True}
        if parts.get("actor"):
            self.actor.load_state_dict(loaded["actor_state_dict"], strict=strict)
        if parts.get("critic"):
            self.critic.load_state_dict(loaded["critic_state_dict"], strict=strict)
        state = loaded.get("apg_state_dict")
        if load_cfg is None and state is not None:
            self.actor_optimizer.load_state_dict(state["actor_optimizer"])
            self.critic_optimizer.load_state_dict(state["critic_optimizer"])
            self.target_critic.load_state_dict(state["target_critic"])
        else:
            self.target_critic.load_state_dict(self.critic.state_dict())


__getattr__ = renamed(__name__, {"ApgLearner": "ShacLearner", "check_apg": "check_shac",
                                 "ADAM_BETAS": "SHAC_ADAM_BETAS"})
"""The names of the learner once called apg, until ``settings.deprecation.REMOVED_IN``."""
