"""``PopulationPPO``: K independent rsl-rl PPO learners ("members") trained as one batched computation.

Each member has its own actor, critic, observation normalisers, Gaussian std, Adam moments and step count, learning
rate (with rsl-rl's adaptive-KL rule), gradient-norm clip, mini-batch permutation and scalar PPO settings
(``learning_rate``, ``entropy_coef``, ``gamma``, ``lam``, ``clip_param``, ``desired_kl``, ``value_loss_coef``,
``max_grad_norm``: (K,) tensors); shapes (networks, N envs, T steps, epochs, mini-batches) are shared. The K networks
are one flat (K, P) parameter tensor whose layers run as batched products (``BatchedLinear``), so acting and each
mini-batch step are a fixed number of kernel launches whatever K is, with no host sync (``update`` can be captured as
a CUDA graph).

Every member follows rsl-rl's ``PPO`` as ``SyncFreePPO`` (``learners.ppo``) runs it: GAE with time-out bootstrapping,
advantages normalised over the rollout, the same mini-batches for every epoch, clipped surrogate and value losses,
actor and critic gradient norms clipped separately, Adam, normalisers updated after the gradient steps, symmetry as
data augmentation. ``tests/test_population_ppo.py`` checks each member against rsl-rl's own ``PPO``.
"""

from __future__ import annotations

from ....wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
import math
from collections.abc import Callable, Sequence

import torch
from rsl_rl.models import MLPModel
from rsl_rl.modules.distribution import GaussianDistribution, HeteroscedasticGaussianDistribution
from torch import nn

from ....settings.deprecation import renamed
from ...image_model import ImageModel
from ...policies import gaussian_sample
from ..ppo_rules import adaptive_kl_rate, clipped_surrogate, value_error
from .encoder import encode_members, encoder_layers

Mirror = Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]
"""Symmetry augmentation of flat batches: (obs (B, O), actions (B, A)) -> (obs (C*B, O), actions (C*B, A)), the
originals first, then C-1 mirrored copies (rsl-rl's ``data_augmentation_func`` convention, without ``env``)."""

PPO_ADAM_BETAS, PPO_ADAM_EPS = (0.9, 0.999), 1e-8
"""torch.optim.Adam's defaults, which rsl-rl's PPO uses."""


SPLIT_K_ROWS = 512
"""Rows of a batch per partial product of a batched linear layer's weight gradient (``BatchedLinear``)."""


class BatchedLinear(torch.autograd.Function):
    """K linear layers at once, ``bias + x @ weight`` for x (K, B, in), weight (K, in, out), bias (K, 1, out), whose
    weight gradient x^T @ grad sums over the B rows in partial products of ``SPLIT_K_ROWS`` rows each: as one batched
    product per member (what ``torch.baddbmm``'s backward does) a GPU computes each member's small (in, out) output
    on a single tile, a reduction over B that leaves all but K of its multiprocessors idle."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(x, weight)
        return torch.baddbmm(bias, x, weight)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        x, weight = ctx.saved_tensors
        members, rows, n_in = x.shape
        parts = math.gcd(rows, max(1, rows // SPLIT_K_ROWS))
        grad_x = torch.bmm(grad, weight.transpose(1, 2)) if ctx.needs_input_grad[0] else None
        grad_weight = torch.bmm(x.reshape(members * parts, rows // parts, n_in).transpose(1, 2),
                                grad.reshape(members * parts, rows // parts, -1))
        return grad_x, grad_weight.view(members, parts, n_in, -1).sum(dim=1), grad.sum(dim=1, keepdim=True)


class BatchedNormalizer(nn.Module):
    """K of rsl-rl's ``EmpiricalNormalization``: running mean, variance and std of observations, per member."""

    def __init__(self, num_members: int, num_obs: int, eps: float):
        super().__init__()
        self.eps = eps
        self.register_buffer("mean", torch.zeros(num_members, 1, num_obs))
        self.register_buffer("var", torch.ones(num_members, 1, num_obs))
        self.register_buffer("std", torch.ones(num_members, 1, num_obs))
        self.register_buffer("count", torch.zeros(num_members, dtype=torch.long))

    def forward(self, obs: torch.Tensor, members: torch.Tensor | None = None) -> torch.Tensor:
        """(K, B, O) observations normalised with each member's statistics (``members``: of those K members)."""
        if members is None:
            return (obs - self.mean) / (self.std + self.eps)
        return (obs - self.mean[members]) / (self.std[members] + self.eps)

    @torch.no_grad()
    def update(self, obs: torch.Tensor, active: torch.Tensor):
        """Fold (K, B, O) observations into the statistics of the ``active`` (K,) members, in place."""
        batch_mean = obs.mean(dim=1, keepdim=True)
        batch_var = obs.var(dim=1, unbiased=False, keepdim=True)
        self.count += obs.shape[1] * active
        rate = torch.where(active, obs.shape[1] / self.count, 0.0)[:, None, None]
        delta_mean = batch_mean - self.mean
        self.mean += rate * delta_mean
        self.var += rate * (batch_var - self.var + delta_mean * (batch_mean - self.mean))
        self.std.copy_(torch.where(active[:, None, None], self.var.sqrt(), self.std))


