"""The batched PPO learner: K members (``Member``: a seed and the PPO settings it differs in) trained as one
batched computation on one env of K x N envs, member k on block k (``PopulationLearner``; the update is
``update.PopulationPPO``). A population (``train.py --seeds``, ``rl.population``) and SAPG's leader and followers
(``learners.sapg``) are both built on it; ``MemberLearner`` is member k as one run's learner."""

from __future__ import annotations

from ....wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import torch
from tensordict import TensorDict

from ....engine.streams import PhaseClock, TorchGraph
from ....evaluation.statistics import EpisodeStats, EpisodeSummary, summary_of
from ....wrappers.rsl_rl import RslRlVecEnv, mirror
from ...config import TrainConfig
from ...policies import build_networks
from .update import PPO_ADAM_BETAS, PPO_ADAM_EPS, BatchedActorCritic, PopulationPPO

VARIABLE_SETTINGS = ("learning_rate", "entropy_coef", "gamma", "lam", "clip_param", "desired_kl", "value_loss_coef",
                     "max_grad_norm")
"""PPO's settings (``agent.algorithm``) members may differ in: they keep the networks' shapes and the env."""


@dataclass(frozen=True)
class Member:
    """One training of a population: its seed (``env.seed``: envs, physics draws, network initialisation) and the
    ``agent.algorithm`` settings it differs in (name, value)."""

    seed: int
    settings: tuple[tuple[str, float], ...] = ()

    @property
    def name(self) -> str:
        """Its run folder's name, e.g. ``seed3`` or ``learning_rate=0.0003-seed3``."""
        return "-".join([f"{name}={value:g}" for name, value in self.settings] + [f"seed{self.seed}"])

    def config(self, cfg: TrainConfig) -> TrainConfig:
        """``cfg`` with this member's seed and settings (validated)."""
        algorithm = dataclasses.replace(cfg.agent.algorithm, **dict(self.settings))
        return dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, seed=self.seed),
                                   agent=dataclasses.replace(cfg.agent, algorithm=algorithm)).validate()


def batched_ppo_problems(cfg: TrainConfig) -> dict[str, bool]:
    """What keeps ``cfg`` from training on ``PopulationPPO`` (whose networks are rsl-rl's MLPs on the task's state,
    updated in float32 by rsl-rl's PPO), in words, each with whether ``cfg`` has it."""
    return {
        "a task that observes camera frames (the batched networks are MLPs)": cfg.env.camera.enabled,
        "agent.algorithm.use_mixed_precision": cfg.agent.algorithm.use_mixed_precision,
        "agent.torch_compile_mode": cfg.agent.torch_compile_mode is not None,
        "console rsl_rl (the batched rollout keeps no per-step log)": cfg.console == "rsl_rl",
    }


@dataclass
class Readout:
    """Each member's figures after an iteration, on the host (``PopulationLearner.read``)."""

    episodes: list[EpisodeSummary]
    learning_rates: list[float]
    finite: list[bool]
    """The member's networks hold finite numbers only."""
    losses: list[dict[str, float]]
    action_std: list[torch.Tensor]


class MemberEpisodes:
    """Member k's training episodes of the iteration just read (``Readout``), as its runner pops them."""

    def __init__(self, population: PopulationLearner, k: int):
        self.population, self.k = population, k

    def summary(self) -> EpisodeSummary:
        return self.population.readout.episodes[self.k]

    def pop(self, all_processes: bool = False) -> EpisodeSummary:
        return self.summary()


