"""The Warp side of ``BatchedEnv``, robot-agnostic: end codes, the four functions a task writes (``TaskFunctions``),
the struct of a task config's constants (``kernel_constants``) and ``build_kernels``, which inlines a task's functions
into the machinery's kernels (one Warp module per task, compiled on first use and cached on disk).

The kernels take structs of arrays, one thread per env: ``Robot`` (the shard's joint state and forces), ``Episodes``
(each env's running episode), ``StepResults`` (what a step hands back) and ``StepSettings``.
"""

import functools
import typing
import warnings
from dataclasses import InitVar, dataclass, fields
from types import SimpleNamespace
from typing import Any

import warp as wp

from ..settings.config import EnvConfig, TaskConfig
from ..settings.deprecation import REMOVED_IN, caller_level, renamed
from .step_rules import (
    END_DIVERGED,
    END_NONE,
    END_NONFINITE,
    END_TIME_LIMIT,
    all_within,
    clip_actions,
    role_state,
    set_role_state,
    with_time_limit,
)

wp.set_module_options({"enable_backward": False})  # this module's kernels are never differentiated

FIRST_TASK_END = 4
"""A task's own end reasons (failures) are the codes FIRST_TASK_END, FIRST_TASK_END + 1, ... in its ``task_ends``."""
COMMON_ENDS = ("running", "time_limit", "nonfinite_state", "diverged_state")
"""Names of the codes 0-3 of ``end_reason``, the same for every task."""


def _struct(name: str, module: str, fields: dict[str, Any], doc: str) -> type:
    """A Warp struct named ``name`` (unique per task: Warp names a struct's code after its module and name)."""
    return wp.struct(type(name, (), {"__annotations__": fields, "__module__": module, "__qualname__": name,
                                      "__doc__": doc}))


@functools.cache
def kernel_constants(config_class: type[TaskConfig]) -> type:
    """The Warp struct of a task config's float fields, each under its own name: the task's constants in its Warp
    functions (written once, in the dataclass; one struct per config class, a subclass's with its own fields)."""
    fields = [name for name, kind in typing.get_type_hints(config_class).items() if kind is float]
    return _struct(f"{config_class.__name__}Constants", config_class.__module__, dict.fromkeys(fields, float),
                   f"The float fields of {config_class.__name__}, generated from it.")


def constants_of(config_class: type[TaskConfig], task: TaskConfig) -> Any:
    """The kernels' copy of a task config's constants (``task``: a ``config_class``)."""
    struct = kernel_constants(config_class)
    constants = struct()
    for name in struct.vars:
        setattr(constants, name, getattr(task, name))
    return constants


def step_settings(kernels: SimpleNamespace, cfg: EnvConfig) -> Any:
    """The kernels' ``StepSettings`` of an env's settings: observation noise, divergence limit, time limit (steps)."""
    settings = kernels.StepSettings()
    settings.noise_std = float(cfg.randomization.obs_noise_std)
    settings.divergence_limit = float(cfg.sim.divergence_limit)
    settings.max_episode_length = int(cfg.max_episode_length)
    return settings


