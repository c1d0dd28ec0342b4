"""PPO's rules on tensors, written once for the learners that follow rsl-rl's PPO (``ppo``'s ``SyncFreePPO`` on one
policy's tensors, ``batched_ppo``'s ``PopulationPPO`` on K members' (K, B) rows, ``sapg``'s leader through it): the
adaptive-KL learning rate, the clipped surrogate and the (clipped) value error, each as rsl-rl's ``PPO`` computes it."""

from __future__ import annotations

import torch


def adaptive_kl_rate(learning_rate: torch.Tensor, kl_mean: torch.Tensor, desired_kl) -> torch.Tensor:
    """rsl-rl's adaptive learning rate after a mini-batch whose mean KL is ``kl_mean``: divided by 1.5 (not below 1e-5)
    above twice ``desired_kl``, multiplied by 1.5 (not above 1e-2) below half of it (KL above 0), else kept; on the
    device, without a host sync."""
    smaller = torch.clamp(learning_rate / 1.5, min=1e-5)
    larger = torch.clamp(learning_rate * 1.5, max=1e-2)
    return torch.where(kl_mean > desired_kl * 2.0, smaller,
                       torch.where((kl_mean < desired_kl / 2.0) & (kl_mean > 0.0), larger, learning_rate))


def clipped_surrogate(ratio: torch.Tensor, advantages: torch.Tensor, clip) -> torch.Tensor:
    """Each sample's clipped surrogate loss, max(-A r, -A clip(r, 1 - clip, 1 + clip)), for the mean to be taken."""
    return torch.max(-advantages * ratio, -advantages * torch.clamp(ratio, 1.0 - clip, 1.0 + clip))


def value_error(values: torch.Tensor, old_values: torch.Tensor, returns: torch.Tensor, clip,
                clipped: bool) -> torch.Tensor:
    """Each sample's squared value error; ``clipped`` (``use_clipped_value_loss``): the larger of it and that of the
    value moved at most ``clip`` from the rollout's."""
    if not clipped:
        return (returns - values).pow(2)
    value_clipped = old_values + (values - old_values).clamp(-clip, clip)
    return torch.max((values - returns).pow(2), (value_clipped - returns).pow(2))
