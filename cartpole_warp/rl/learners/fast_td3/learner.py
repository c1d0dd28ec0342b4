"""``FastTd3Learner``: off-policy TD3 for many parallel envs (``agent.learner: fasttd3``, settings ``agent.fasttd3``),
after FastTD3 (Seo et al. 2025).

    python train.py --task cartpole-swingup --learner fasttd3 --device cuda

Each iteration every env acts ``num_steps_per_env`` steps with the deterministic actor plus Gaussian noise of a std
of its own (drawn from U(std_min, std_max) at each episode's start: mixed exploration across envs), every transition
into the replay on the device (``update.Replay``), the observation normaliser updated with the iteration's states;
then ``num_updates`` gradient steps per env step of the distributional twin critic on batches drawn from the replay
(``update.critic_loss``: clipped double Q, target policy smoothing, time-outs bootstrapped, terminations not) and of
the actor every ``policy_frequency``-th (``update.actor_loss``), the target critic following each (``tau``). FastTD3
interleaves its updates with the env steps; here they follow the iteration's steps (the same number per step). Where
the task has a mirror, each batch is followed by its mirror image. On a GPU with ``cuda_graph`` the rollout and the
updates are each captured as a CUDA graph (the second iteration) and replayed. Not FastTD3's: no bf16, no n-step
returns, constant learning rates.

The actor is rsl-rl's ``MLPModel`` with a ``SquashedGaussian`` (its deterministic output tanh(mean)), so its
checkpoints play, evaluate and export as PPO's; the critics and their target are the learner's own.
"""

from __future__ import annotations

from ....wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
import copy

import torch
from tensordict import TensorDict

from ....engine.streams import PhaseClock, TorchGraph
from ....evaluation.rollouts import Policy
from ....evaluation.statistics import EpisodeStats
from ....settings.config import ConfigError, EnvConfig, refuse_present
from ....wrappers.rsl_rl import RslRlVecEnv
from ...config import TrainConfig
from ...distributed import Ranks
from ...policies import build_networks, deterministic, update_normalization
from .. import Readout
from .update import Replay, TwinDistributionalCritic, actor_loss, critic_loss, soft_update


def check_fasttd3(cfg: TrainConfig):
    """ConfigError, before anything is built, where ``--learner fasttd3`` cannot train ``cfg`` as asked."""
    s = cfg.agent.fasttd3
    problems = {
        "a task that observes camera frames (the critics are MLPs on the state)": cfg.env.camera.enabled,
        "agent.torch_compile_mode (the learner steps the networks itself)": cfg.agent.torch_compile_mode is not None,
        f"agent.fasttd3.v_min {s.v_min:g} >= v_max {s.v_max:g}": s.v_min >= s.v_max,
        f"agent.fasttd3.std_min {s.std_min:g} > std_max {s.std_max:g}": s.std_min > s.std_max,
    }
    refuse_present(f"--learner fasttd3 cannot train {cfg.task}", problems)