@dataclass(frozen=True)
class TaskFunctions:
    """A task's Warp functions (``@wp.func``). ``Joints`` is ``wp.types.vector(len(joint roles), float)`` in the order
    of the task's roles, ``Obs`` and ``Actions`` vectors of ``num_obs`` and ``num_actions`` floats, ``p`` the struct
    of the task config's constants (``kernel_constants``): type it ``Any``, so that a variant's config reuses the
    function."""

    observe: Any
    """``(q: Joints, qd: Joints, p) -> Obs``: the observation of a joint state."""
    reward_and_end: Any = None
    """``(q: Joints, qd: Joints, action: Actions, p) -> (reward: float, end: int)`` on the state after the physics
    step (``action`` already clipped to [-1, 1]); ``end`` is END_NONE or one of the task's codes (FIRST_TASK_END +
    i)."""
    sample_reset: Any = None
    """``(rng_state: wp.array(dtype=wp.uint32), env: int, p) -> (q: Joints, qd: Joints)``: a random start; advances
    ``rng_state[env]``."""
    joint_forces: Any = None
    """``(action: Actions, p, forces: Joints) -> Joints``: ``forces`` (zero on every joint) with the generalised force
    (N or N m) of an action written on the joints it drives."""
    evaluate: InitVar[Any] = None
    """The old name of ``reward_and_end``, until ``REMOVED_IN`` (with a DeprecationWarning)."""

    def __post_init__(self, evaluate: Any):
        if evaluate is not None:
            warnings.warn("TaskFunctions(evaluate=...) is now TaskFunctions(reward_and_end=...); the old name goes "
                          f"in {REMOVED_IN}", DeprecationWarning, stacklevel=caller_level())
            object.__setattr__(self, "reward_and_end", evaluate)
        missing = [field.name for field in fields(self) if getattr(self, field.name) is None]
        if missing:
            raise TypeError(f"TaskFunctions: missing {', '.join(missing)}")


@wp.kernel
def init_rng(seed: int, first_env: int, rng_state: wp.array(dtype=wp.uint32)):
    """Seed each env's RNG from ``seed`` and its global index (``first_env`` + thread), whatever the sharding."""
    env = wp.tid()
    rng_state[env] = wp.rand_init(seed, first_env + env)


