"""FastTD3's parts (Seo et al. 2025, "FastTD3: Simple, Fast, and Capable Reinforcement Learning for Humanoid
Control"): the distributional twin critic, the categorical projection of a target distribution onto the critic's
atoms (C51: Bellemare, Dabney and Munos, ICML 2017), the critics' and the actor's losses, and the replay of every
env's transitions on the device. All of it is device work on tensors that stay put, so a gradient step can be
captured as a CUDA graph.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional


class TwinDistributionalCritic(nn.Module):
    """Two critics Z_1, Z_2 (s, a) -> logits of a categorical distribution of returns on ``num_atoms`` atoms evenly
    spaced on [``v_min``, ``v_max``] (``support``), each an MLP of ``hidden_dims`` (ReLU) on the concatenated
    observation and action."""

    def __init__(self, num_obs: int, num_actions: int, hidden_dims: list[int], num_atoms: int, v_min: float,
                 v_max: float):
        super().__init__()

        def mlp() -> nn.Sequential:
            sizes, layers = [num_obs + num_actions, *hidden_dims], []
            for n_in, n_out in zip(sizes, sizes[1:]):
                layers += [nn.Linear(n_in, n_out), nn.ReLU()]
            return nn.Sequential(*layers, nn.Linear(sizes[-1], num_atoms))

        self.critics = nn.ModuleList([mlp(), mlp()])
        self.register_buffer("support", torch.linspace(v_min, v_max, num_atoms))

    def forward(self, obs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """(B, O), (B, A) -> logits (2, B, num_atoms)."""
        x = torch.cat([obs, actions], dim=-1)
        return torch.stack([critic(x) for critic in self.critics])

    def expected(self, probabilities: torch.Tensor) -> torch.Tensor:
        """The means (..., ) of distributions (..., num_atoms) on the support."""
        return (probabilities * self.support).sum(-1)


def project(probabilities: torch.Tensor, rewards: torch.Tensor, discounts: torch.Tensor,
            support: torch.Tensor) -> torch.Tensor:
    """C51's projection: the distribution of r + discount * Z, Z with ``probabilities`` (B, M) on ``support`` (M,)
    (evenly spaced), onto the support: each atom's shifted value, clipped to the support's ends, splits its mass
    between the two atoms around it in proportion to its nearness (all of it to an atom it falls on). ``rewards``
    and ``discounts`` (B,); the discount is 0 where the episode ended in a termination."""
    atoms = support.shape[0]
    v_min, v_max = support[0], support[-1]
    shifted = (rewards[:, None] + discounts[:, None] * support).clamp(v_min, v_max)
    position = (shifted - v_min) / ((v_max - v_min) / (atoms - 1))
    lower = position.floor().clamp(max=atoms - 1)
    upper_weight = position - lower
    lower = lower.long()
    projected = torch.zeros_like(probabilities)
    projected.scatter_add_(1, lower, probabilities * (1 - upper_weight))
    projected.scatter_add_(1, (lower + 1).clamp(max=atoms - 1), probabilities * upper_weight)
    return projected


def critic_loss(critic: TwinDistributionalCritic, target_critic: TwinDistributionalCritic, obs: torch.Tensor,
                actions: torch.Tensor, rewards: torch.Tensor, discounts: torch.Tensor, next_obs: torch.Tensor,
                next_actions: torch.Tensor) -> torch.Tensor:
    """FastTD3's critic loss with clipped double Q: both target critics' distributions at (next state, smoothed
    next action), projected (``project``); per transition the one of the lower mean is both critics' target; the loss
    is the sum over the two critics of the mean cross-entropy of their distributions at (state, action) to it."""
    with torch.no_grad():
        next_probabilities = functional.softmax(target_critic(next_obs, next_actions), dim=-1)
        targets = torch.stack([project(p, rewards, discounts, critic.support) for p in next_probabilities])
        means = target_critic.expected(targets)
        target = torch.where((means[0] < means[1])[:, None], targets[0], targets[1])
    log_probabilities = functional.log_softmax(critic(obs, actions), dim=-1)
    return -(target * log_probabilities).sum(-1).mean(-1).sum()


def actor_loss(critic: TwinDistributionalCritic, obs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
    """TD3's actor loss: minus the mean over the batch of the smaller of the two critics' expected returns at
    (state, the actor's ``actions`` there)."""
    values = critic.expected(functional.softmax(critic(obs, actions), dim=-1))
    return -values.min(dim=0).values.mean()


@torch.no_grad()
def soft_update(target: nn.Module, source: nn.Module, tau: float):
    """target = (1 - tau) target + tau source, parameter by parameter."""
    targets, sources = list(target.parameters()), list(source.parameters())
    torch._foreach_mul_(targets, 1.0 - tau)
    torch._foreach_add_(targets, sources, alpha=tau)


class Replay:
    """The last ``steps`` env steps of ``num_envs`` envs, on ``device``: state, action, reward, discount (gamma, 0
    after a termination), next state (the episode's last observation where it ended). ``add`` writes a step at a
    position held on the device, ``sample`` draws transitions uniformly from those written: both device work only."""

    def __init__(self, steps: int, num_envs: int, num_obs: int, num_actions: int, device: str):
        self.steps, self.num_envs = steps, num_envs
        self.widths = [num_obs, num_actions, 1, 1, num_obs]
        self.data = torch.zeros(steps, num_envs, sum(self.widths), device=device)
        self.position = torch.zeros(1, dtype=torch.long, device=device)
        self.filled = torch.zeros((), device=device)
        """Steps written (at most ``steps``), a float for sampling."""

    def add(self, obs: torch.Tensor, actions: torch.Tensor, rewards: torch.Tensor, discounts: torch.Tensor,
            next_obs: torch.Tensor):
        step = torch.cat([obs, actions, rewards[:, None], discounts[:, None], next_obs], dim=-1)
        self.data.index_copy_(0, self.position, step[None])
        self.position.copy_((self.position + 1) % self.steps)
        self.filled.copy_((self.filled + 1).clamp(max=self.steps))

    def sample(self, batch_size: int) -> tuple[torch.Tensor, ...]:
        """(obs, actions, rewards, discounts, next_obs) of ``batch_size`` transitions drawn with replacement."""
        step = (torch.rand(batch_size, device=self.data.device) * self.filled).long()
        env = torch.randint(self.num_envs, (batch_size,), device=self.data.device)
        obs, actions, rewards, discounts, next_obs = self.data[step, env].split(self.widths, dim=-1)
        return obs, actions, rewards.squeeze(-1), discounts.squeeze(-1), next_obs
