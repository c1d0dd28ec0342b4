"""``SyncFreePPO``: rsl-rl's PPO with an update that never waits for the device (its actor samples with
``policies.SyncFreeGaussian``, which does not wait either).

rsl-rl's ``PPO.update`` reads four values back per mini-batch (the KL for its adaptive learning rate, then the value,
surrogate and entropy losses); on a GPU each read drains the queue, so the CPU cannot run ahead and a mini-batch of a
small network costs its launch time plus its run time. Here the learning rate is a tensor that the KL rule updates
on the device (``torch.where`` instead of ``if``), Adam takes it as a tensor (``fused=True``), and the losses are
summed on the device and read once per update. Everything else is rsl-rl's (storage, models, ``act``, returns,
mini-batches, the same loss): ``tests/test_ppo.py`` checks that both updates give the same networks. Free of syncs,
the gradient steps of an update can also be captured as one CUDA graph (``cuda_graph``): one launch instead of
~150 kernel launches per mini-batch.
"""

from __future__ import annotations

from ....wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
from itertools import chain
from types import SimpleNamespace

import torch
from rsl_rl.algorithms import PPO
from rsl_rl.utils.utils import reduce_gradients_in_buckets
from torch import nn

from ....engine.streams import TorchGraph
from ....settings.deprecation import moved_names
from ...policies import update_normalization
from ..ppo_rules import adaptive_kl_rate, clipped_surrogate, value_error