@functools.cache
def build_kernels(functions: TaskFunctions, config_class: type[TaskConfig], num_joints: int, num_actions: int,
                  num_obs: int, name: str) -> SimpleNamespace:
    """A task's env kernels and the structs they take: the machinery's step, reset and set-state kernels with the
    task's ``functions`` inlined, in the Warp module ``name``."""
    fns = functions
    Joints = wp.types.vector(num_joints, float)
    Actions = wp.types.vector(num_actions, float)
    Obs = wp.types.vector(num_obs, float)
    State = wp.types.vector(2 * num_joints, float)
    Constants = kernel_constants(config_class)
    kernel = functools.partial(wp.kernel, module=name, enable_backward=False)
    prefix = name.replace(".", "_")
    Robot = _struct(f"{prefix}_Robot", __name__, {
        "joint_q": wp.array(dtype=float), "joint_qd": wp.array(dtype=float), "joint_f": wp.array(dtype=float),
        "dofs_per_env": int, "role_dofs": wp.array(dtype=int)},
        "A shard's joint positions, velocities and forces (Newton's, ``dofs_per_env`` per env) and where each joint "
        "role's dof sits in an env's.")
    Episodes = _struct(f"{prefix}_Episodes", __name__, {
        "rng_state": wp.array(dtype=wp.uint32), "last_q": wp.array(dtype=Joints), "last_qd": wp.array(dtype=Joints),
        "obs": wp.array(dtype=Obs), "time_out_count": wp.array(dtype=wp.int32), "steps_run": wp.array(dtype=wp.int32),
        "episode_return": wp.array(dtype=float)},
        "Each env's running episode: RNG, last sound joint state, observation, the steps toward the time limit "
        "(rsl-rl's ``episode_length_buf``), the steps it really ran, its return.")
    StepResults = _struct(f"{prefix}_StepResults", __name__, {
        "reward": wp.array(dtype=float), "terminated": wp.array(dtype=wp.bool), "truncated": wp.array(dtype=wp.bool),
        "final_obs": wp.array(dtype=Obs), "final_state": wp.array(dtype=State), "ended_return": wp.array(dtype=float),
        "ended_length": wp.array(dtype=wp.int32), "end_reason": wp.array(dtype=wp.int32)},
        "What a step hands back per env; the ended episode's last sound joint state (per role: position, velocity), "
        "return, length and reason where it ended.")
    StepSettings = _struct(f"{prefix}_StepSettings", __name__, {
        "noise_std": float, "divergence_limit": float, "max_episode_length": int},
        "Observation noise, the joint magnitude beyond which physics counts as diverged, the time limit (steps).")

    @wp.func
    def read_joints(robot: Robot, env: int):
        return role_state(robot.joint_q, robot.joint_qd, robot.role_dofs, env * robot.dofs_per_env, Joints())

    @wp.func
    def all_finite(q: Joints, qd: Joints):
        ok = True
        for r in range(num_joints):
            ok = ok and wp.isfinite(q[r]) and wp.isfinite(qd[r])
        return ok

    @wp.func
    def noisy(o: Obs, noise_std: float, rng_state: wp.array(dtype=wp.uint32), env: int):
        """``o`` plus Gaussian noise of ``noise_std`` per element (none, and no draw, at 0)."""
        out = o
        if noise_std > 0.0:
            s = rng_state[env]
            for i in range(num_obs):
                out[i] = out[i] + noise_std * wp.randn(s)
            rng_state[env] = s
        return out

    @wp.func
    def begin_episode(env: int, q: Joints, qd: Joints, p: Constants, settings: StepSettings, robot: Robot,
                      episodes: Episodes):
        """Every dof of the env at 0, then the roles' joints at ``q``, ``qd``; a new episode's first observation."""
        base = env * robot.dofs_per_env
        for d in range(robot.dofs_per_env):
            robot.joint_q[base + d] = 0.0
            robot.joint_qd[base + d] = 0.0
        set_role_state(q, qd, robot.role_dofs, base, robot.joint_q, robot.joint_qd)
        episodes.last_q[env] = q
        episodes.last_qd[env] = qd
        episodes.obs[env] = noisy(fns.observe(q, qd, p), settings.noise_std, episodes.rng_state, env)
        episodes.time_out_count[env] = 0
        episodes.steps_run[env] = 0
        episodes.episode_return[env] = 0.0

    @wp.func
    def judge(env: int, q: Joints, qd: Joints, a: Actions, p: Constants, settings: StepSettings, episodes: Episodes,
              nonfinite_state_count: wp.array(dtype=wp.int32), diverged_state_count: wp.array(dtype=wp.int32)):
        """(observation, reward, end reason) of the state after the physics, the time limit aside. A non-finite
        state, or one beyond ``divergence_limit``, keeps the last sound observation, earns 0 and is counted; its end
        reason is that state's (a task failure when it was already beyond the task's limits)."""
        o = episodes.obs[env]
        r = float(0.0)  # noqa: UP018 (a Warp variable that the branch below assigns, not a constant)
        reason = END_NONE
        if all_within(q, qd, settings.divergence_limit):
            o = noisy(fns.observe(q, qd, p), settings.noise_std, episodes.rng_state, env)
            r, reason = fns.reward_and_end(q, qd, a, p)
        else:
            unused, reason = fns.reward_and_end(episodes.last_q[env], episodes.last_qd[env], a, p)
            if all_finite(q, qd):
                wp.atomic_add(diverged_state_count, 0, 1)
                if reason == END_NONE:
                    reason = END_DIVERGED
            else:
                wp.atomic_add(nonfinite_state_count, 0, 1)
                if reason == END_NONE:
                    reason = END_NONFINITE
        return o, r, reason

    @kernel
    def apply_actions(p: Constants, robot: Robot, episodes: Episodes, delay: wp.array(dtype=wp.int32),
                      actuator_scale: wp.array(dtype=float), actions: wp.array(dtype=Actions),
                      action_history: wp.array2d(dtype=Actions), actuator_f: wp.array2d(dtype=float),
                      nonfinite_action_count: wp.array(dtype=wp.int32)):
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
        a = clip_actions(a)
        actions[env] = a
        slots = action_history.shape[1]
        step = episodes.steps_run[env]
        action_history[env, step % slots] = a
        applied = Actions()
        if step >= delay[env]:
            applied = action_history[env, (step - delay[env]) % slots]
        forces = fns.joint_forces(applied, p, Joints()) * actuator_scale[env]
        base = env * robot.dofs_per_env
        for r in range(num_joints):
            robot.joint_f[base + robot.role_dofs[r]] = forces[r]
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
    def end_step(p: Constants, settings: StepSettings, robot: Robot, actions: wp.array(dtype=Actions),
                 episodes: Episodes, results: StepResults, nonfinite_state_count: wp.array(dtype=wp.int32),
                 diverged_state_count: wp.array(dtype=wp.int32)):
        """After the physics: judge the state (``judge``), apply the time limit, hand back the step's results and
        carry the episode on, or record its end and start the next from the task's random start.
        ``time_out_count`` counts toward the time limit (rsl-rl may start it at random values); ``steps_run`` counts
        the steps the episode really ran, which ``ended_length`` reports."""
        env = wp.tid()
        q, qd = read_joints(robot, env)
        o, r, reason = judge(env, q, qd, actions[env], p, settings, episodes, nonfinite_state_count,
                             diverged_state_count)
        count = episodes.time_out_count[env] + 1
        reason = with_time_limit(reason, count, settings.max_episode_length)
        ret = episodes.episode_return[env] + r
        results.reward[env] = r
        results.terminated[env] = reason != END_NONE and reason != END_TIME_LIMIT
        results.truncated[env] = reason == END_TIME_LIMIT
        results.final_obs[env] = o
        results.end_reason[env] = reason
        if reason == END_NONE:
            episodes.obs[env] = o
            episodes.last_q[env] = q
            episodes.last_qd[env] = qd
            episodes.time_out_count[env] = count
            episodes.steps_run[env] = episodes.steps_run[env] + 1
            episodes.episode_return[env] = ret
        else:
            final_q, final_qd = q, qd
            if not all_within(q, qd, settings.divergence_limit):
                final_q = Joints(episodes.last_q[env])
                final_qd = Joints(episodes.last_qd[env])
            final = State()
            for role in range(num_joints):
                final[2 * role] = final_q[role]
                final[2 * role + 1] = final_qd[role]
            results.final_state[env] = final
            results.ended_return[env] = ret
            results.ended_length[env] = episodes.steps_run[env] + 1
            q0, qd0 = fns.sample_reset(episodes.rng_state, env, p)
            begin_episode(env, q0, qd0, p, settings, robot, episodes)

    @kernel
    def reset_masked(mask: wp.array(dtype=wp.bool), p: Constants, settings: StepSettings, robot: Robot,
                     episodes: Episodes):
        """Start a new episode from the task's random start in every env where ``mask`` is set."""
        env = wp.tid()
        if mask[env]:
            q, qd = fns.sample_reset(episodes.rng_state, env, p)
            begin_episode(env, q, qd, p, settings, robot, episodes)

    @kernel
    def set_states_masked(states: wp.array(dtype=State), mask: wp.array(dtype=wp.bool), p: Constants,
                          settings: StepSettings, robot: Robot, episodes: Episodes):
        """Start a new episode from ``states`` (per joint role: position, velocity) where ``mask`` is set."""
        env = wp.tid()
        if mask[env]:
            s = states[env]
            q, qd = Joints(), Joints()
            for r in range(num_joints):
                q[r] = s[2 * r]
                qd[r] = s[2 * r + 1]
            begin_episode(env, q, qd, p, settings, robot, episodes)

    return SimpleNamespace(Joints=Joints, Actions=Actions, Obs=Obs, State=State, Constants=Constants, Robot=Robot,
                           Episodes=Episodes, StepResults=StepResults, StepSettings=StepSettings,
                           apply_actions=apply_actions, random_actions=random_actions, end_step=end_step,
                           reset_masked=reset_masked, set_states_masked=set_states_masked)


__getattr__ = renamed(__name__, {"kernel_params": "kernel_constants", "params_of": "constants_of"})
"""The old names (``params`` is the physical parameters' word), until ``settings.deprecation.REMOVED_IN``."""