class FastTd3Learner:
    """FastTD3's iterations (module docstring) on ``env`` (``rl.learners.Learner``, of one member)."""

    num_members = 1

    @staticmethod
    def env_config(cfg: TrainConfig, env_cfg: EnvConfig, ranks: Ranks) -> EnvConfig:
        """``env_cfg`` as it is; ConfigError where the learner cannot train ``cfg`` (``check_fasttd3``) or under
        torchrun."""
        check_fasttd3(cfg)
        if ranks.distributed:
            raise ConfigError("--learner fasttd3 trains in one process (not under torchrun)")
        return env_cfg

    def __init__(self, env: RslRlVecEnv, cfg: TrainConfig, rsl_rl_cfg: dict, episodes: EpisodeStats):
        check_fasttd3(cfg)
        self.env, self.episodes, self.device = env, episodes, env.device
        self.settings = s = cfg.agent.fasttd3
        self.clock = PhaseClock(self.device, phases=2)
        self.num_steps_per_env, n = cfg.agent.num_steps_per_env, env.num_envs
        self.actor, _ = build_networks(env, rsl_rl_cfg, critic=False)
        torch.nn.init.normal_(self.actor.mlp[-1].weight, 0.0, s.init_scale)
        torch.nn.init.zeros_(self.actor.mlp[-1].bias)
        num_obs = self.actor.obs_dim
        self.critic = TwinDistributionalCritic(num_obs, env.num_actions, s.critic_hidden_dims, s.num_atoms, s.v_min,
                                               s.v_max).to(self.device)
        self.target_critic = copy.deepcopy(self.critic).requires_grad_(False)
        graphed = cfg.agent.cuda_graph and torch.device(self.device).type == "cuda"
        self.capturable = graphed
        """The optimizers step inside captured graphs (torch's ``capturable`` Adam: its step counts on the device)."""
        self.actor_parameters = [p for name, p in self.actor.named_parameters() if name.startswith("mlp.")]
        self.actor_optimizer, self.critic_optimizer = (
            torch.optim.AdamW(parameters, lr=lr, weight_decay=s.weight_decay, capturable=graphed)
            for parameters, lr in ((self.actor_parameters, s.actor_learning_rate),
                                   (list(self.critic.parameters()), s.critic_learning_rate)))
        self.replay = Replay(s.replay_steps, n, num_obs, env.num_actions, self.device)
        self.noise_std = torch.empty(n, 1, device=self.device).uniform_(s.std_min, s.std_max)
        """(N, 1) each env's exploration noise std, drawn again when its episode ends."""
        self.rollout_obs = torch.zeros(self.num_steps_per_env, n, num_obs, device=self.device)
        """The iteration's states, for the observation normaliser."""
        self.mirror = (env.obs_mirror, env.action_mirror) if s.symmetry and env.obs_mirror is not None else None
        self.losses = torch.zeros(2, device=self.device)
        """The iteration's summed critic and actor losses."""
        self._graphs = (TorchGraph(self.device), TorchGraph(self.device)) if graphed else None
        self.on_step = None
        """Called with each step's rewards, dones and extras where set (rsl-rl's console); then nothing is captured."""

    def policy_of(self, normalized_obs: torch.Tensor) -> torch.Tensor:
        """The deterministic actor's actions, tanh(mean), of normalised observations."""
        return torch.tanh(self.actor.mlp(normalized_obs))

    def begin(self, first_iteration: int, end_iteration: int):
        self.train_mode()

    def iteration(self, obs: TensorDict, it: int) -> tuple[TensorDict, dict]:
        """The iteration's steps into the replay, the normaliser, then the gradient steps (module docstring)."""
        graphs = self._graphs if self.on_step is None else None
        self.clock.mark(0)
        with torch.no_grad():
            obs = self._rollout(obs) if graphs is None else graphs[0].with_inputs(obs, self._rollout)
        update_normalization([self.actor], TensorDict({"policy": self.rollout_obs.flatten(0, 1)},
                                                      batch_size=[self.rollout_obs.shape[0] * self.env.num_envs]))
        self.clock.mark(1)
        self.losses.zero_()
        if graphs is None:
            self._updates()
        else:
            graphs[1](self._updates)
        self.clock.mark(2)
        steps = self.num_steps_per_env * self.settings.num_updates
        return obs, {"critic": self.losses[0] / steps,
                     "actor": self.losses[1] / max(1, steps // self.settings.policy_frequency)}

    def _rollout(self, obs: TensorDict) -> TensorDict:
        s, normalizer = self.settings, self.actor.obs_normalizer
        for step in range(self.num_steps_per_env):
            state = obs["policy"]
            self.rollout_obs[step] = state
            noise = torch.randn(state.shape[0], self.env.num_actions, device=self.device) * self.noise_std
            actions = (self.policy_of(normalizer(state)) + noise).clamp(-1.0, 1.0)
            obs, rewards, dones, extras = self.env.step(actions)
            ended, time_outs = dones.bool(), extras["time_outs"]
            discounts = torch.where(ended & ~time_outs, 0.0, s.gamma)
            next_state = torch.where(ended[:, None], extras["final_obs"], obs["policy"])
            self.replay.add(state, actions, rewards, discounts, next_state)
            redrawn = torch.empty_like(self.noise_std).uniform_(s.std_min, s.std_max)
            self.noise_std.copy_(torch.where(ended[:, None], redrawn, self.noise_std))
            self.episodes.add(ended, extras["episode_return"], extras["episode_length"], time_outs)
            if self.on_step is not None:
                self.on_step(rewards, dones, extras)
        return obs

    def _updates(self):
        """The iteration's gradient steps; losses summed into ``losses``. Device work only (captured on a GPU)."""
        s = self.settings
        for i in range(self.num_steps_per_env * s.num_updates):
            obs, actions, rewards, discounts, next_obs = self._batch()
            with torch.no_grad():
                smoothing = (torch.randn_like(actions) * s.policy_noise).clamp(-s.noise_clip, s.noise_clip)
                next_actions = (self.policy_of(next_obs) + smoothing).clamp(-1.0, 1.0)
            loss = critic_loss(self.critic, self.target_critic, obs, actions, rewards, discounts, next_obs,
                               next_actions)
            self._step(loss, list(self.critic.parameters()), self.critic_optimizer)
            self.losses[0] += loss.detach()
            if (i + 1) % s.policy_frequency == 0:
                loss = actor_loss(self.critic, obs, self.policy_of(obs))
                self._step(loss, self.actor_parameters, self.actor_optimizer)
                self.losses[1] += loss.detach()
            soft_update(self.target_critic, self.critic, s.tau)

    def _batch(self) -> tuple[torch.Tensor, ...]:
        """A batch from the replay, followed by its mirror image where the task has one; states normalised."""
        obs, actions, rewards, discounts, next_obs = self.replay.sample(self.settings.batch_size)
        if self.mirror is not None:
            obs_signs, action_signs = self.mirror
            obs, next_obs = (torch.cat([x, x * obs_signs]) for x in (obs, next_obs))
            actions = torch.cat([actions, actions * action_signs])
            rewards, discounts = rewards.repeat(2), discounts.repeat(2)
        normalizer = self.actor.obs_normalizer
        return normalizer(obs), actions, rewards, discounts, normalizer(next_obs)

    def _step(self, loss: torch.Tensor, parameters: list[torch.Tensor], optimizer: torch.optim.Optimizer):
        """One gradient step of ``parameters`` (only theirs: the actor's loss passes through the critics)."""
        for parameter, gradient in zip(parameters, torch.autograd.grad(loss, parameters), strict=True):
            parameter.grad = gradient
        if self.settings.max_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(parameters, self.settings.max_grad_norm)
        optimizer.step()

    def read(self, losses: dict) -> Readout:
        figures = torch.stack([*losses.values(), self.noise_std.mean()]).tolist()
        return Readout.of_one(self.episodes.pop(), self.settings.actor_learning_rate,
                              torch.full((self.env.num_actions,), figures[-1]), dict(zip(losses, figures)))

    @property
    def episode_steps(self) -> torch.Tensor:
        return self.env.episode_length_buf[None]

    def retire(self, member: int):
        """Nothing: the run ends with its one member."""

    def member_actor(self, member: int = 0) -> torch.nn.Module:
        return self.actor.eval()

    def evaluation_policy(self) -> Policy:
        return deterministic(self.actor)

    def train_mode(self):
        self.actor.train()

    def eval_mode(self):
        self.actor.eval()

    def state_dict(self, member: int = 0) -> dict:
        """The actor (rsl-rl's format: it plays and exports as PPO's), the critics, their target and both AdamW
        states; the replay is not kept (a resumed run fills it again)."""
        return {"actor_state_dict": self.actor.state_dict(), "critic_state_dict": self.critic.state_dict(),
                "target_critic_state_dict": self.target_critic.state_dict(),
                "optimizer_state_dict": {"actor": self.actor_optimizer.state_dict(),
                                         "critic": self.critic_optimizer.state_dict()}}

    def load_state_dict(self, loaded: dict, load_cfg: dict | None, strict: bool, member: int = 0):
        """The parts of ``loaded`` that ``load_cfg`` names ('actor', 'critic': with its target and the optimizers;
        None: all) into the networks."""
        parts = load_cfg if load_cfg is not None else {"actor": True, "critic": True}
        if parts.get("actor"):
            self.actor.load_state_dict(loaded["actor_state_dict"], strict=strict)
        if parts.get("critic") and "critic_state_dict" in loaded:
            self.critic.load_state_dict(loaded["critic_state_dict"], strict=strict)
            self.target_critic.load_state_dict(loaded["target_critic_state_dict"], strict=strict)
            for optimizer, part in ((self.actor_optimizer, "actor"), (self.critic_optimizer, "critic")):
                optimizer.load_state_dict(loaded["optimizer_state_dict"][part])
                self._fit_optimizer(optimizer)

    def _fit_optimizer(self, optimizer: torch.optim.Optimizer):
        """A loaded optimizer made to step as this learner's do (``capturable`` or not, its step counts where that
        needs them: a checkpoint of a run on another device keeps its own)."""
        for group in optimizer.param_groups:
            group["capturable"] = self.capturable
            for parameter in group["params"]:
                state = optimizer.state.get(parameter, {})
                if "step" in state:
                    where = parameter.device if self.capturable else "cpu"
                    state["step"] = state["step"].to(where, torch.float32)

    def release_graphs(self):
        for graph in self._graphs or ():
            graph.release()
