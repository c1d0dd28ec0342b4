"""``BatchedEnv``: the machinery of a batched env on Newton and Warp, robot-agnostic. A task subclasses it with its
sizes, its stage and joint roles, and four Warp functions (``TaskFunctions``); everything else lives here.

One env step: clip actions to [-1, 1] -> joint forces of the task (of the action d steps ago, times the actuator scale,
with domain randomization) -> ``decimation`` solver steps (each after the joints' friction) -> observe, reward and end
reason of the task -> time limit, returns and lengths, keep the final observation -> masked reset of the ended envs
from the task's reset sampler -> new physics for them (``randomization``). All of it is Warp work on persistent arrays,
captured once as a graph per CPU shard (or on CUDA) and replayed. The kernels are built from the task's functions once
per task (Warp closures) and compiled into one module per task.
"""

import abc
import functools
import typing
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any, ClassVar

import warp as wp

from . import randomization
from .config import EnvConfig, TaskConfig
from .files import data_path
from .randomization import Physics, add_friction
from .runtime import Shard, ShardedStep, load_modules, resolve_device, shard_bounds, timed, warp_output
from .scene import SHARDABLE_SOLVERS, JointRole, Scene, build_scene, preloadable_modules, set_gradients

if TYPE_CHECKING:
    import torch  # imported where used: parsing a command line needs no torch

wp.set_module_options({"enable_backward": False})  # this module's kernels are never differentiated

END_NONE = wp.constant(0)
END_TIME_LIMIT = wp.constant(1)
END_NONFINITE = wp.constant(2)
END_DIVERGED = wp.constant(3)
FIRST_TASK_END = 4
"""A task's own end reasons (failures) are the codes FIRST_TASK_END, FIRST_TASK_END + 1, ... in its ``task_ends``."""
COMMON_ENDS = ("running", "time_limit", "nonfinite_state", "diverged_state")
"""Names of the codes 0-3 of ``end_reason``, the same for every task."""


def kernel_params(config_class: type[TaskConfig]) -> type:
    """The Warp struct of a task config's float fields, each under its own name: the task's constants in its
    Warp functions (written once, in the dataclass)."""
    fields = [name for name, kind in typing.get_type_hints(config_class).items() if kind is float]
    name = f"{config_class.__name__}Params"
    return wp.struct(type(name, (), {
        "__annotations__": dict.fromkeys(fields, float),
        "__module__": config_class.__module__,
        "__qualname__": name,
        "__doc__": f"The float fields of {config_class.__name__}, generated from it.",
    }))


def params_of(params_type: type, task: TaskConfig) -> Any:
    """The kernels' copy of a task config's constants."""
    params = params_type()
    for name in params_type.vars:
        setattr(params, name, getattr(task, name))
    return params


@dataclass(frozen=True)
class TaskFunctions:
    """A task's Warp functions (``@wp.func``). ``Joints`` is ``wp.types.vector(len(joint roles), float)`` in the order
    of the task's roles, ``Obs`` and ``Actions`` vectors of ``num_obs`` and ``num_actions`` floats, ``p`` the task's
    ``kernel_params`` struct."""

    observe: Any
    """``(q: Joints, qd: Joints, p) -> Obs``: the observation of a joint state."""
    evaluate: Any
    """``(q: Joints, qd: Joints, action: Actions, p) -> (reward: float, end: int)`` on the state after the physics
    step (``action`` already clipped to [-1, 1]); ``end`` is END_NONE or one of the task's codes (FIRST_TASK_END +
    i)."""
    sample_reset: Any
    """``(rng_state: wp.array(dtype=wp.uint32), env: int, p) -> (q: Joints, qd: Joints)``: a random start; advances
    ``rng_state[env]``."""
    joint_forces: Any
    """``(action: Actions, p) -> Joints``: the generalised force (N or N m) on each role's joint for an action."""


@wp.kernel
def init_rng(seed: int, first_env: int, rng_state: wp.array(dtype=wp.uint32)):
    """Seed each env's RNG from ``seed`` and its global index (``first_env`` + thread), whatever the sharding."""
    env = wp.tid()
    rng_state[env] = wp.rand_init(seed, first_env + env)


