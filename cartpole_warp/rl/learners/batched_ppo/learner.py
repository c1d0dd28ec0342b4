"""The batched PPO learner: K members (``Member``: a seed and the PPO settings it differs in) trained as one
batched computation on one env of K x N envs, member k on block k (``BatchedPpoLearner``; the update is
``update.PopulationPPO``). A population (``train.py --seeds``, ``rl.population``) and SAPG's leader and followers
(``learners.sapg``) are both built on it."""

from __future__ import annotations

from ....wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import torch
from tensordict import TensorDict

from ....engine.streams import PhaseClock, TorchGraph
from ....evaluation.statistics import EpisodeStats, summary_of
from ....settings.deprecation import renamed
from ....wrappers.rsl_rl import RslRlVecEnv, mirror
from ...config import TrainConfig
from ...policies import build_networks
from .. import Readout
from .update import PPO_ADAM_BETAS, PPO_ADAM_EPS, BatchedActorCritic, PopulationPPO

VARIABLE_SETTINGS = PopulationPPO.SETTINGS
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
    """What keeps ``cfg`` from training on ``PopulationPPO`` (whose networks are rsl-rl's MLPs, the actor's after an
    image encoder where it sees camera frames, updated in float32 by rsl-rl's PPO), in words, each with whether
    ``cfg`` has it."""
    return {
        "agent.algorithm.use_mixed_precision": cfg.agent.algorithm.use_mixed_precision,
        "agent.torch_compile_mode": cfg.agent.torch_compile_mode is not None,
        "console rsl_rl (the batched rollout keeps no per-step log)": cfg.console == "rsl_rl",
    }


