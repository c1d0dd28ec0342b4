"""Warp kernels of the cartpole task: one thread per env, inputs first and outputs last.

Observations are ``wp.vec4`` in the order [cart_pos (m), cart_vel (m/s), pole_angle (rad), pole_vel (rad/s)].
Joint arrays are Newton's flat ``joint_q`` / ``joint_qd`` / ``joint_f``: env ``i`` owns the block
``[i * dofs_per_env, (i + 1) * dofs_per_env)``.
"""

import typing

import warp as wp

from .config import TaskConfig

END_NONE = wp.constant(0)
END_CART_OUT = wp.constant(1)
END_POLE_FELL = wp.constant(2)
END_TIME_LIMIT = wp.constant(3)
END_NONFINITE = wp.constant(4)
END_REASONS = ("running", "cart_out_of_range", "pole_fell", "time_limit", "nonfinite_state")
"""Names of the codes in ``end_reason``, by code."""


TASK_FIELDS = tuple(name for name, kind in typing.get_type_hints(TaskConfig).items() if kind is float)
"""The float fields of ``TaskConfig``: the task's constants, passed to the kernels under the same names."""

TaskParams = wp.struct(type("TaskParams", (), {
    "__annotations__": dict.fromkeys(TASK_FIELDS, float),
    "__module__": __name__,
    "__qualname__": "TaskParams",
    "__doc__": "The float fields of TaskConfig, generated from it (the config is the one place they are written).",
}))


@wp.struct
class DofLayout:
    """Where one env's cart and pole DOFs sit in Newton's flat joint arrays (from the scene)."""

    dofs_per_env: int
    cart_dof: int
    pole_dof: int


def task_params(task: TaskConfig) -> TaskParams:
    """The kernels' copy of the task's constants."""
    params = TaskParams()
    for name in TASK_FIELDS:
        setattr(params, name, getattr(task, name))
    return params


def dof_layout(dofs_per_env: int, cart_dof: int, pole_dof: int) -> DofLayout:
    """The kernels' view of a scene's DOF layout."""
    layout = DofLayout()
    layout.dofs_per_env, layout.cart_dof, layout.pole_dof = dofs_per_env, cart_dof, pole_dof
    return layout


@wp.func
def read_obs(joint_q: wp.array(dtype=float), joint_qd: wp.array(dtype=float), env: int, layout: DofLayout):
    base = env * layout.dofs_per_env
    cart, pole = base + layout.cart_dof, base + layout.pole_dof
    return wp.vec4(joint_q[cart], joint_qd[cart], joint_q[pole], joint_qd[pole])


@wp.func
def shaped_reward(obs: wp.vec4, p: TaskParams):
    return (
        p.alive_reward
        - p.pole_angle_weight * obs[2] * obs[2]
        - p.cart_vel_weight * wp.abs(obs[1])
        - p.pole_vel_weight * wp.abs(obs[3])
    )


@wp.func
def failure_reason(obs: wp.vec4, p: TaskParams):
    if wp.abs(obs[0]) > p.reset_dist_m:
        return END_CART_OUT
    if wp.abs(obs[2]) > p.max_pole_angle_rad:
        return END_POLE_FELL
    return END_NONE


@wp.func
def is_finite4(v: wp.vec4):
    return wp.isfinite(v[0]) and wp.isfinite(v[1]) and wp.isfinite(v[2]) and wp.isfinite(v[3])


@wp.func
def sample_reset_state(rng_state: wp.array(dtype=wp.uint32), env: int, p: TaskParams):
    """[cart_pos, cart_vel, pole_angle, pole_vel], each uniform in [-range, range]; advances the env's RNG."""
    s = rng_state[env]
    x = wp.vec4(
        wp.randf(s, -p.reset_cart_pos_m, p.reset_cart_pos_m),
        wp.randf(s, -p.reset_cart_vel_m_s, p.reset_cart_vel_m_s),
        wp.randf(s, -p.reset_pole_angle_rad, p.reset_pole_angle_rad),
        wp.randf(s, -p.reset_pole_vel_rad_s, p.reset_pole_vel_rad_s),
    )
    rng_state[env] = s
    return x


@wp.func
def begin_episode(
    env: int,
    state: wp.vec4,
    layout: DofLayout,
    joint_q: wp.array(dtype=float),
    joint_qd: wp.array(dtype=float),
    obs: wp.array(dtype=wp.vec4),
    episode_length: wp.array(dtype=wp.int32),
    steps_run: wp.array(dtype=wp.int32),
    episode_return: wp.array(dtype=float),
):
    base = env * layout.dofs_per_env
    for d in range(layout.dofs_per_env):
        joint_q[base + d] = 0.0
        joint_qd[base + d] = 0.0
    joint_q[base + layout.cart_dof] = state[0]
    joint_qd[base + layout.cart_dof] = state[1]
    joint_q[base + layout.pole_dof] = state[2]
    joint_qd[base + layout.pole_dof] = state[3]
    obs[env] = state
    episode_length[env] = 0
    steps_run[env] = 0
    episode_return[env] = 0.0


@wp.kernel
def init_rng(seed: int, first_env: int, rng_state: wp.array(dtype=wp.uint32)):
    """Seed each env's RNG from ``seed`` and its global index (``first_env`` + thread), whatever the sharding."""
    env = wp.tid()
    rng_state[env] = wp.rand_init(seed, first_env + env)


