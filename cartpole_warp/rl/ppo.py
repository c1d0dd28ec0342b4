"""``SyncFreePPO``: rsl-rl's PPO with an update that never waits for the device.

rsl-rl's ``PPO.update`` reads four values back per mini-batch (the KL for its adaptive learning rate, then the value,
surrogate and entropy losses); on a GPU each read drains the queue, so the CPU cannot run ahead and a mini-batch of a
small network costs its launch time plus its run time. Here the learning rate is a tensor that the KL rule updates
on the device (``torch.where`` instead of ``if``), Adam takes it as a tensor (``fused=True``), and the losses are
summed on the device and read once per update. Everything else is rsl-rl's (storage, models, ``act``, returns,
mini-batches, the same loss): ``tests/test_ppo.py`` checks that both updates give the same networks.
"""

from __future__ import annotations

from itertools import chain

import torch
from rsl_rl.algorithms import PPO
from torch import nn


class SyncFreePPO(PPO):
    """rsl-rl ``PPO`` (feed-forward models, no RND or symmetry) whose ``update`` has no host sync per mini-batch."""

    def __init__(self, actor, critic, storage, *args, **kwargs):
        self._learning_rate = None
        super().__init__(actor, critic, storage, *args, **kwargs)
        if self.rnd or self.symmetry or actor.is_recurrent or critic.is_recurrent:
            raise ValueError("SyncFreePPO supports feed-forward actor and critic without RND or symmetry; use PPO")
        self.optimizer = torch.optim.Adam(chain(self.actor.parameters(), self.critic.parameters()),
                                          lr=self._learning_rate, fused=True)

    @property
    def learning_rate(self) -> float:
        """The current learning rate (reading it waits for the device)."""
        return float(self._learning_rate)

    @learning_rate.setter
    def learning_rate(self, value: float | torch.Tensor):
        value = torch.as_tensor(value, dtype=torch.float32, device=self.device)
        if self._learning_rate is None:
            self._learning_rate = value.clone()
        else:
            self._learning_rate.copy_(value)

    def load(self, loaded_dict: dict, load_cfg: dict | None, strict: bool) -> bool:
        """rsl-rl's ``load``; then the optimizer uses the learning-rate tensor and fused Adam again (a checkpoint of
        rsl-rl's PPO carries a float rate and its own Adam options)."""
        iteration = super().load(loaded_dict, load_cfg, strict)
        for group in self.optimizer.param_groups:
            group.update(lr=self._learning_rate, fused=True, foreach=None)
        for param, state in self.optimizer.state.items():
            if "step" in state:
                state["step"] = state["step"].to(param.device, torch.float32)
        return iteration

    def _adapt_learning_rate(self, kl_mean: torch.Tensor):
        """rsl-rl's rule, on the device: divide by 1.5 above twice the target KL, multiply by 1.5 below half of it."""
        if self.is_multi_gpu:
            torch.distributed.all_reduce(kl_mean, op=torch.distributed.ReduceOp.SUM)
            kl_mean /= self.gpu_world_size
        lr = self._learning_rate
        smaller = torch.clamp(lr / 1.5, min=1e-5)
        larger = torch.clamp(lr * 1.5, max=1e-2)
        lr.copy_(torch.where(kl_mean > self.desired_kl * 2.0, smaller,
                             torch.where((kl_mean < self.desired_kl / 2.0) & (kl_mean > 0.0), larger, lr)))

    def update(self) -> dict[str, float]:
        """rsl-rl's ``PPO.update``: the same mini-batches, losses, learning-rate rule and gradient steps."""
        sums = torch.zeros(3, device=self.device)
        """value loss, surrogate loss, entropy, summed over the mini-batches."""
        for batch in self.storage.mini_batch_generator(self.num_mini_batches, self.num_learning_epochs):
            if self.normalize_advantage_per_mini_batch:
                with torch.no_grad():
                    batch.advantages = (batch.advantages - batch.advantages.mean()) / (batch.advantages.std() + 1e-8)
            with torch.amp.autocast(device_type=torch.device(self.device).type, enabled=self.use_mixed_precision,
                                    dtype=torch.bfloat16):
                self.actor(batch.observations, stochastic_output=True)
                actions_log_prob = self.actor.get_output_log_prob(batch.actions)
                values = self.critic(batch.observations)
                distribution_params = self.actor.output_distribution_params
                entropy = self.actor.output_entropy
                if self.desired_kl is not None and self.schedule == "adaptive":
                    with torch.inference_mode():
                        kl = self.actor.get_kl_divergence(batch.old_distribution_params, distribution_params)
                        self._adapt_learning_rate(torch.mean(kl))
                ratio = torch.exp(actions_log_prob - torch.squeeze(batch.old_actions_log_prob))
                advantages = torch.squeeze(batch.advantages)
                surrogate = -advantages * ratio
                surrogate_clipped = -advantages * torch.clamp(ratio, 1.0 - self.clip_param, 1.0 + self.clip_param)
                surrogate_loss = torch.max(surrogate, surrogate_clipped).mean()
                if self.use_clipped_value_loss:
                    value_clipped = batch.values + (values - batch.values).clamp(-self.clip_param, self.clip_param)
                    value_losses = (values - batch.returns).pow(2)
                    value_loss = torch.max(value_losses, (value_clipped - batch.returns).pow(2)).mean()
                else:
                    value_loss = (batch.returns - values).pow(2).mean()
                entropy_mean = entropy.mean()
                loss = surrogate_loss + self.value_loss_coef * value_loss - self.entropy_coef * entropy_mean
            self.optimizer.zero_grad()
            loss.backward()
            if self.is_multi_gpu:
                self.reduce_parameters()
            nn.utils.clip_grad_norm_(self.actor.parameters(), self.max_grad_norm)
            nn.utils.clip_grad_norm_(self.critic.parameters(), self.max_grad_norm)
            self.optimizer.step()
            sums += torch.stack((value_loss.detach(), surrogate_loss.detach(), entropy_mean.detach()))
        obs = self.storage.observations.flatten(0, 1)
        self.actor.update_normalization(obs)
        self.critic.update_normalization(obs)
        self.storage.clear()
        value, surrogate, entropy = (sums / (self.num_learning_epochs * self.num_mini_batches)).tolist()
        return {"value": value, "surrogate": surrogate, "entropy": entropy}
