"""``CartpoleEnv``: the batched cartpole on persistent Warp buffers, with a captured step and autoreset."""

from __future__ import annotations

import torch
import warp as wp

from . import kernels
from .config import EnvConfig, env_config
from .runtime import Shard, ShardedStep, TorchOrder, resolve_device, shard_bounds
from .scene import SHARDABLE_SOLVERS, Scene, build_scene


class CartpoleEnv:
    """Batched cartpole, the Isaac Sim "Custom RL Example using Stable Baselines" task.

    ==============  ==================================================================================
    observation     (N, 4) float32: [cart_pos (m), cart_vel (m/s), pole_angle (rad), pole_vel (rad/s)]
    action          (N, 1) or (N,) float32, clipped to [-1, 1]; cart force = max_push_effort_n * action
    reward          1 - pole_angle^2 - 0.01 |cart_vel| - 0.005 |pole_vel|; -2 on the terminating step
    terminated      |cart_pos| > 3 m or |pole_angle| > pi/2, on the state after the physics step
    truncated       episode length reaches ``max_episode_length`` env steps (not terminated)
    reset           cart_pos ~ U(-1, 1), cart_vel ~ U(-0.5, 0.5), pole_angle ~ U(-pi/8, pi/8),
                    pole_vel ~ U(-pi/4, pi/4); one RNG state per env, seeded by ``seed``
    ==============  ==================================================================================

    Envs that end are reset within the same ``step``: the returned observation is the new episode's
    first one, and ``info["final_obs"]`` holds the observation at which the episode ended. ``step`` returns
    fresh tensors; ``obs_buf`` and friends are the zero-copy views the next step overwrites.

    ``info`` keys (tensors on ``device``): ``final_obs`` (N, 4); ``episode_return`` (N,), ``episode_length``
    (N,) and ``end_reason`` (N,) int32 (codes named by ``kernels.END_REASONS``), valid where
    terminated | truncated; ``nonfinite_actions`` and ``nonfinite_states`` (scalars, totals since construction):
    non-finite actions are applied as 0, and a non-finite physics state ends its episode as a failure whose
    ``final_obs`` is the last finite observation.

    On the CPU the envs are split into ``shards`` (one Newton scene each) stepped in parallel threads
    (``sim.cpu_threads``); results do not depend on the split. ``scene`` is the scene holding env 0.
    """

    num_actions = 1
    num_obs = 4

    def __init__(self, cfg: EnvConfig):
        self.cfg = cfg.validate()
        self.device = resolve_device(cfg.device)
        self.num_envs = cfg.num_envs
        self.max_episode_length = cfg.max_episode_length
        self.env_dt = cfg.sim.env_dt
        bounds = shard_bounds(cfg.num_envs, self.device, cfg.sim.cpu_threads, cfg.sim.solver in SHARDABLE_SOLVERS)
        self.shards = [Shard(i, start, stop, build_scene(stop - start, self.device, cfg.sim))
                       for i, (start, stop) in enumerate(bounds)]
        self.params = kernels.task_params(cfg.task)
        self.layout = kernels.dof_layout(self.scene.dofs_per_env, self.scene.cart_dof, self.scene.pole_dof)
        self._order = TorchOrder(self.device)
        self._allocate()
        self._seed(cfg.seed)
        self._launch_reset(self._all_envs)
        self._step = ShardedStep(self.shards, self._step_kernels, self._order, capture=cfg.sim.capture != "off")

    @property
    def scene(self) -> Scene:
        """The Newton scene holding env 0 (all envs unless the CPU shards them)."""
        return self.shards[0].scene

    def _allocate(self):
        n, dev = self.num_envs, self.device

        def buf(dtype, shape=n):
            return wp.zeros(shape, dtype=dtype, device=dev)

        self._rng_state = buf(wp.uint32)
        self._actions = buf(float)
        self._obs = buf(wp.vec4)
        self._final_obs = buf(wp.vec4)
        self._reward = buf(float)
        self._terminated = buf(wp.bool)
        self._truncated = buf(wp.bool)
        self._episode_length = buf(wp.int32)
        self._steps_run = buf(wp.int32)
        self._episode_return = buf(float)
        self._ended_return = buf(float)
        self._ended_length = buf(wp.int32)
        self._end_reason = buf(wp.int32)
        self._nonfinite_actions = buf(wp.int32, len(self.shards))
        self._nonfinite_states = buf(wp.int32, len(self.shards))
        self._states_in = buf(wp.vec4)
        self._mask_in = buf(wp.bool)
        self._all_envs = wp.full(n, True, dtype=wp.bool, device=dev)

        self.actions_buf = wp.to_torch(self._actions)
        self.obs_buf = wp.to_torch(self._obs)
        self.reward_buf = wp.to_torch(self._reward)
        self.terminated_buf = wp.to_torch(self._terminated)
        self.truncated_buf = wp.to_torch(self._truncated)
        self._episode_length_t = wp.to_torch(self._episode_length)
        self._states_in_t = wp.to_torch(self._states_in)
        self._mask_in_t = wp.to_torch(self._mask_in)
        self._info_views = {
            "final_obs": wp.to_torch(self._final_obs),
            "episode_return": wp.to_torch(self._ended_return),
            "episode_length": wp.to_torch(self._ended_length),
            "end_reason": wp.to_torch(self._end_reason),
        }
        self._counter_views = {
            "nonfinite_actions": wp.to_torch(self._nonfinite_actions),
            "nonfinite_states": wp.to_torch(self._nonfinite_states),
        }

    @property
    def episode_length_buf(self) -> torch.Tensor:
        """(N,) int32 time-out counter: the episode is truncated when it reaches ``max_episode_length`` (zero-copy;
        assigning copies into it, as rsl-rl's ``init_at_random_ep_len`` does to spread the time-outs). The
        ``episode_length`` reported at the end is the steps the episode really ran, whatever was assigned."""
        return self._episode_length_t

    @episode_length_buf.setter
    def episode_length_buf(self, value: torch.Tensor):
        self._episode_length_t.copy_(value)

    def _step_kernels(self, shard: Shard):
        s, rows = shard.scene, shard.rows
        wp.launch(kernels.apply_actions, dim=shard.num_envs, inputs=[rows(self._actions), self.params, self.layout],
                  outputs=[s.control.joint_f, shard.slot(self._nonfinite_actions)], device=self.device)
        s.simulate(self.cfg.sim.physics_dt, self.cfg.sim.decimation)
        wp.launch(
            kernels.finish_step, dim=shard.num_envs,
            inputs=[self.params, self.layout, self.max_episode_length],
            outputs=[rows(self._rng_state), s.state_0.joint_q, s.state_0.joint_qd, rows(self._obs),
                     rows(self._episode_length), rows(self._steps_run), rows(self._episode_return),
                     rows(self._reward), rows(self._terminated), rows(self._truncated), rows(self._final_obs),
                     rows(self._ended_return), rows(self._ended_length), rows(self._end_reason),
                     shard.slot(self._nonfinite_states)],
            device=self.device,
        )

    def _seed(self, seed: int):
        for shard in self.shards:
            wp.launch(kernels.init_rng, dim=shard.num_envs, inputs=[int(seed), shard.start],
                      outputs=[shard.rows(self._rng_state)], device=self.device)

    def _launch_reset(self, mask: wp.array):
        for shard in self.shards:
            s, rows = shard.scene, shard.rows
            wp.launch(kernels.reset_masked, dim=shard.num_envs, inputs=[rows(mask), self.params, self.layout],
                      outputs=[rows(self._rng_state), s.state_0.joint_q, s.state_0.joint_qd, rows(self._obs),
                               rows(self._episode_length), rows(self._steps_run), rows(self._episode_return)],
                      device=self.device)

    def _check(self, name: str, value, shapes: tuple, dtype: torch.dtype) -> torch.Tensor:
        shape = " or ".join(str(tuple(s)) for s in shapes)
        expected = f"a torch.Tensor of shape {shape}, dtype {dtype}, on {self.device}"
        if not isinstance(value, torch.Tensor):
            raise ValueError(f"{name}: expected {expected}; got {type(value).__name__}")
        if tuple(value.shape) not in [tuple(s) for s in shapes]:
            raise ValueError(f"{name}: expected {expected}; got shape {tuple(value.shape)}")
        if value.dtype != dtype:
            raise ValueError(f"{name}: expected {expected}; got dtype {value.dtype}")
        if value.device != torch.device(self.device):
            raise ValueError(f"{name}: expected {expected}; got device {value.device}")
        return value

    def _outputs(self):
        info = {k: v.clone() for k, v in self._info_views.items()}
        info.update({k: v.sum() for k, v in self._counter_views.items()})
        return info

    def reset(self, seed: int | None = None) -> tuple[torch.Tensor, dict]:
        """Start a new episode in every env (re-seeding the RNG when ``seed`` is given): (obs, info)."""
        with self._order:
            if seed is not None:
                self._seed(seed)
            self._launch_reset(self._all_envs)
        return self.obs_buf.clone(), self._outputs()

    def step(self, actions: torch.Tensor):
        """Apply actions for one env step: (obs, reward, terminated, truncated, info), autoresetting ended envs."""
        n = self.num_envs
        actions = self._check("actions", actions, ((n, 1), (n,)), torch.float32)
        self.actions_buf.copy_(actions.reshape(n))
        self._step()
        return (self.obs_buf.clone(), self.reward_buf.clone(), self.terminated_buf.clone(),
                self.truncated_buf.clone(), self._outputs())

    def set_state(self, states: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """Start new episodes from ``states`` (N, 4) [cart_pos, cart_vel, pole_angle, pole_vel] where ``mask``
        (N,) bool is set (everywhere by default); returns the observations."""
        n = self.num_envs
        states = self._check("states", states, ((n, 4),), torch.float32)
        if not torch.isfinite(states).all():
            raise ValueError("states: every value must be finite")
        mask = self._check("mask", mask, ((n,),), torch.bool) if mask is not None else None
        self._states_in_t.copy_(states)
        if mask is None:
            self._mask_in_t.fill_(True)
        else:
            self._mask_in_t.copy_(mask)
        with self._order:
            for shard in self.shards:
                s, rows = shard.scene, shard.rows
                wp.launch(kernels.set_states_masked, dim=shard.num_envs,
                          inputs=[rows(self._states_in), rows(self._mask_in), self.layout],
                          outputs=[s.state_0.joint_q, s.state_0.joint_qd, rows(self._obs), rows(self._episode_length),
                                   rows(self._steps_run), rows(self._episode_return)], device=self.device)
        return self.obs_buf.clone()

    def close(self):
        """Stop the shard threads (the env cannot step afterwards)."""
        self._step.close()

    def get_observations(self) -> torch.Tensor:
        """The current observations (N, 4), a fresh tensor."""
        return self.obs_buf.clone()


def make_env(num_envs: int | None = None, device: str | None = None, seed: int | None = None,
             preset: str = "default", **sim_task_overrides) -> CartpoleEnv:
    """Build a ``CartpoleEnv`` from a preset ('default', 'tutorial' or a YAML path) and overrides.

    ``sim_task_overrides`` take nested dicts, e.g. ``sim={"solver": "mujoco"}``, ``task={"episode_length_s": 5}``.
    """
    return CartpoleEnv(env_config(preset, num_envs=num_envs, device=device, seed=seed, **sim_task_overrides))