@functools.cache
def build_kernels(env_class: "type[BatchedEnv]") -> SimpleNamespace:  # noqa: UP037 (no __future__ annotations: Warp
    # reads the closure's kernel annotations as objects)
    """The env kernels of a task: the machinery's step, reset and set-state kernels with the task's functions inlined,
    one Warp module per task (compiled on first use, cached on disk)."""
    fns, num_joints, num_actions = env_class.functions, len(env_class.joint_roles), env_class.num_actions
    Joints = wp.types.vector(num_joints, float)
    Actions = wp.types.vector(env_class.num_actions, float)
    Obs = wp.types.vector(env_class.num_obs, float)
    State = wp.types.vector(2 * num_joints, float)
    Params = env_class.params_type
    module = f"{env_class.__module__}.{env_class.__qualname__}.kernels"
    kernel = functools.partial(wp.kernel, module=module, enable_backward=False)

    @wp.func
    def read_joints(joint_q: wp.array(dtype=float), joint_qd: wp.array(dtype=float), base: int,
                    role_dofs: wp.array(dtype=int)):
        q, qd = Joints(), Joints()
        for r in range(num_joints):
            q[r] = joint_q[base + role_dofs[r]]
            qd[r] = joint_qd[base + role_dofs[r]]
        return q, qd

    @wp.func
    def all_finite(q: Joints, qd: Joints):
        ok = True
        for r in range(num_joints):
            ok = ok and wp.isfinite(q[r]) and wp.isfinite(qd[r])
        return ok

    @wp.func
    def all_within(q: Joints, qd: Joints, limit: float):
        """Every joint position and velocity within +-``limit`` (so finite: a NaN fails the comparison)."""
        ok = True
        for r in range(num_joints):
            ok = ok and wp.abs(q[r]) <= limit and wp.abs(qd[r]) <= limit
        return ok

    @wp.func
    def noisy(o: Obs, noise_std: float, rng_state: wp.array(dtype=wp.uint32), env: int):
        """``o`` plus Gaussian noise of ``noise_std`` per element (none, and no draw, at 0)."""
        out = o
        if noise_std > 0.0:
            s = rng_state[env]
            for i in range(env_class.num_obs):
                out[i] = out[i] + noise_std * wp.randn(s)
            rng_state[env] = s
        return out

    @wp.func
    def begin_episode(env: int, q: Joints, qd: Joints, p: Params, noise_std: float, base: int, dofs_per_env: int,
                      role_dofs: wp.array(dtype=int), rng_state: wp.array(dtype=wp.uint32),
                      joint_q: wp.array(dtype=float), joint_qd: wp.array(dtype=float),
                      last_q: wp.array(dtype=Joints), last_qd: wp.array(dtype=Joints), obs: wp.array(dtype=Obs),
                      episode_length: wp.array(dtype=wp.int32), steps_run: wp.array(dtype=wp.int32),
                      episode_return: wp.array(dtype=float)):
        for d in range(dofs_per_env):
            joint_q[base + d] = 0.0
            joint_qd[base + d] = 0.0
        for r in range(num_joints):
            joint_q[base + role_dofs[r]] = q[r]
            joint_qd[base + role_dofs[r]] = qd[r]
        last_q[env] = q
        last_qd[env] = qd
        obs[env] = noisy(fns.observe(q, qd, p), noise_std, rng_state, env)
        episode_length[env] = 0
        steps_run[env] = 0
        episode_return[env] = 0.0

    @kernel
    def apply_actions(p: Params, dofs_per_env: int, role_dofs: wp.array(dtype=int),
                      steps_run: wp.array(dtype=wp.int32), delay: wp.array(dtype=wp.int32),
                      actuator_scale: wp.array(dtype=float), actions: wp.array(dtype=Actions),
                      action_history: wp.array2d(dtype=Actions), joint_f: wp.array(dtype=float),
                      actuator_f: wp.array2d(dtype=float), nonfinite_action_count: wp.array(dtype=wp.int32)):
        """Clip each action to [-1, 1] in place (a non-finite one becomes 0 and is counted), keep it in the env's
        action history, then write the task's joint forces for the action ``delay`` steps ago (none before the
        episode's first), times ``actuator_scale``."""
        env = wp.tid()
        a = actions[env]
        finite = True
        for i in range(num_actions):
            finite = finite and wp.isfinite(a[i])
        if not finite:
            a = Actions()
            wp.atomic_add(nonfinite_action_count, 0, 1)
        for i in range(num_actions):
            a[i] = wp.clamp(a[i], -1.0, 1.0)
        actions[env] = a
        slots = action_history.shape[1]
        step = steps_run[env]
        action_history[env, step % slots] = a
        applied = Actions()
        if step >= delay[env]:
            applied = action_history[env, (step - delay[env]) % slots]
        forces = fns.joint_forces(applied, p) * actuator_scale[env]
        base = env * dofs_per_env
        for r in range(num_joints):
            joint_f[base + role_dofs[r]] = forces[r]
            actuator_f[env, r] = forces[r]

    @kernel
    def random_actions(rng_state: wp.array(dtype=wp.uint32), actions: wp.array(dtype=Actions)):
        """Uniform random actions in [-1, 1] (the physics-alone benchmark)."""
        env = wp.tid()
        s = rng_state[env]
        a = Actions()
        for i in range(num_actions):
            a[i] = wp.randf(s, -1.0, 1.0)
        rng_state[env] = s
        actions[env] = a

    @kernel
    def finish_step(p: Params, noise_std: float, divergence_limit: float, dofs_per_env: int,
                    role_dofs: wp.array(dtype=int), max_episode_length: int, actions: wp.array(dtype=Actions),
                    rng_state: wp.array(dtype=wp.uint32),
                    joint_q: wp.array(dtype=float), joint_qd: wp.array(dtype=float), last_q: wp.array(dtype=Joints),
                    last_qd: wp.array(dtype=Joints), obs: wp.array(dtype=Obs), episode_length: wp.array(dtype=wp.int32),
                    steps_run: wp.array(dtype=wp.int32), episode_return: wp.array(dtype=float),
                    reward: wp.array(dtype=float), terminated: wp.array(dtype=wp.bool),
                    truncated: wp.array(dtype=wp.bool), final_obs: wp.array(dtype=Obs),
                    ended_return: wp.array(dtype=float), ended_length: wp.array(dtype=wp.int32),
                    end_reason: wp.array(dtype=wp.int32), nonfinite_state_count: wp.array(dtype=wp.int32),
                    diverged_state_count: wp.array(dtype=wp.int32)):
        """After the physics: observe, reward, end reason, time limit; keep the final observation; reset ended envs.

        A non-finite physics state, or one with a joint position or velocity beyond ``divergence_limit`` (runaway
        physics), ends the episode with reward 0 and is counted; its final observation is the last sound one, and its
        end reason that state's (a task failure when it was already beyond the task's limits, else
        'nonfinite_state' or 'diverged_state'). ``episode_length`` counts toward the time limit (rsl-rl may start it
        at random values); ``steps_run`` counts the steps the episode really ran, which ``ended_length`` reports."""
        env = wp.tid()
        base = env * dofs_per_env
        q, qd = read_joints(joint_q, joint_qd, base, role_dofs)
        length = episode_length[env] + 1
        steps = steps_run[env] + 1
        a = actions[env]
        o = obs[env]
        r = float(0.0)  # noqa: UP018 (a Warp variable that the branch below assigns, not a constant)
        reason = END_NONE
        if all_within(q, qd, divergence_limit):
            o = noisy(fns.observe(q, qd, p), noise_std, rng_state, env)
            r, reason = fns.evaluate(q, qd, a, p)
        else:
            unused, reason = fns.evaluate(last_q[env], last_qd[env], a, p)
            if all_finite(q, qd):
                wp.atomic_add(diverged_state_count, 0, 1)
                if reason == END_NONE:
                    reason = END_DIVERGED
            else:
                wp.atomic_add(nonfinite_state_count, 0, 1)
                if reason == END_NONE:
                    reason = END_NONFINITE
        if reason == END_NONE and length >= max_episode_length:
            reason = END_TIME_LIMIT
        ret = episode_return[env] + r
        reward[env] = r
        terminated[env] = reason != END_NONE and reason != END_TIME_LIMIT
        truncated[env] = reason == END_TIME_LIMIT
        final_obs[env] = o
        end_reason[env] = reason
        if reason == END_NONE:
            obs[env] = o
            last_q[env] = q
            last_qd[env] = qd
            episode_length[env] = length
            steps_run[env] = steps
            episode_return[env] = ret
        else:
            ended_return[env] = ret
            ended_length[env] = steps
            q0, qd0 = fns.sample_reset(rng_state, env, p)
            begin_episode(env, q0, qd0, p, noise_std, base, dofs_per_env, role_dofs, rng_state, joint_q, joint_qd,
                          last_q, last_qd, obs, episode_length, steps_run, episode_return)

    @kernel
    def reset_masked(mask: wp.array(dtype=wp.bool), p: Params, noise_std: float, dofs_per_env: int,
                     role_dofs: wp.array(dtype=int), rng_state: wp.array(dtype=wp.uint32),
                     joint_q: wp.array(dtype=float),
                     joint_qd: wp.array(dtype=float), last_q: wp.array(dtype=Joints), last_qd: wp.array(dtype=Joints),
                     obs: wp.array(dtype=Obs), episode_length: wp.array(dtype=wp.int32),
                     steps_run: wp.array(dtype=wp.int32), episode_return: wp.array(dtype=float)):
        """Start a new episode from the task's random start in every env where ``mask`` is set."""
        env = wp.tid()
        if mask[env]:
            q, qd = fns.sample_reset(rng_state, env, p)
            begin_episode(env, q, qd, p, noise_std, env * dofs_per_env, dofs_per_env, role_dofs, rng_state, joint_q,
                          joint_qd, last_q, last_qd, obs, episode_length, steps_run, episode_return)

    @kernel
    def set_states_masked(states: wp.array(dtype=State), mask: wp.array(dtype=wp.bool), p: Params,
                          noise_std: float, dofs_per_env: int, role_dofs: wp.array(dtype=int),
                          rng_state: wp.array(dtype=wp.uint32), joint_q: wp.array(dtype=float),
                          joint_qd: wp.array(dtype=float), last_q: wp.array(dtype=Joints),
                          last_qd: wp.array(dtype=Joints), obs: wp.array(dtype=Obs),
                          episode_length: wp.array(dtype=wp.int32), steps_run: wp.array(dtype=wp.int32),
                          episode_return: wp.array(dtype=float)):
        """Start a new episode from ``states`` (per joint role: position, velocity) where ``mask`` is set."""
        env = wp.tid()
        if mask[env]:
            s = states[env]
            q, qd = Joints(), Joints()
            for r in range(num_joints):
                q[r] = s[2 * r]
                qd[r] = s[2 * r + 1]
            begin_episode(env, q, qd, p, noise_std, env * dofs_per_env, dofs_per_env, role_dofs, rng_state, joint_q,
                          joint_qd, last_q, last_qd, obs, episode_length, steps_run, episode_return)

    return SimpleNamespace(Joints=Joints, Actions=Actions, Obs=Obs, State=State, apply_actions=apply_actions,
                           random_actions=random_actions, finish_step=finish_step, reset_masked=reset_masked,
                           set_states_masked=set_states_masked)