class SyncFreePPO(PPO):
    """rsl-rl ``PPO`` (feed-forward models, no RND; symmetry as data augmentation, without the mirror loss) whose
    ``update`` has no host sync per mini-batch."""

    def __init__(self, actor, critic, storage, *args, cuda_graph: bool = False, **kwargs):
        self._learning_rate = None
        super().__init__(actor, critic, storage, *args, **kwargs)
        if self.rnd or actor.is_recurrent or critic.is_recurrent or (
                self.symmetry and (self.symmetry.use_mirror_loss or not self.symmetry.use_data_augmentation)):
            raise ValueError("SyncFreePPO supports feed-forward actor and critic without RND, and symmetry as data "
                             "augmentation without the mirror loss; use PPO")
        self.cuda_graph = cuda_graph and torch.device(self.device).type == "cuda"
        """Capture the update's gradient steps (with their NCCL all-reduces under torchrun) as one CUDA graph."""
        self.optimizer = torch.optim.Adam(chain(self.actor.parameters(), self.critic.parameters()),
                                          lr=self._learning_rate, fused=True, capturable=self.cuda_graph)
        self._graph = TorchGraph(self.device) if self.cuda_graph else None
        self._advantages = self._permutation = self._sums = None

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
            group.update(lr=self._learning_rate, fused=True, foreach=None, capturable=self.cuda_graph)
        for param, state in self.optimizer.state.items():
            if "step" in state:
                state["step"] = state["step"].to(param.device, torch.float32)
        return iteration

    def reduce_parameters(self) -> None:
        """rsl-rl's gradient all-reduce, for gradients of any dense layout: it flattens each with ``view(-1)``, which
        a channels-last convolution kernel's gradient (``rl.image_model``) refuses; it gets a flat alias instead."""
        grads = [SimpleNamespace(grad=p.grad.as_strided((p.grad.numel(),), (1,)))
                 for p in chain(self.actor.parameters(), self.critic.parameters()) if p.grad is not None]
        reduce_gradients_in_buckets(grads, self.gpu_world_size, self.grad_reduce_bucket_mb)

    def release_graph(self):
        """Free the captured update (before the process group is destroyed: ``TorchGraph.release``)."""
        if self._graph is not None:
            self._graph.release()

    def _adapt_learning_rate(self, kl_mean: torch.Tensor):
        """rsl-rl's rule (``ppo_rules.adaptive_kl_rate``) on the KL averaged over the processes."""
        if self.is_multi_gpu:
            torch.distributed.all_reduce(kl_mean, op=torch.distributed.ReduceOp.SUM)
            kl_mean /= self.gpu_world_size
        self._learning_rate.copy_(adaptive_kl_rate(self._learning_rate, kl_mean, self.desired_kl))

    def update(self) -> dict[str, float]:
        """rsl-rl's ``PPO.update``: the same mini-batches, losses, learning-rate rule and gradient steps. With
        ``cuda_graph`` the gradient steps run op by op the first time (Adam makes its state), are captured the second
        time and replayed after."""
        st = self.storage
        batch_size = self.num_mini_batches * (st.num_envs * st.num_transitions_per_env // self.num_mini_batches)
        if self._advantages is None:
            self._advantages = torch.empty_like(st.advantages)
            self._permutation = torch.empty(batch_size, dtype=torch.long, device=self.device)
            self._sums = torch.zeros(3, device=self.device)
        self._advantages.copy_(st.advantages)
        self._permutation.copy_(torch.randperm(batch_size, requires_grad=False, device=self.device))
        if self._graph is None:
            self._gradient_steps()
        else:
            self._graph(self._gradient_steps)
        update_normalization((self.actor, self.critic), st.observations.flatten(0, 1))
        st.clear()
        value, surrogate, entropy = (self._sums / (self.num_learning_epochs * self.num_mini_batches)).tolist()
        return {"value": value, "surrogate": surrogate, "entropy": entropy}

    def _gradient_steps(self):
        """Every epoch's mini-batches (slices of ``_permutation`` over the flattened rollout, as rsl-rl's
        ``mini_batch_generator`` makes them): loss, adaptive learning rate, gradient step; losses summed into
        ``_sums``. Only device work on tensors that stay put, so that it can be captured as a CUDA graph."""
        st = self.storage
        observations = st.observations.flatten(0, 1)
        actions, values, returns = st.actions.flatten(0, 1), st.values.flatten(0, 1), st.returns.flatten(0, 1)
        old_log_prob, advantages = st.actions_log_prob.flatten(0, 1), self._advantages.flatten(0, 1)
        old_params = tuple(p.flatten(0, 1) for p in st.distribution_params)
        size = self._permutation.numel() // self.num_mini_batches
        self._sums.zero_()
        for _ in range(self.num_learning_epochs):
            for i in range(self.num_mini_batches):
                index = self._permutation[i * size:(i + 1) * size]
                self._gradient_step(observations[index], actions[index], values[index], returns[index],
                                    old_log_prob[index], advantages[index], tuple(p[index] for p in old_params))

    def _gradient_step(self, observations, actions, old_values, returns, old_log_prob, advantages, old_params):
        """One mini-batch of rsl-rl's PPO loss and optimizer step (with symmetry: the mini-batch and its mirror images,
        the rollout's values repeated for them, entropy and KL over the original samples, as rsl-rl's PPO does)."""
        if self.normalize_advantage_per_mini_batch:
            with torch.no_grad():
                advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        size = actions.shape[0]
        if self.symmetry:
            observations, actions = self.symmetry.data_augmentation_func(env=self.symmetry.env, obs=observations,
                                                                         actions=actions)
            copies = actions.shape[0] // size
            old_values, returns, old_log_prob, advantages = (
                t.repeat(copies, 1) for t in (old_values, returns, old_log_prob, advantages))
        with torch.amp.autocast(device_type=torch.device(self.device).type, enabled=self.use_mixed_precision,
                                dtype=torch.bfloat16):
            self.actor(observations, stochastic_output=True)
            log_prob = self.actor.get_output_log_prob(actions)
            values = self.critic(observations)
            entropy = self.actor.output_entropy[:size].mean()
            if self.desired_kl is not None and self.schedule == "adaptive":
                with torch.inference_mode():
                    kl = self.actor.get_kl_divergence(
                        old_params, tuple(p[:size] for p in self.actor.output_distribution_params))
                    self._adapt_learning_rate(torch.mean(kl))
            ratio = torch.exp(log_prob - torch.squeeze(old_log_prob))
            surrogate_loss = clipped_surrogate(ratio, torch.squeeze(advantages), self.clip_param).mean()
            value_loss = value_error(values, old_values, returns, self.clip_param, self.use_clipped_value_loss).mean()
            loss = surrogate_loss + self.value_loss_coef * value_loss - self.entropy_coef * entropy
        self.optimizer.zero_grad()
        loss.backward()
        if self.is_multi_gpu:
            self.reduce_parameters()
        nn.utils.clip_grad_norm_(self.actor.parameters(), self.max_grad_norm)
        nn.utils.clip_grad_norm_(self.critic.parameters(), self.max_grad_norm)
        self.optimizer.step()
        self._sums += torch.stack((value_loss.detach(), surrogate_loss.detach(), entropy.detach()))


__getattr__ = moved_names(__name__, "cartpole_warp.rl.policies")
"""``SyncFreeGaussian``, which lived here, until ``settings.deprecation.REMOVED_IN``."""
