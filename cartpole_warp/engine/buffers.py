"""The batch's persistent memory (``EnvBuffers``): the Warp buffers its kernels read and write, allocated once, and the
torch tensors over them (zero-copy), which ``BatchedEnv`` hands out or fills."""

from __future__ import annotations

from types import SimpleNamespace

import warp as wp

from .runtime import Shard


class EnvBuffers:
    """The inputs (``actions``, their ``action_history`` for the delay, ``actuator_f``, the ``states_in`` and
    ``mask_in`` that ``set_state`` and ``restart`` start from, ``all_envs``), the episodes' state (``episodes``: the
    kernels' ``Episodes`` struct of arrays) and each step's ``results`` (``StepResults``), the guards' per-shard
    counters, and the observations and final observations of the ``observations`` source; ``torch`` holds the tensor
    views."""

    def __init__(self, kernels, num_envs: int, num_roles: int, delay_steps: int, num_shards: int, observations,
                 device: str):
        n, k = num_envs, kernels

        def buf(dtype, shape=n):
            return wp.zeros(shape, dtype=dtype, device=device)

        self.kernels = kernels
        self.actions = buf(k.Actions)
        self.action_history = buf(k.Actions, (n, delay_steps + 1))
        self.actuator_f = buf(float, (n, num_roles))
        self.episodes = k.Episodes()
        for name, dtype in k.Episodes.vars.items():
            setattr(self.episodes, name, buf(dtype.type.dtype))
        self.results = k.StepResults()
        for name, dtype in k.StepResults.vars.items():
            setattr(self.results, name, buf(dtype.type.dtype))
        self.nonfinite_actions = buf(wp.int32, num_shards)
        self.nonfinite_states = buf(wp.int32, num_shards)
        self.diverged_states = buf(wp.int32, num_shards)
        self.states_in = buf(k.State)
        self.mask_in = buf(wp.bool)
        self.restart_in = buf(wp.int32)
        """1 where ``restart`` draws new physics (the draw's mask, as an end reason would be)."""
        self.all_envs = wp.full(n, True, dtype=wp.bool, device=device)
        self.obs, self.final_obs = observations.buffers(self.episodes.obs, self.results.final_obs)
        self.torch = self._views()

    def _views(self) -> SimpleNamespace:
        r = self.results
        return SimpleNamespace(
            actions=wp.to_torch(self.actions), state_obs=wp.to_torch(self.episodes.obs), obs=wp.to_torch(self.obs),
            final_state=wp.to_torch(r.final_state), reward=wp.to_torch(r.reward),
            terminated=wp.to_torch(r.terminated), truncated=wp.to_torch(r.truncated),
            time_out_count=wp.to_torch(self.episodes.time_out_count), states_in=wp.to_torch(self.states_in),
            mask_in=wp.to_torch(self.mask_in), restart_in=wp.to_torch(self.restart_in),
            info={"final_obs": wp.to_torch(self.final_obs), "episode_return": wp.to_torch(r.ended_return),
                  "episode_length": wp.to_torch(r.ended_length), "end_reason": wp.to_torch(r.end_reason)},
            counters={"nonfinite_actions": wp.to_torch(self.nonfinite_actions),
                      "nonfinite_states": wp.to_torch(self.nonfinite_states),
                      "diverged_states": wp.to_torch(self.diverged_states)})

    def structs_of(self, shard: Shard, role_dofs: wp.array) -> tuple:
        """(robot, episodes, results): the kernels' structs over the shard's scene and rows (views, made once)."""
        k, s = self.kernels, shard.scene
        robot = k.Robot()
        robot.joint_q, robot.joint_qd, robot.joint_f = s.state_0.joint_q, s.state_0.joint_qd, s.control.joint_f
        robot.dofs_per_env, robot.role_dofs = s.dofs_per_env, role_dofs
        views = []
        for whole, struct in ((self.episodes, k.Episodes), (self.results, k.StepResults)):
            part = struct()
            for name in struct.vars:
                setattr(part, name, shard.rows(getattr(whole, name)))
            views.append(part)
        return robot, *views