class BatchedPpoLearner:
    """The learner (``rl.learners.Learner``) of K members: their iterations on ``env`` (K x N envs, member k's block
    k), as one: each step the members' batched actors act on their blocks, one env step; then one update of every
    member not ``retire``d. On a GPU with
    ``cuda_graph`` the rollout and the update are each captured as a CUDA graph (the second iteration) and replayed.
    ``actors`` and ``critics`` are the members' rsl-rl networks, initialised as their solo runs' (``torch`` seeded with
    each member's seed; the action noise and mini-batches are drawn after ``torch`` is seeded with ``seed``, so that
    no member's draws depend on another's seed); ``member_actor`` copies the trained weights back into them where a
    member is saved or exported. ``ppo_class``: the batched update, built as ``PopulationPPO``."""

    def __init__(self, env: RslRlVecEnv, cfgs: list[TrainConfig], rsl_rl_cfg: dict, seed: int,
                 ppo_class: Callable[..., PopulationPPO] = PopulationPPO):
        self.env, self.device, self.num_members = env, env.device, len(cfgs)
        self.num_envs = env.num_envs // self.num_members
        """Envs per member."""
        self.num_steps_per_env = rsl_rl_cfg["num_steps_per_env"]
        self.episodes = EpisodeStats(env.device, env.max_episode_length, groups=self.num_members)
        self.clock = PhaseClock(self.device, phases=2)
        self.on_step = None
        """rsl-rl's console's per-step hook: none (``batched_ppo_problems``)."""
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

    def _observations(self, obs: TensorDict) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The members' state observations (K, N, O) and, where the actors see camera frames, those (K, N, C, H, W)
        (``RslRlVecEnv``'s groups: 'policy', with 'critic' the state where the policy sees frames)."""
        members, n = self.num_members, self.num_envs
        if not self.env.images:
            return obs["policy"].view(members, n, -1), None
        return obs["critic"].view(members, n, -1), obs["policy"].view(members, n, *obs["policy"].shape[1:])

    def _rollout(self, obs: TensorDict) -> TensorDict:
        members, n = self.num_members, self.num_envs
        for _ in range(self.num_steps_per_env):
            actions = self.ppo.act(*self._observations(obs))
            obs, rewards, dones, extras = self.env.step(actions.view(members * n, -1))
            time_outs = extras["time_outs"]
            self.ppo.process_env_step(rewards.view(members, n), dones.view(members, n), time_outs.view(members, n))
            self.episodes.add(dones.bool(), extras["episode_return"], extras["episode_length"], time_outs)
        self.ppo.compute_returns(self._observations(obs)[0])
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
                               [not row[8] for row in rows], [dict(zip(names, row[9:std])) for row in rows],
                               [torch.tensor(row[std:]) for row in rows])
        return self.readout

    @property
    def episode_steps(self) -> torch.Tensor:
        return self.env.episode_length_buf.view(self.num_members, self.num_envs)

    def begin(self, first_iteration: int, end_iteration: int):
        """Nothing to prepare: every member trains from the first iteration."""

    def retire(self, member: int):
        """``member`` is updated no more (its rollout goes on: the env steps as one)."""
        self.ppo.active[member] = False

    def evaluation_policy(self) -> Callable[[torch.Tensor], torch.Tensor]:
        """The members' means, all in one batched forward."""
        def policy(obs: torch.Tensor) -> torch.Tensor:
            members = self.num_members
            return self.ppo.model.action_mean(obs.view(members, obs.shape[0] // members, *obs.shape[1:])).flatten(0, 1)

        return policy

    def eval_mode(self):
        """Nothing: the batched networks act alike in training and evaluation."""

    def train_mode(self):
        for network in (*self.actors, *self.critics):
            network.train()

    @torch.no_grad()
    def member_actor(self, member: int = 0) -> torch.nn.Module:
        """Member ``member``'s trained weights copied into its rsl-rl networks, in eval mode: its actor."""
        actor_state, critic_state = self.ppo.model.member_state_dicts(member)
        self.actors[member].load_state_dict(actor_state)
        self.critics[member].load_state_dict(critic_state)
        self.actors[member].eval()
        self.critics[member].eval()
        return self.actors[member]

    def state_dict(self, member: int = 0) -> dict:
        """rsl-rl's checkpoint of ``member``: its networks and its Adam state in the format of the optimizer of
        ``SyncFreePPO`` (torch's ``Adam`` over the actor's then the critic's parameters), made without a torch
        optimizer (the first one made imports ``torch._dynamo``: seconds, in the middle of training); its run folder
        plays, resumes and exports as a solo run's."""
        actor, critic = self.member_actor(member), self.critics[member]
        ppo = self.ppo
        moments = [ppo.model.member_parameters(member, tensor) for tensor in (ppo.exp_avg, ppo.exp_avg_sq)]
        names = [(role, name) for role, network in (("actor", actor), ("critic", critic))
                 for name, _ in network.named_parameters()]
        step = ppo.adam_steps[member].to(torch.float32).cpu()
        state = {i: {"step": step.clone(), "exp_avg": moments[0][role][name].clone(),
                     "exp_avg_sq": moments[1][role][name].clone()} for i, (role, name) in enumerate(names)}
        group = {"lr": ppo.learning_rate[member].item(), "betas": PPO_ADAM_BETAS, "eps": PPO_ADAM_EPS,
                 "weight_decay": 0, "amsgrad": False, "maximize": False, "foreach": None, "capturable": False,
                 "differentiable": False, "fused": None, "decoupled_weight_decay": False,
                 "params": list(range(len(names)))}
        self.train_mode()
        return {"actor_state_dict": actor.state_dict(), "critic_state_dict": critic.state_dict(),
                "optimizer_state_dict": {"state": state, "param_groups": [group]}}

    @torch.no_grad()
    def load_state_dict(self, loaded: dict, load_cfg: dict | None, strict: bool, member: int = 0):
        """The networks of ``loaded`` that ``load_cfg`` names (rsl-rl's choice of parts; None: both) into
        ``member``'s (the best policy loaded for its exports; a population starts afresh, without its optimiser).
        Always strict: the batched layout takes whole state dicts (KeyError naming the keys that differ)."""
        parts = load_cfg if load_cfg is not None else {"actor": True, "critic": True}
        actor_state, critic_state = self.ppo.model.member_state_dicts(member)
        self.ppo.model.load_member_state_dicts(
            member, loaded["actor_state_dict"] if parts.get("actor") else actor_state,
            loaded["critic_state_dict"] if parts.get("critic") else critic_state)

    def exploit(self, source: int, target: int):
        """Population-based training's exploit: member ``source``'s networks, Adam state, normalisers and settings over
        member ``target``'s (``PopulationPPO.copy_member``); the others' untouched."""
        self.ppo.copy_member(source, target)

    def member_settings(self, member: int) -> dict[str, float]:
        """The ``VARIABLE_SETTINGS`` ``member`` trains with now (its learning rate as adapted)."""
        return {name: getattr(self.ppo, name)[member].item() for name in VARIABLE_SETTINGS}

    @torch.no_grad()
    def set_member_settings(self, member: int, settings: dict[str, float]):
        """Set some of ``member``'s ``VARIABLE_SETTINGS`` (in place: a captured update reads them next time)."""
        for name, value in settings.items():
            getattr(self.ppo, name)[member] = value

    def release_graphs(self):
        for graph in self._graphs or ():
            graph.release()


__getattr__ = renamed(__name__, {"PopulationLearner": "BatchedPpoLearner"})
"""The learner's name before it was named for what it runs (a population and SAPG's blocks both run on it), until
``settings.deprecation.REMOVED_IN``."""