class BatchedEnv(abc.ABC):
    """``num_envs`` copies of a task's robot stepped together on persistent Warp buffers (the machinery of every task).

    A task subclass sets the class attributes below and keeps its spec (observation, action, reward, ends, reset) in
    its docstring. Envs that end are reset within the same ``step``: the returned observation is the new episode's
    first one, and ``info["final_obs"]`` holds the observation at which the episode ended. ``step`` returns fresh
    tensors; ``obs_buf`` and friends are the zero-copy views the next step overwrites.

    ``info`` keys (tensors on ``device``): ``final_obs`` (N, num_obs); ``episode_return`` (N,), ``episode_length``
    (N,) and ``end_reason`` (N,) int32 (codes named by ``end_reasons``), valid where terminated | truncated;
    ``nonfinite_actions``, ``nonfinite_states`` and ``diverged_states`` (scalars, totals since construction):
    non-finite actions are applied as 0, and a non-finite physics state, or one beyond ``sim.divergence_limit``, ends
    its episode (reward 0) with the last sound observation.

    On the CPU the envs are split into ``shards`` (one Newton scene each) stepped in parallel threads
    (``sim.cpu_threads``); results do not depend on the split. ``scene`` is the scene holding env 0.

    Each env simulates its own physical parameters (``physical_params()``): the stage's, or drawn by the config's
    ``randomization`` at each episode start (or once), or set by ``set_physical_params``.
    """

    config_class: ClassVar[type[TaskConfig]]
    """The task's settings (``env.task``)."""
    params_type: ClassVar[type]
    """``kernel_params(config_class)``: the struct the task's functions take."""
    num_obs: ClassVar[int]
    num_actions: ClassVar[int]
    stage: ClassVar[str | Path]
    """The task's stage: a file name in the package's usd/ folder, or the Path of a stage elsewhere (e.g. in an
    installed package); ``sim.stage_path`` names another."""
    joint_roles: ClassVar[tuple[str, ...]]
    """The roles of the joints the task drives or reads, in the order of its ``Joints`` vectors."""
    task_ends: ClassVar[tuple[str, ...]] = ()
    """Names of the task's failure codes FIRST_TASK_END, FIRST_TASK_END + 1, ..."""
    obs_mirror: ClassVar[tuple[float, ...] | None] = None
    """The task's left-right symmetry, where it has one: the signs that turn an observation into that of the mirrored
    state (every joint position and velocity negated); training appends mirrored samples to PPO's mini-batches
    (``agent.algorithm.symmetry``). None: no symmetry."""
    action_mirror: ClassVar[tuple[float, ...] | None] = None
    """The signs that mirror an action, with ``obs_mirror``."""
    functions: ClassVar[TaskFunctions]

    @abc.abstractmethod
    def joints(self, task: TaskConfig) -> list[JointRole]:
        """The stage's joint for each role of ``joint_roles`` (name and type), from the task's settings."""

    def __init__(self, cfg: EnvConfig):
        self.cfg = cfg.validate()
        with warp_output(cfg.verbose):
            self._build(cfg)

    def _build(self, cfg: EnvConfig):
        """Scene, buffers, first reset and the step's graphs: every Warp module the env steps with is loaded here."""
        self.build_time_s: dict[str, float] = {}
        """Seconds the construction took: 'newton' (Warp's start-up and Newton's import, in a process's first env),
        'kernels' (loading or compiling the Warp modules, first launches), 'scene' (stage import, replication,
        solver), 'capture' (the step's graphs)."""
        with timed(self.build_time_s, "newton"):
            self.device = resolve_device(cfg.device)
            joints = self.joints(cfg.task)
        self.num_envs = cfg.num_envs
        self.max_episode_length = cfg.max_episode_length
        self.env_dt = cfg.sim.env_dt
        self.end_reasons = COMMON_ENDS + self.task_ends
        """Names of the ``end_reason`` codes, by code."""
        self._kernels = build_kernels(type(self))
        stage = (Path(cfg.sim.stage_path) if cfg.sim.stage_path
                 else self.stage if isinstance(self.stage, Path) else data_path("usd", self.stage))
        cfg.randomization.validate(self.joint_roles)
        bounds = shard_bounds(cfg.num_envs, self.device, cfg.sim.cpu_threads, cfg.sim.solver in SHARDABLE_SOLVERS)
        with timed(self.build_time_s, "kernels"):
            set_gradients(cfg.sim.solver, cfg.sim.gradients)
            load_modules(self.warp_modules(), self.device, type(self).__name__)
        with timed(self.build_time_s, "scene"):
            self.shards = [Shard(i, start, stop, build_scene(stop - start, self.device, cfg.sim, stage, joints))
                           for i, (start, stop) in enumerate(bounds)]
        self.params = params_of(self.params_type, cfg.task)
        self._role_dofs = wp.array(self.scene.role_dofs, dtype=int, device=self.device)
        from .streams import TorchOrder  # torch, imported once an env is built

        self._order = TorchOrder(self.device)
        self.physics = Physics(cfg.randomization, self.joint_roles, [joint.kind for joint in joints], self.scene,
                               self.num_envs, self.device)
        """The per-env physical parameters and their draws."""
        self._noise_std = float(cfg.randomization.obs_noise_std)
        self._allocate()
        with timed(self.build_time_s, "kernels"):
            self._seed(cfg.seed)
            self._reset_all()
            wp.synchronize_device(self.device)
        with timed(self.build_time_s, "capture"):
            self._step = ShardedStep(self.shards, self._step_kernels, self._order, capture=cfg.sim.capture != "off")

    def warp_modules(self) -> list[wp.Module]:
        """The Warp modules this env launches kernels of (loaded when it is built): Newton's (but mujoco-warp's), the
        machinery's, the randomization's and the task's."""
        return [*preloadable_modules(self.cfg.sim.solver), wp.get_module(__name__),
                wp.get_module(randomization.__name__), self._kernels.finish_step.module]

    @property
    def scene(self) -> Scene:
        """The Newton scene holding env 0 (all envs unless the CPU shards them)."""
        return self.shards[0].scene

    def _allocate(self):
        n, dev, k = self.num_envs, self.device, self._kernels

        def buf(dtype, shape=n):
            return wp.zeros(shape, dtype=dtype, device=dev)

        self._rng_state = buf(wp.uint32)
        self._actions = buf(k.Actions)
        self._action_history = buf(k.Actions, (n, self.cfg.randomization.action_delay_steps + 1))
        self._actuator_f = buf(float, (n, len(self.joint_roles)))
        self._obs = buf(k.Obs)
        self._final_obs = buf(k.Obs)
        self._last_q = buf(k.Joints)
        self._last_qd = buf(k.Joints)
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
        self._diverged_states = buf(wp.int32, len(self.shards))
        self._states_in = buf(k.State)
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
            "diverged_states": wp.to_torch(self._diverged_states),
        }

    @property
    def episode_length_buf(self) -> "torch.Tensor":
        """(N,) int32 time-out counter: the episode is truncated when it reaches ``max_episode_length`` (zero-copy;
        assigning copies into it, as rsl-rl's ``init_at_random_ep_len`` does to spread the time-outs). The
        ``episode_length`` reported at the end is the steps the episode really ran, whatever was assigned."""
        return self._episode_length_t

    @episode_length_buf.setter
    def episode_length_buf(self, value: "torch.Tensor"):
        self._episode_length_t.copy_(value)

    def _apply_actions(self, shard: Shard):
        s, rows, physics = shard.scene, shard.rows, self.physics
        wp.launch(self._kernels.apply_actions, dim=shard.num_envs,
                  inputs=[self.params, s.dofs_per_env, self._role_dofs, rows(self._steps_run), rows(physics.delay),
                          rows(physics.actuator_scale)],
                  outputs=[rows(self._actions), rows(self._action_history), s.control.joint_f, rows(self._actuator_f),
                           shard.slot(self._nonfinite_actions)],
                  device=self.device)

    def _simulate(self, shard: Shard):
        """``decimation`` solver steps, each after the joints' friction where it is randomized."""
        s = shard.scene
        add_joint_friction = None
        if self.physics.has_friction:
            def add_joint_friction():
                wp.launch(add_friction, dim=shard.num_envs,
                          inputs=[s.dofs_per_env, self._role_dofs, shard.rows(self._actuator_f),
                                  shard.rows(self.physics.friction), s.state_0.joint_qd],
                          outputs=[s.control.joint_f], device=self.device)
        s.simulate(self.cfg.sim.physics_dt, self.cfg.sim.decimation, add_joint_friction)

    def physics_step(self, shard: Shard):
        """Random actions in [-1, 1], the task's joint forces and ``decimation`` solver steps for one shard: an env step
        without observations, rewards or resets (what ``tools.bench`` times as the physics alone)."""
        wp.launch(self._kernels.random_actions, dim=shard.num_envs, inputs=[shard.rows(self._rng_state)],
                  outputs=[shard.rows(self._actions)], device=self.device)
        self._apply_actions(shard)
        self._simulate(shard)

    def _step_kernels(self, shard: Shard):
        s, rows, k = shard.scene, shard.rows, self._kernels
        self._apply_actions(shard)
        self._simulate(shard)
        wp.launch(
            k.finish_step, dim=shard.num_envs,
            inputs=[self.params, self._noise_std, self.cfg.sim.divergence_limit, s.dofs_per_env, self._role_dofs,
                    self.max_episode_length, rows(self._actions)],
            outputs=[rows(self._rng_state), s.state_0.joint_q, s.state_0.joint_qd, rows(self._last_q),
                     rows(self._last_qd), rows(self._obs), rows(self._episode_length), rows(self._steps_run),
                     rows(self._episode_return), rows(self._reward), rows(self._terminated), rows(self._truncated),
                     rows(self._final_obs), rows(self._ended_return), rows(self._ended_length), rows(self._end_reason),
                     shard.slot(self._nonfinite_states), shard.slot(self._diverged_states)],
            device=self.device,
        )
        if self.physics.drawn and self.cfg.randomization.at == "reset":
            self.physics.draw(shard, self._rng_state, self._end_reason)

    def _episode_outputs(self, shard: Shard) -> list:
        s, rows = shard.scene, shard.rows
        return [s.state_0.joint_q, s.state_0.joint_qd, rows(self._last_q), rows(self._last_qd), rows(self._obs),
                rows(self._episode_length), rows(self._steps_run), rows(self._episode_return)]

    def _seed(self, seed: int):
        for shard in self.shards:
            wp.launch(init_rng, dim=shard.num_envs, inputs=[int(seed), shard.start],
                      outputs=[shard.rows(self._rng_state)], device=self.device)

    def _reset_all(self):
        """A new episode in every env, and new physics where it is randomized."""
        for shard in self.shards:
            wp.launch(self._kernels.reset_masked, dim=shard.num_envs,
                      inputs=[shard.rows(self._all_envs), self.params, self._noise_std, shard.scene.dofs_per_env,
                              self._role_dofs],
                      outputs=[shard.rows(self._rng_state), *self._episode_outputs(shard)], device=self.device)
            if self.physics.drawn:
                self.physics.draw(shard, self._rng_state, None)

    def _check(self, name: str, value, shapes: tuple, dtype: "torch.dtype") -> "torch.Tensor":
        import torch

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

    def reset(self, seed: int | None = None) -> "tuple[torch.Tensor, dict]":
        """Start a new episode in every env (re-seeding the RNG when ``seed`` is given): (obs, info)."""
        with self._order:
            if seed is not None:
                self._seed(seed)
            self._reset_all()
        return self.obs_buf.clone(), self._outputs()

    def step(self, actions: "torch.Tensor"):
        """Apply actions for one env step: (obs, reward, terminated, truncated, info), autoresetting ended envs."""
        import torch

        n, a = self.num_envs, self.num_actions
        shapes = ((n, a), (n,)) if a == 1 else ((n, a),)
        actions = self._check("actions", actions, shapes, torch.float32)
        self.actions_buf.copy_(actions.reshape(n, a))
        self._step()
        return (self.obs_buf.clone(), self.reward_buf.clone(), self.terminated_buf.clone(),
                self.truncated_buf.clone(), self._outputs())

    def set_state(self, states: "torch.Tensor", mask: "torch.Tensor | None" = None) -> "torch.Tensor":
        """Start new episodes from ``states`` (N, 2 x joint roles): for each role in ``joint_roles`` order, its
        position (m or rad) then its velocity (m/s or rad/s); where ``mask`` (N,) bool is set (everywhere by default).
        Returns the observations."""
        import torch

        n = self.num_envs
        states = self._check("states", states, ((n, 2 * len(self.joint_roles)),), torch.float32)
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
                wp.launch(self._kernels.set_states_masked, dim=shard.num_envs,
                          inputs=[shard.rows(self._states_in), shard.rows(self._mask_in), self.params,
                                  self._noise_std, shard.scene.dofs_per_env, self._role_dofs],
                          outputs=[shard.rows(self._rng_state), *self._episode_outputs(shard)], device=self.device)
        return self.obs_buf.clone()

    def physical_params(self) -> "dict[str, torch.Tensor]":
        """What each env simulates, in SI units: (N,) tensors named by what they are. Per joint role:
        ``<role>_mass_kg`` of the body the role's joint moves, ``<role>_com_m`` (distance from the joint to that body's
        centre of mass), ``<role>_inertia_kg_m2`` (about the centre of mass, around the joint's axis),
        ``<role>_damping_n_s_m`` or ``_n_m_s_rad``, ``<role>_friction_n`` or ``_n_m``; then ``actuator_scale`` (on
        the task's forces), ``gravity_m_s2``, ``action_delay_steps``, and the task's own (``task_physical_params``)."""
        values = self.physics.values()
        return values | self.task_physical_params(values)

    def task_physical_params(self, values: "dict[str, torch.Tensor]") -> "dict[str, torch.Tensor]":
        """The task's own physical parameters, derived from the machinery's ``values`` (none by default)."""
        return {}

    def set_physical_params(self, **values: "torch.Tensor"):
        """Set what the named envs simulate from now on: (N,) tensors on ``device`` in SI units, named as in
        ``physical_params`` (derived values excepted); the others keep theirs. With randomization ``at='reset'``, an
        env's next episode start draws anew."""
        import torch

        n = self.num_envs
        for name, value in values.items():
            self._check(name, value, ((n,),), value.dtype if isinstance(value, torch.Tensor) else torch.float32)
        self.physics.set(values)
        with self._order, warp_output(self.cfg.verbose):
            for shard in self.shards:
                self.physics.write(shard)

    def close(self):
        """Stop the shard threads (the env cannot step afterwards)."""
        self._step.close()

    def get_observations(self) -> "torch.Tensor":
        """The current observations (N, num_obs), a fresh tensor."""
        return self.obs_buf.clone()