def check_templates(actor: MLPModel, critic: MLPModel):
    """ValueError unless ``actor`` is an rsl-rl ``MLPModel`` or an ``ImageModel`` with a state-independent Gaussian and
    ``critic`` an ``MLPModel`` with no distribution (what ``BatchedActorCritic`` batches)."""
    if type(actor) not in (MLPModel, ImageModel):
        raise ValueError(f"the actor must be an rsl-rl MLPModel or an ImageModel, not {type(actor).__name__}")
    if type(critic) is not MLPModel:
        raise ValueError(f"the critic must be an rsl-rl MLPModel, not {type(critic).__name__}")
    distribution = actor.distribution
    if not isinstance(distribution, GaussianDistribution) or isinstance(
            distribution, HeteroscedasticGaussianDistribution) or critic.distribution is not None:
        raise ValueError("the actor needs a GaussianDistribution (state-independent std), the critic none")


class BatchedActorCritic(nn.Module):
    """K rsl-rl ``MLPModel`` actors (Gaussian, state-independent std) and critics as one module; the actors may be
    ``ImageModel``s that see camera frames alone (``encoder.encode_members``), the critics then seeing the task's state.

    All parameters live in ``params`` (K, P): per member, the actor's encoder (kernels as (out, in, kh, kw), biases),
    its layers (weight as (in, out), bias), its std parameter, then the critic's layers; the first
    ``num_actor_params`` columns are the actor's. Built from rsl-rl models (``from_members``) and read back in
    rsl-rl's ``state_dict`` format (``member_state_dicts``).
    """

    def __init__(self, actor: MLPModel, critic: MLPModel, num_members: int):
        """Zero-initialised networks of ``num_members`` members laid out as the template ``actor`` and ``critic``."""
        super().__init__()
        check_templates(actor, critic)
        distribution = actor.distribution
        self.num_members, self.num_obs, self.num_actions = num_members, critic.obs_dim, distribution.output_dim
        """``num_obs``: the width of the state observations, the critic's (and the actor's, unless it sees images)."""
        self.activation = actor.mlp[1]
        """The hidden layers' activation (rsl-rl's MLP shares one module between its layers)."""
        self.image_shape: tuple[int, int, int] | None = None
        """(C, H, W) of the images an image actor sees (None: the actor sees the state)."""
        self._convs = []
        if isinstance(actor, ImageModel):
            group, self._convs, self.encoder_activation = encoder_layers(actor)
            self.image_shape, self.image_dtype = actor.image_shapes[group], actor.image_dtypes[0]
            self.block, self.low_precision = actor.blocks[group], actor.low_precision
        self.std_type, self.std_range, self.log_std_range = (distribution.std_type, distribution.std_range,
                                                             distribution.log_std_range)
        std_name = "std_param" if self.std_type == "scalar" else "log_std_param"
        self.learn_std = getattr(distribution, std_name).requires_grad
        self._keys = {"actor": list(actor.state_dict()), "critic": list(critic.state_dict())}
        """rsl-rl's state_dict keys, in its order."""
        self._parameter_names = {"actor": [name for name, _ in actor.named_parameters()],
                                 "critic": [name for name, _ in critic.named_parameters()]}
        """The networks' parameters' names, in ``parameters()``'s order."""
        self._layers = {role: [(name, module.in_features, module.out_features)
                               for name, module in model.named_modules() if isinstance(module, nn.Linear)]
                        for role, model in (("actor", actor), ("critic", critic))}
        """Per network: (module name, in, out) of each linear layer."""
        self._sizes = [size for conv in self._convs for size in (math.prod(conv.weight_shape), conv.out_channels)]
        self._sizes += [size for _, n_in, n_out in self._layers["actor"] for size in (n_in * n_out, n_out)]
        self._sizes.append(distribution.output_dim)
        self.num_actor_params = sum(self._sizes)
        self._sizes += [size for _, n_in, n_out in self._layers["critic"] for size in (n_in * n_out, n_out)]
        self._std_name = f"distribution.{std_name}"
        self.params = nn.Parameter(torch.zeros(num_members, sum(self._sizes)))
        self.actor_normalizer, self.critic_normalizer = (
            BatchedNormalizer(num_members, model.obs_dim, model.obs_normalizer.eps) if model.obs_normalization
            else None for model in (actor, critic))
        """An image actor's is of its 0 state observations (as ``ImageModel``'s): in its state dicts, never updated."""

    @classmethod
    def from_members(cls, actors: Sequence[MLPModel], critics: Sequence[MLPModel]) -> BatchedActorCritic:
        """The members' actors and critics (same layouts) stacked: weights, std parameters, normaliser statistics."""
        model = cls(actors[0], critics[0], len(actors)).to(next(actors[0].parameters()).device)
        for k, (actor, critic) in enumerate(zip(actors, critics, strict=True)):
            model.load_member_state_dicts(k, actor.state_dict(), critic.state_dict())
        return model

    def member_parameters(self, k: int, flat: torch.Tensor) -> dict[str, dict[str, torch.Tensor]]:
        """Row ``k`` of a (K, P) tensor laid out as ``params`` (e.g. Adam's moments) as views shaped as the rsl-rl
        networks' parameters, by name, per network ('actor', 'critic')."""
        views = self._member_views(k, flat)
        return {role: {name: views[role][name] for name in self._parameter_names[role]} for role in views}

    def _member_views(self, k: int, flat: torch.Tensor | None = None) -> dict[str, dict[str, torch.Tensor]]:
        """Member ``k``'s tensors (of ``flat``, default ``params``) as views shaped as in rsl-rl's state dicts, per
        network ('actor', 'critic')."""
        chunks = iter((self.params.detach() if flat is None else flat)[k].split(self._sizes))
        views = {}
        for role in ("actor", "critic"):
            views[role] = {}
            for conv in self._convs if role == "actor" else ():
                views[role][f"{conv.name}.weight"] = next(chunks).view(conv.weight_shape)
                views[role][f"{conv.name}.bias"] = next(chunks)
            for name, n_in, n_out in self._layers[role]:
                views[role][f"{name}.weight"] = next(chunks).view(n_in, n_out).T
                views[role][f"{name}.bias"] = next(chunks)
            if role == "actor":
                views[role][self._std_name] = next(chunks)
            normalizer = self.actor_normalizer if role == "actor" else self.critic_normalizer
            if normalizer is not None:
                views[role] |= {"obs_normalizer._mean": normalizer.mean[k], "obs_normalizer._var": normalizer.var[k],
                                "obs_normalizer._std": normalizer.std[k], "obs_normalizer.count": normalizer.count[k]}
        return views

    def member_state_dicts(self, k: int) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
        """Member ``k``'s (actor, critic) state dicts, as rsl-rl's ``MLPModel.state_dict()`` (copies)."""
        views = self._member_views(k)
        return tuple({key: views[role][key].clone(memory_format=torch.contiguous_format) for key in self._keys[role]}
                     for role in ("actor", "critic"))

    @torch.no_grad()
    def load_member_state_dicts(self, k: int, actor_state: dict[str, torch.Tensor],
                                critic_state: dict[str, torch.Tensor]):
        """Copy rsl-rl ``MLPModel`` state dicts (of this layout) into member ``k``."""
        views = self._member_views(k)
        for role, state in (("actor", actor_state), ("critic", critic_state)):
            if set(state) != set(self._keys[role]):
                raise KeyError(f"{role} state dict keys {sorted(state)} differ from {sorted(self._keys[role])}")
            for key, view in views[role].items():
                view.copy_(state[key])

    def _networks(self, members: torch.Tensor | None = None) -> tuple[list, list, torch.Tensor, list]:
        """(encoder [(kernels (K, O C kh kw), biases (K, O))], actor layers [(weight (K, in, out), bias (K, 1, out))],
        std parameter (K, 1, A), critic layers), of every member or of ``members`` (indices)."""
        chunks = iter((self.params if members is None else self.params[members]).split(self._sizes, dim=1))
        encoder = [(next(chunks), next(chunks)) for _ in self._convs]
        actor = [(next(chunks).view(-1, n_in, n_out), next(chunks).view(-1, 1, n_out))
                 for _, n_in, n_out in self._layers["actor"]]
        std_param = next(chunks).unsqueeze(1)
        critic = [(next(chunks).view(-1, n_in, n_out), next(chunks).view(-1, 1, n_out))
                  for _, n_in, n_out in self._layers["critic"]]
        return encoder, actor, (std_param if self.learn_std else std_param.detach()), critic

    def _mlp(self, x: torch.Tensor, layers: list) -> torch.Tensor:
        for i, (weight, bias) in enumerate(layers):
            x = BatchedLinear.apply(x, weight, bias)
            if i < len(layers) - 1:
                x = self.activation(x)
        return x

    def _std(self, std_param: torch.Tensor) -> torch.Tensor:
        """rsl-rl's ``GaussianDistribution`` std of its parameter (clamped to its range)."""
        if self.std_type == "scalar":
            return std_param.clamp(*self.std_range)
        return std_param.clamp(*self.log_std_range).exp()

    def _actor(self, obs: torch.Tensor, encoder: list, layers: list, members: torch.Tensor | None) -> torch.Tensor:
        """The actors' means (K, B, A) of what they see: (K, B, O) states, normalised, or (K, B, C, H, W) images,
        encoded."""
        if self.image_shape is not None:
            return self._mlp(encode_members(obs, encoder, self._convs, self.encoder_activation, self.block,
                                            self.low_precision), layers)
        return self._mlp(obs if self.actor_normalizer is None else self.actor_normalizer(obs, members), layers)

    def forward(self, obs: torch.Tensor, members: torch.Tensor | None = None, images: torch.Tensor | None = None
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(K, B, O) state observations (and the (K, B, C, H, W) ``images`` an image actor sees instead) -> action
        means (K, B, A), std (K, 1, A), values (K, B); of every member, or of the K ``members`` (indices)."""
        if (images is None) != (self.image_shape is None):
            raise ValueError("images are what an image actor sees, and only it" if images is not None
                             else "an image actor needs its images")
        encoder, actor, std_param, critic = self._networks(members)
        critic_obs = obs if self.critic_normalizer is None else self.critic_normalizer(obs, members)
        mean = self._actor(obs if images is None else images, encoder, actor, members)
        return mean, self._std(std_param), self._mlp(critic_obs, critic).squeeze(-1)

    def action_mean(self, obs: torch.Tensor) -> torch.Tensor:
        """What the actors see, (K, B, O) states or (K, B, C, H, W) images -> their means (K, B, A): the members'
        deterministic actions."""
        encoder, actor, _, _ = self._networks()
        return self._actor(obs, encoder, actor, None)

    @torch.no_grad()
    def action_std(self) -> torch.Tensor:
        """(K, A) the members' action standard deviations."""
        return self._std(self._networks()[2]).squeeze(1)

    def values(self, obs: torch.Tensor, members: torch.Tensor | None = None) -> torch.Tensor:
        """(K, B, O) state observations -> the critics' values (K, B), of every member or of the K ``members``."""
        critic_obs = obs if self.critic_normalizer is None else self.critic_normalizer(obs, members)
        return self._mlp(critic_obs, self._networks(members)[3]).squeeze(-1)

    def update_normalization(self, obs: torch.Tensor, active: torch.Tensor):
        """rsl-rl's ``update_normalization`` of actor and critic with (K, B, O) state observations, ``active``
        members (an image actor's statistics stay as they are, as ``ImageModel``'s)."""
        actor_normalizer = self.actor_normalizer if self.image_shape is None else None
        for normalizer in (actor_normalizer, self.critic_normalizer):
            if normalizer is not None:
                normalizer.update(obs, active)


def gaussian_log_prob(actions: torch.Tensor, mean: torch.Tensor, std: torch.Tensor) -> torch.Tensor:
    """torch's ``Normal(mean, std).log_prob(actions)`` summed over the last dimension."""
    return (-((actions - mean) ** 2) / (2 * std**2) - std.log() - math.log(math.sqrt(2 * math.pi))).sum(-1)


def gaussian_kl(old_mean: torch.Tensor, old_std: torch.Tensor, new_mean: torch.Tensor,
                new_std: torch.Tensor) -> torch.Tensor:
    """torch's ``kl_divergence(Normal(old_mean, old_std), Normal(new_mean, new_std))`` summed over the last dim."""
    var_ratio = (old_std / new_std).pow(2)
    t1 = ((old_mean - new_mean) / new_std).pow(2)
    return (0.5 * (var_ratio + t1 - 1 - var_ratio.log())).sum(-1)


class PopulationPPO:
    """K rsl-rl PPO learners on one batched model; member k acts in its own N envs.

    Per step: ``act(obs (K, N, O)) -> actions (K, N, A)`` (with the ``images`` (K, N, C, H, W) where the actors see
    images, ``obs`` then the critics' state observations), then ``process_env_step(rewards, dones, time_outs)`` (each
    (K, N)); after T steps ``compute_returns(last_obs (K, N, O))`` and ``update() -> {"value", "surrogate",
    "entropy"}`` mean losses, each (K,). The scalar settings take a float (all members) or K values and keep rsl-rl's
    ``PPO`` names and defaults. Members whose ``active`` (K,) flag is False are left unchanged by ``update``
    (parameters, Adam state, learning rate, normalisers; their losses are still reported). The rollout is stored
    member-major, ``rollout`` (K, T, N, F) with named views (``observations`` (K, T, N, O), ``actions``, ``values``
    (K, T, N), ...), so that each member's (T, N) flattens to rsl-rl's sample order without a copy; an image actor's
    frames in ``images`` (K, T, N, C, H, W), of the env's dtype (uint8 colour: a quarter of float32's memory).
    """

    def __init__(self, model: BatchedActorCritic, num_envs: int, num_steps: int, *, num_learning_epochs: int = 5,
                 num_mini_batches: int = 4, clip_param=0.2, gamma=0.99, lam=0.95, value_loss_coef=1.0,
                 entropy_coef=0.01, learning_rate=1e-3, max_grad_norm=1.0, use_clipped_value_loss: bool = True,
                 schedule: str = "adaptive", desired_kl=0.01, normalize_advantage_per_mini_batch: bool = False,
                 mirror: Mirror | None = None):
        if mirror is not None and model.image_shape is not None:
            raise ValueError("the mirror augmentation mirrors state observations, not an image actor's frames")
        self.model = model
        device, members = model.params.device, model.num_members
        self.num_envs, self.num_steps = num_envs, num_steps
        self.num_learning_epochs, self.num_mini_batches = num_learning_epochs, num_mini_batches
        self.use_clipped_value_loss = use_clipped_value_loss
        self.adaptive = schedule == "adaptive" and desired_kl is not None
        """The learning rates follow rsl-rl's adaptive-KL rule (else they stay fixed)."""
        self.normalize_advantage_per_mini_batch, self.mirror = normalize_advantage_per_mini_batch, mirror

        def per_member(value) -> torch.Tensor:
            return torch.as_tensor(value, dtype=torch.float32, device=device).expand(members).clone()

        self.clip_param, self.gamma, self.lam = per_member(clip_param), per_member(gamma), per_member(lam)
        self.value_loss_coef, self.entropy_coef = per_member(value_loss_coef), per_member(entropy_coef)
        self.max_grad_norm = per_member(max_grad_norm)
        self.desired_kl = per_member(0.0 if desired_kl is None else desired_kl)
        self.learning_rate = per_member(learning_rate)
        """(K,) current learning rates (adapted in place under the 'adaptive' schedule)."""
        self.active = torch.ones(members, dtype=torch.bool, device=device)
        """(K,) members that ``update`` changes."""
        self.exp_avg, self.exp_avg_sq = torch.zeros_like(model.params), torch.zeros_like(model.params)
        self.adam_steps = torch.zeros(members, dtype=torch.float64, device=device)
        """(K,) Adam steps taken per member (float64: bias corrections as torch computes them, in double)."""
        self._allocate_rollout()

    def _allocate_rollout(self):
        """The rollout's storage (the class's docstring names it), zeroed."""
        model, members, num_steps, num_envs = self.model, self.model.num_members, self.num_steps, self.num_envs
        device, num_obs, num_actions = model.params.device, model.num_obs, model.num_actions
        self._fields = [num_obs, num_actions, 1, 1, 1, 1, num_actions, num_actions]
        """Feature widths of ``rollout``: observations, actions, values, returns, advantages, actions_log_prob,
        action_mean, action_std (one gather per mini-batch fetches them all)."""
        self.rollout = torch.zeros(members, num_steps, num_envs, sum(self._fields), device=device)
        (self.observations, self.actions, values, returns, advantages, log_prob, self.action_mean,
         self.action_std) = self.rollout.split(self._fields, dim=-1)
        self.values, self.returns, self.advantages, self.actions_log_prob = (
            t.squeeze(-1) for t in (values, returns, advantages, log_prob))
        self.rewards = torch.zeros(members, num_steps, num_envs, device=device)
        """(K, T, N) rewards, time-outs bootstrapped (rsl-rl's ``process_env_step``)."""
        self.dones = torch.zeros(members, num_steps, num_envs, device=device)
        self.images = None if model.image_shape is None else torch.zeros(
            members, num_steps, num_envs, *model.image_shape, dtype=model.image_dtype, device=device)
        self._member_rows = torch.arange(members, device=device)[:, None]
        self.step = 0
        """Steps stored in the current rollout."""

    @torch.no_grad()
    def act(self, obs: torch.Tensor, images: torch.Tensor | None = None) -> torch.Tensor:
        """Sample actions (K, N, A) for observations (K, N, O) (and ``images`` (K, N, C, H, W) of an image actor) (mean
        + std * N(0, 1), as ``SyncFreeGaussian``) and store the transition."""
        mean, std, values = self.model(obs, images=images)
        actions = gaussian_sample(mean, std)
        step = self.step
        if images is not None:
            self.images[:, step] = images
        self.observations[:, step] = obs
        self.actions[:, step] = actions
        self.values[:, step] = values
        self.actions_log_prob[:, step] = gaussian_log_prob(actions, mean, std)
        self.action_mean[:, step] = mean
        self.action_std[:, step] = std
        return actions

    def process_env_step(self, rewards: torch.Tensor, dones: torch.Tensor, time_outs: torch.Tensor | None = None):
        """Store the (K, N) rewards and dones of the step after ``act``; time-outs add gamma * V(obs) to the reward."""
        if self.step >= self.num_steps:
            raise OverflowError("rollout full: call update() before adding more steps")
        if time_outs is not None:
            rewards = rewards + self.gamma[:, None] * (self.values[:, self.step] * time_outs)
        self.rewards[:, self.step] = rewards
        self.dones[:, self.step] = dones
        self.step += 1

    @torch.no_grad()
    def compute_returns(self, last_obs: torch.Tensor):
        """GAE returns and advantages of the rollout, bootstrapped with the values of ``last_obs`` (K, N, O);
        advantages normalised per member over the rollout (unless ``normalize_advantage_per_mini_batch``)."""
        last_values = self.model.values(last_obs)
        gamma, lam = self.gamma[:, None], self.lam[:, None]
        advantage = 0
        for step in reversed(range(self.num_steps)):
            next_values = last_values if step == self.num_steps - 1 else self.values[:, step + 1]
            next_is_not_terminal = 1.0 - self.dones[:, step]
            delta = self.rewards[:, step] + next_is_not_terminal * gamma * next_values - self.values[:, step]
            advantage = delta + next_is_not_terminal * gamma * lam * advantage
            self.returns[:, step] = advantage + self.values[:, step]
        self.advantages.copy_(self.returns - self.values)
        if not self.normalize_advantage_per_mini_batch:
            mean = self.advantages.mean(dim=(1, 2), keepdim=True)
            std = self.advantages.std(dim=(1, 2), keepdim=True)
            self.advantages.copy_((self.advantages - mean) / (std + 1e-8))

    def update(self, permutation: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """rsl-rl's ``PPO.update`` for every member: mini-batches of one (K, batch) ``permutation`` of each member's
        T * N samples (default: drawn here; batch = num_mini_batches * (T * N // num_mini_batches)) for every epoch,
        then the normalisers. Returns the mean value and surrogate losses and entropy, (K,) each."""
        members = self.model.num_members
        mini_batch = self.num_envs * self.num_steps // self.num_mini_batches
        if permutation is None:
            permutation = torch.rand(members, mini_batch * self.num_mini_batches,
                                     device=self.rollout.device).argsort(dim=1)
        rollout = self.rollout.flatten(1, 2)
        images = None if self.images is None else self.images.flatten(1, 2)
        sums = torch.zeros(3, members, device=rollout.device)
        for _ in range(self.num_learning_epochs):
            for i in range(self.num_mini_batches):
                rows = permutation[:, i * mini_batch:(i + 1) * mini_batch]
                index = rows[..., None].expand(-1, -1, rollout.shape[-1])
                batch_images = None if images is None else images[self._member_rows, rows]
                sums += self._gradient_step(rollout.gather(1, index), i, batch_images)
        self.model.update_normalization(self.observations.flatten(1, 2), self.active)
        self.step = 0
        value, surrogate, entropy = sums / (self.num_learning_epochs * self.num_mini_batches)
        return {"value": value, "surrogate": surrogate, "entropy": entropy}

    def _gradient_step(self, batch: torch.Tensor, mini_batch: int, images: torch.Tensor | None) -> torch.Tensor:
        """Mini-batch ``mini_batch`` (K, B, F) of the epoch (with its ``images`` (K, B, C, H, W) of an image actor):
        every member's PPO loss, learning-rate rule, clip and Adam step; returns the (3, K) value loss, surrogate loss
        and entropy."""
        surrogate_loss, value_loss, entropy = self._losses(batch, images=images)
        self._step(surrogate_loss + self.value_loss_coef * value_loss - self.entropy_coef * entropy, mini_batch)
        return torch.stack((value_loss.detach(), surrogate_loss.detach(), entropy.detach()))

    def _step(self, loss: torch.Tensor, mini_batch: int):
        """Each member's gradient of its (K,) ``loss`` on mini-batch ``mini_batch`` of the epoch, clipped, and its Adam
        step (a subclass may add losses of its own mini-batches)."""
        (grad,) = torch.autograd.grad(loss.sum(), self.model.params)
        self._clip_and_step(grad)

    def _losses(self, batch: torch.Tensor, members: torch.Tensor | None = None, dual_clip: float | None = None,
                images: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """rsl-rl's PPO losses of a mini-batch (K, B, F) laid out as ``rollout`` (and its (K, B, C, H, W) ``images``
        of an image actor): the clipped surrogate loss, the (clipped) value loss and the entropy, (K,) each, of every
        member (and its learning-rate rule on the batch's KL) or of the K ``members`` (indices), each on its row of
        ``batch``. ``dual_clip`` c: a sample's surrogate loss with a negative advantage A is at most -c A (dual-clip
        PPO: Ye et al., AAAI 2020)."""
        obs, actions, old_values, returns, advantages, old_log_prob, old_mean, old_std = batch.split(self._fields, -1)
        old_values, returns, advantages, old_log_prob = (
            t.squeeze(-1) for t in (old_values, returns, advantages, old_log_prob))
        if self.normalize_advantage_per_mini_batch:
            advantages = ((advantages - advantages.mean(1, keepdim=True))
                          / (advantages.std(1, keepdim=True) + 1e-8))
        rows, size = advantages.shape
        if self.mirror is not None:
            obs, actions = (
                t.reshape(-1, rows, size, t.shape[-1]).transpose(0, 1).reshape(rows, -1, t.shape[-1])
                for t in self.mirror(obs.reshape(rows * size, -1), actions.reshape(rows * size, -1)))
            copies = obs.shape[1] // size
            old_values, returns, advantages, old_log_prob = (
                t.repeat(1, copies) for t in (old_values, returns, advantages, old_log_prob))
        mean, std, values = self.model(obs, members, images)
        log_prob = gaussian_log_prob(actions, mean, std)
        entropy = (0.5 + 0.5 * math.log(2 * math.pi) + std.log()).sum(-1).squeeze(1)
        if self.adaptive and members is None:
            with torch.no_grad():
                self._adapt_learning_rate(gaussian_kl(old_mean, old_std, mean[:, :size], std).mean(1))
        clip = (self.clip_param if members is None else self.clip_param[members])[:, None]
        surrogate = clipped_surrogate(torch.exp(log_prob - old_log_prob), advantages, clip)
        if dual_clip is not None:
            surrogate = torch.where(advantages < 0, torch.min(surrogate, -dual_clip * advantages), surrogate)
        value_loss = value_error(values, old_values, returns, clip, self.use_clipped_value_loss).mean(1)
        return surrogate.mean(1), value_loss, entropy

    SETTINGS = ("learning_rate", "entropy_coef", "gamma", "lam", "clip_param", "desired_kl", "value_loss_coef",
                "max_grad_norm")
    """The (K,) settings tensors: ``learning_rate`` the current (adapted) rate, the others as given."""

    def member_state(self, k: int) -> dict[str, torch.Tensor]:
        """Member ``k``'s whole training state, by name (views): its parameters (networks and std), Adam's moments and
        step count, its normalisers' statistics and its ``SETTINGS``."""
        model = self.model
        normalizers = [(name, normalizer) for name, normalizer in (("actor_normalizer", model.actor_normalizer),
                                                                    ("critic_normalizer", model.critic_normalizer))
                       if normalizer is not None]
        state = {"params": model.params.detach()[k], "exp_avg": self.exp_avg[k], "exp_avg_sq": self.exp_avg_sq[k],
                 "adam_steps": self.adam_steps[k]}
        state |= {f"{name}.{buffer}": getattr(normalizer, buffer)[k] for name, normalizer in normalizers
                  for buffer in ("mean", "var", "std", "count")}
        return state | {name: getattr(self, name)[k] for name in self.SETTINGS}

    @torch.no_grad()
    def copy_member(self, source: int, target: int):
        """Member ``source``'s whole state (``member_state``) copied over member ``target``'s, in place (a captured
        graph's tensors stay where they are); every other member's is untouched."""
        for into, value in zip(self.member_state(target).values(), self.member_state(source).values(), strict=True):
            into.copy_(value)

    def _adapt_learning_rate(self, kl_mean: torch.Tensor):
        """rsl-rl's rule (``ppo_rules.adaptive_kl_rate``) per active member."""
        lr = self.learning_rate
        lr.copy_(torch.where(self.active, adaptive_kl_rate(lr, kl_mean, self.desired_kl), lr))

    @torch.no_grad()
    def _clip_and_step(self, grad: torch.Tensor):
        """``clip_grad_norm_`` of each member's actor and critic gradients (separately), then torch's Adam step
        (``torch.optim.Adam`` arithmetic) of the active members with their learning rates."""
        max_norm = self.max_grad_norm[:, None]
        for part in grad.split([self.model.num_actor_params, grad.shape[1] - self.model.num_actor_params], dim=1):
            norm = torch.linalg.vector_norm(part, dim=1, keepdim=True)
            part.mul_((max_norm / (norm + 1e-6)).clamp(max=1.0))
        beta1, beta2 = PPO_ADAM_BETAS
        active = self.active[:, None]
        self.adam_steps += self.active
        steps = self.adam_steps.clamp(min=1.0)[:, None]
        self.exp_avg.lerp_(grad, (1 - beta1) * active)
        self.exp_avg_sq.mul_(torch.where(active, beta2, 1.0)).add_((1 - beta2) * active * grad * grad)
        step_size = (self.learning_rate[:, None] * active / (1 - beta1**steps)).float()
        bias_correction2_sqrt = (1 - beta2**steps).sqrt().float()
        denom = (self.exp_avg_sq.sqrt() / bias_correction2_sqrt).add_(PPO_ADAM_EPS)
        self.model.params.sub_(step_size * (self.exp_avg / denom))


__getattr__ = renamed(__name__, {"ADAM_BETAS": "PPO_ADAM_BETAS", "ADAM_EPS": "PPO_ADAM_EPS"})
"""The old names, until ``settings.deprecation.REMOVED_IN``."""