class PopulationLearner:
    """The members' iterations on ``env`` (K x N envs, member k's block k), as one: each step the members' batched
    actors act on their blocks, one env step; then one update of every member still ``active``. On a GPU with
    ``cuda_graph`` the rollout and the update are each captured as a CUDA graph (the second iteration) and replayed.
    ``actors`` and ``critics`` are the members' rsl-rl networks, initialised as their solo runs' (``torch`` seeded with
    each member's seed; the action noise and mini-batches are drawn after ``torch`` is seeded with ``seed``, so that
    no member's draws depend on another's seed); ``MemberLearner`` copies the trained weights back into them where a
    member is judged, saved or exported. ``ppo_class``: the batched update, built as ``PopulationPPO``."""

    def __init__(self, env: RslRlVecEnv, cfgs: list[TrainConfig], rsl_rl_cfg: dict, seed: int,
                 ppo_class: Callable[..., PopulationPPO] = PopulationPPO):
        self.env, self.device, self.num_members = env, env.device, len(cfgs)
        self.num_envs = env.num_envs // self.num_members
        """Envs per member."""
        self.num_steps_per_env = rsl_rl_cfg["num_steps_per_env"]
        self.episodes = EpisodeStats(env.device, env.max_episode_length, groups=self.num_members)
        self.clock = PhaseClock(self.device, phases=2)
        self.actors, self.critics = [], []
        for cfg in cfgs:
            torch.manual_seed(cfg.env.seed)
            actor, critic = build_networks(env, rsl_rl_cfg)
            self.actors.append(actor)
            self.critics.append(critic)
        torch.manual_seed(seed)  # the population's own draws (action noise, mini-batches): no member's seed alone
        settings = {name: [getattr(cfg.agent.algorithm, name) for cfg in cfgs] for name in VARIABLE_SETTINGS}
        algorithm = cfgs[0].agent.algorithm
        mirrored = algorithm.symmetry and env.obs_mirror is not None
        self.ppo = ppo_class(
            BatchedActorCritic.from_members(self.actors, self.critics), self.num_envs, self.num_steps_per_env,
            num_learning_epochs=algorithm.num_learning_epochs, num_mini_batches=algorithm.num_mini_batches,
            use_clipped_value_loss=algorithm.use_clipped_value_loss, schedule=algorithm.schedule,
            mirror=self._mirror if mirrored else None, **settings)
        graphed = cfgs[0].agent.cuda_graph and torch.device(self.device).type == "cuda"
        self._graphs = (TorchGraph(self.device), TorchGraph(self.device)) if graphed else None
        self.readout: Readout | None = None
        """The latest iteration's figures (``read``)."""

    def _mirror(self, obs: torch.Tensor, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The task's mirror images after the originals: ``wrappers.rsl_rl.mirror`` (rsl-rl's augmentation), on flat
        tensors."""
        mirrored, actions = mirror(self.env, TensorDict({"policy": obs}, batch_size=obs.shape[:1]), actions)
        return mirrored["policy"], actions

    def iteration(self, obs: TensorDict, it: int) -> tuple[TensorDict, dict[str, torch.Tensor]]:
        """One iteration of every member: the last observations and the (K,) losses out."""
        self.clock.mark(0)
        with torch.inference_mode():
            obs = self._rollout(obs) if self._graphs is None else self._graphs[0].with_inputs(obs, self._rollout)
        self.clock.mark(1)
        losses = self.ppo.update() if self._graphs is None else self._graphs[1](self.ppo.update)
        self.clock.mark(2)
        return obs, losses

    def _rollout(self, obs: TensorDict) -> TensorDict:
        members, n = self.num_members, self.num_envs
        for _ in range(self.num_steps_per_env):
            actions = self.ppo.act(obs["policy"].view(members, n, -1))
            obs, rewards, dones, extras = self.env.step(actions.view(members * n, -1))
            time_outs = extras["time_outs"]
            self.ppo.process_env_step(rewards.view(members, n), dones.view(members, n), time_outs.view(members, n))
            self.episodes.add(dones.bool(), extras["episode_return"], extras["episode_length"], time_outs)
        self.ppo.compute_returns(obs["policy"].view(members, n, -1))
        return obs

    def read(self, losses: dict[str, torch.Tensor]) -> Readout:
        """The iteration's per-member figures on the host, in one read from the device; the episode sums start
        afresh."""
        ppo = self.ppo
        columns = [self.episodes.take(), ppo.learning_rate[:, None], torch.isfinite(ppo.model.params).all(1)[:, None],
                   torch.stack(list(losses.values()), dim=1), ppo.model.action_std()]
        rows = torch.cat([column.to(torch.float64) for column in columns], dim=1).tolist()
        names, std = list(losses), 9 + len(losses)
        self.readout = Readout([summary_of(row[:7]) for row in rows], [row[7] for row in rows],
                               [bool(row[8]) for row in rows], [dict(zip(names, row[9:std])) for row in rows],
                               [torch.tensor(row[std:]) for row in rows])
        return self.readout

    def release_graphs(self):
        for graph in self._graphs or ():
            graph.release()


class MemberEnv:
    """Envs [k N, (k+1) N) of a population's ``RslRlVecEnv`` as member k's runner sees them (no stepping: the
    population steps the whole env)."""

    def __init__(self, env: RslRlVecEnv, k: int, num_envs: int):
        self.env, self.num_envs, self.block = env, num_envs, slice(k * num_envs, (k + 1) * num_envs)
        self.num_actions, self.max_episode_length, self.device = env.num_actions, env.max_episode_length, env.device
        self.cfg, self.images, self.evaluation = env.cfg, env.images, None
        self.obs_mirror, self.action_mirror = env.obs_mirror, env.action_mirror

    @property
    def episode_length_buf(self) -> torch.Tensor:
        return self.env.episode_length_buf[self.block]

    @episode_length_buf.setter
    def episode_length_buf(self, value: torch.Tensor):
        self.env.episode_length_buf[self.block] = value

    def get_observations(self) -> TensorDict:
        return self.env.get_observations()[self.block]


class MemberLearner:
    """Member k of a ``PopulationLearner`` as a ``Learner`` for its own ``TaskRunner``: its episode statistics, its
    learning rate and action noise, its rsl-rl actor (the population's weights copied in by ``eval_mode``), and its
    checkpoint state in rsl-rl's format (networks and a torch ``Adam`` state of its moments), so that its run folder
    plays, resumes and exports as a solo run's. The population runs its iterations."""

    def __init__(self, population: PopulationLearner, k: int):
        self.population, self.k = population, k
        self.env = MemberEnv(population.env, k, population.num_envs)
        self.episodes, self.clock = MemberEpisodes(population, k), population.clock
        self.actor, self.critic = population.actors[k], population.critics[k]
        self.on_step = None

    @property
    def learning_rate(self) -> float:
        return self.population.readout.learning_rates[self.k]

    @property
    def action_std(self) -> torch.Tensor:
        return self.population.readout.action_std[self.k]

    @property
    def episode_steps(self) -> torch.Tensor:
        return self.env.episode_length_buf

    def begin(self, first_iteration: int, end_iteration: int):
        """Nothing: the population's iterations are the member's."""

    def iteration(self, obs: TensorDict, it: int):
        raise RuntimeError("a member's iterations are its population's (PopulationLearner.iteration)")

    def train_mode(self):
        self.actor.train()
        self.critic.train()

    @torch.no_grad()
    def eval_mode(self):
        """The member's trained weights into its rsl-rl networks, in eval mode."""
        actor_state, critic_state = self.population.ppo.model.member_state_dicts(self.k)
        self.actor.load_state_dict(actor_state)
        self.critic.load_state_dict(critic_state)
        self.actor.eval()
        self.critic.eval()

    def state_dict(self) -> dict:
        """rsl-rl's checkpoint of the member: its networks and its Adam state in the format of the optimizer of
        ``SyncFreePPO`` (torch's ``Adam`` over the actor's then the critic's parameters), made without a torch
        optimizer (the first one made imports ``torch._dynamo``: seconds, in the middle of training)."""
        self.eval_mode()
        ppo, k = self.population.ppo, self.k
        moments = [ppo.model.member_parameters(k, tensor) for tensor in (ppo.exp_avg, ppo.exp_avg_sq)]
        names = [(role, name) for role, network in (("actor", self.actor), ("critic", self.critic))
                 for name, _ in network.named_parameters()]
        step = ppo.adam_steps[k].to(torch.float32).cpu()
        state = {i: {"step": step.clone(), "exp_avg": moments[0][role][name].clone(),
                     "exp_avg_sq": moments[1][role][name].clone()} for i, (role, name) in enumerate(names)}
        group = {"lr": ppo.learning_rate[k].item(), "betas": PPO_ADAM_BETAS, "eps": PPO_ADAM_EPS, "weight_decay": 0,
                 "amsgrad": False, "maximize": False, "foreach": None, "capturable": False, "differentiable": False,
                 "fused": None, "decoupled_weight_decay": False, "params": list(range(len(names)))}
        self.train_mode()
        return {"actor_state_dict": self.actor.state_dict(), "critic_state_dict": self.critic.state_dict(),
                "optimizer_state_dict": {"state": state, "param_groups": [group]}}

    def load_state_dict(self, loaded: dict, load_cfg: dict | None, strict: bool):
        """The networks of ``loaded`` (``load_cfg``: rsl-rl's choice of parts) into the member's rsl-rl networks;
        the population's weights are not changed (a population starts afresh)."""
        parts = load_cfg if load_cfg is not None else {"actor": True, "critic": True}
        if parts.get("actor"):
            self.actor.load_state_dict(loaded["actor_state_dict"], strict=strict)
        if parts.get("critic"):
            self.critic.load_state_dict(loaded["critic_state_dict"], strict=strict)

    def release_graphs(self):
        """Nothing: the graphs are the population's."""