@wp.kernel
def apply_actions(
    actions: wp.array(dtype=float),
    p: TaskParams,
    layout: DofLayout,
    joint_f: wp.array(dtype=float),
    nonfinite_action_count: wp.array(dtype=wp.int32),
):
    """Cart force = max_push_effort * clip(action, -1, 1); a non-finite action becomes 0 and is counted."""
    env = wp.tid()
    a = actions[env]
    if not wp.isfinite(a):
        a = 0.0
        wp.atomic_add(nonfinite_action_count, 0, 1)
    joint_f[env * layout.dofs_per_env + layout.cart_dof] = p.max_push_effort_n * wp.clamp(a, -1.0, 1.0)


@wp.kernel
def random_forces(
    rng_state: wp.array(dtype=wp.uint32), p: TaskParams, layout: DofLayout, joint_f: wp.array(dtype=float)
):
    """Uniform random cart force in [-max_push_effort, max_push_effort] (benchmarks the physics alone)."""
    env = wp.tid()
    s = rng_state[env]
    joint_f[env * layout.dofs_per_env + layout.cart_dof] = wp.randf(s, -p.max_push_effort_n, p.max_push_effort_n)
    rng_state[env] = s


@wp.kernel
def finish_step(
    p: TaskParams,
    layout: DofLayout,
    max_episode_length: int,
    rng_state: wp.array(dtype=wp.uint32),
    joint_q: wp.array(dtype=float),
    joint_qd: wp.array(dtype=float),
    obs: wp.array(dtype=wp.vec4),
    episode_length: wp.array(dtype=wp.int32),
    steps_run: wp.array(dtype=wp.int32),
    episode_return: wp.array(dtype=float),
    reward: wp.array(dtype=float),
    terminated: wp.array(dtype=wp.bool),
    truncated: wp.array(dtype=wp.bool),
    final_obs: wp.array(dtype=wp.vec4),
    ended_return: wp.array(dtype=float),
    ended_length: wp.array(dtype=wp.int32),
    end_reason: wp.array(dtype=wp.int32),
    nonfinite_state_count: wp.array(dtype=wp.int32),
):
    """After the physics: observe, reward, terminate/truncate, keep the terminal obs, reset ended envs.

    ``obs`` holds the previous observation on entry and the next one on exit. A non-finite physics state
    ends the episode as a failure, reports the last finite observation and is counted; its end reason is that
    observation's (cart out of range, pole fell) when it was already beyond the limits, else "non-finite state".
    ``episode_length`` counts toward the time limit (rsl-rl may start it at random values); ``steps_run`` counts the
    steps the episode really ran, which ``ended_length`` reports.
    """
    env = wp.tid()
    o = read_obs(joint_q, joint_qd, env, layout)
    length = episode_length[env] + 1
    steps = steps_run[env] + 1
    reason = END_NONE
    r = 0.0
    if is_finite4(o):
        reason = failure_reason(o, p)
        r = shaped_reward(o, p)
    else:
        o = obs[env]
        reason = failure_reason(o, p)  # a finite state already beyond the limits says so, not "non-finite"
        if reason == END_NONE:
            reason = END_NONFINITE
        wp.atomic_add(nonfinite_state_count, 0, 1)
    if reason != END_NONE:
        r = p.failure_reward
    elif length >= max_episode_length:
        reason = END_TIME_LIMIT
    ret = episode_return[env] + r

    reward[env] = r
    terminated[env] = reason != END_NONE and reason != END_TIME_LIMIT
    truncated[env] = reason == END_TIME_LIMIT
    final_obs[env] = o
    end_reason[env] = reason
    if reason == END_NONE:
        obs[env] = o
        episode_length[env] = length
        steps_run[env] = steps
        episode_return[env] = ret
    else:
        ended_return[env] = ret
        ended_length[env] = steps
        state = sample_reset_state(rng_state, env, p)
        begin_episode(env, state, layout, joint_q, joint_qd, obs, episode_length, steps_run, episode_return)


@wp.kernel
def reset_masked(
    mask: wp.array(dtype=wp.bool),
    p: TaskParams,
    layout: DofLayout,
    rng_state: wp.array(dtype=wp.uint32),
    joint_q: wp.array(dtype=float),
    joint_qd: wp.array(dtype=float),
    obs: wp.array(dtype=wp.vec4),
    episode_length: wp.array(dtype=wp.int32),
    steps_run: wp.array(dtype=wp.int32),
    episode_return: wp.array(dtype=float),
):
    """Start a new episode from a random reset state in every env where ``mask`` is set."""
    env = wp.tid()
    if mask[env]:
        state = sample_reset_state(rng_state, env, p)
        begin_episode(env, state, layout, joint_q, joint_qd, obs, episode_length, steps_run, episode_return)


@wp.kernel
def set_states_masked(
    states: wp.array(dtype=wp.vec4),
    mask: wp.array(dtype=wp.bool),
    layout: DofLayout,
    joint_q: wp.array(dtype=float),
    joint_qd: wp.array(dtype=float),
    obs: wp.array(dtype=wp.vec4),
    episode_length: wp.array(dtype=wp.int32),
    steps_run: wp.array(dtype=wp.int32),
    episode_return: wp.array(dtype=float),
):
    """Start a new episode from the given state in every env where ``mask`` is set."""
    env = wp.tid()
    if mask[env]:
        begin_episode(env, states[env], layout, joint_q, joint_qd, obs, episode_length, steps_run, episode_return)
