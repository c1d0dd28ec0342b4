"""Warp kernels of the cartpole task: one thread per env, inputs first and outputs last.

Observations are ``wp.vec4`` in the order [cart_pos (m), cart_vel (m/s), pole_angle (rad), pole_vel (rad/s)].
Joint arrays are Newton's flat ``joint_q`` / ``joint_qd`` / ``joint_f``: env ``i`` owns the block
``[i * dofs_per_env, (i + 1) * dofs_per_env)``.
"""

import warp as wp

END_NONE = wp.constant(0)
END_CART_OUT = wp.constant(1)
END_POLE_FELL = wp.constant(2)
END_TIME_LIMIT = wp.constant(3)
END_NONFINITE = wp.constant(4)
END_REASONS = ("running", "cart_out_of_range", "pole_fell", "time_limit", "nonfinite_state")
"""Names of the codes in ``end_reason``, by code."""


@wp.struct
class TaskParams:
    """The task's constants, as read from ``TaskConfig`` and the scene's DOF layout."""

    dofs_per_env: int
    cart_dof: int
    pole_dof: int
    max_push_effort_n: float
    reset_dist_m: float
    max_pole_angle_rad: float
    failure_reward: float
    alive_reward: float
    pole_angle_weight: float
    cart_vel_weight: float
    pole_vel_weight: float
    reset_half_range: wp.vec4
    max_episode_length: int


@wp.func
def read_obs(joint_q: wp.array(dtype=float), joint_qd: wp.array(dtype=float), env: int, p: TaskParams):
    base = env * p.dofs_per_env
    return wp.vec4(
        joint_q[base + p.cart_dof], joint_qd[base + p.cart_dof], joint_q[base + p.pole_dof], joint_qd[base + p.pole_dof]
    )


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
    """Uniform in [-half_range, half_range] per component; advances the env's RNG state."""
    s = rng_state[env]
    h = p.reset_half_range
    x = wp.vec4(wp.randf(s, -h[0], h[0]), wp.randf(s, -h[1], h[1]), wp.randf(s, -h[2], h[2]), wp.randf(s, -h[3], h[3]))
    rng_state[env] = s
    return x


@wp.func
def begin_episode(
    env: int,
    state: wp.vec4,
    p: TaskParams,
    joint_q: wp.array(dtype=float),
    joint_qd: wp.array(dtype=float),
    obs: wp.array(dtype=wp.vec4),
    episode_length: wp.array(dtype=wp.int32),
    episode_return: wp.array(dtype=float),
):
    base = env * p.dofs_per_env
    for d in range(p.dofs_per_env):
        joint_q[base + d] = 0.0
        joint_qd[base + d] = 0.0
    joint_q[base + p.cart_dof] = state[0]
    joint_qd[base + p.cart_dof] = state[1]
    joint_q[base + p.pole_dof] = state[2]
    joint_qd[base + p.pole_dof] = state[3]
    obs[env] = state
    episode_length[env] = 0
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
    joint_f: wp.array(dtype=float),
    nonfinite_action_count: wp.array(dtype=wp.int32),
):
    """Cart force = max_push_effort * clip(action, -1, 1); a non-finite action becomes 0 and is counted."""
    env = wp.tid()
    a = actions[env]
    if not wp.isfinite(a):
        a = 0.0
        wp.atomic_add(nonfinite_action_count, 0, 1)
    joint_f[env * p.dofs_per_env + p.cart_dof] = p.max_push_effort_n * wp.clamp(a, -1.0, 1.0)


@wp.kernel
def random_forces(
    rng_state: wp.array(dtype=wp.uint32), p: TaskParams, joint_f: wp.array(dtype=float)
):
    """Uniform random cart force in [-max_push_effort, max_push_effort] (benchmarks the physics alone)."""
    env = wp.tid()
    s = rng_state[env]
    joint_f[env * p.dofs_per_env + p.cart_dof] = wp.randf(s, -p.max_push_effort_n, p.max_push_effort_n)
    rng_state[env] = s


@wp.kernel
def finish_step(
    p: TaskParams,
    rng_state: wp.array(dtype=wp.uint32),
    joint_q: wp.array(dtype=float),
    joint_qd: wp.array(dtype=float),
    obs: wp.array(dtype=wp.vec4),
    episode_length: wp.array(dtype=wp.int32),
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
    ends the episode as a failure, reports the last finite observation and is counted.
    """
    env = wp.tid()
    o = read_obs(joint_q, joint_qd, env, p)
    length = episode_length[env] + 1
    reason = END_NONE
    r = float(0.0)
    if is_finite4(o):
        reason = failure_reason(o, p)
        r = shaped_reward(o, p)
    else:
        o = obs[env]
        reason = END_NONFINITE
        wp.atomic_add(nonfinite_state_count, 0, 1)
    if reason != END_NONE:
        r = p.failure_reward
    elif length >= p.max_episode_length:
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
        episode_return[env] = ret
    else:
        ended_return[env] = ret
        ended_length[env] = length
        state = sample_reset_state(rng_state, env, p)
        begin_episode(env, state, p, joint_q, joint_qd, obs, episode_length, episode_return)


@wp.kernel
def reset_masked(
    mask: wp.array(dtype=wp.bool),
    p: TaskParams,
    rng_state: wp.array(dtype=wp.uint32),
    joint_q: wp.array(dtype=float),
    joint_qd: wp.array(dtype=float),
    obs: wp.array(dtype=wp.vec4),
    episode_length: wp.array(dtype=wp.int32),
    episode_return: wp.array(dtype=float),
):
    """Start a new episode from a random reset state in every env where ``mask`` is set."""
    env = wp.tid()
    if mask[env]:
        state = sample_reset_state(rng_state, env, p)
        begin_episode(env, state, p, joint_q, joint_qd, obs, episode_length, episode_return)


@wp.kernel
def set_states_masked(
    states: wp.array(dtype=wp.vec4),
    mask: wp.array(dtype=wp.bool),
    p: TaskParams,
    joint_q: wp.array(dtype=float),
    joint_qd: wp.array(dtype=float),
    obs: wp.array(dtype=wp.vec4),
    episode_length: wp.array(dtype=wp.int32),
    episode_return: wp.array(dtype=float),
):
    """Start a new episode from the given state in every env where ``mask`` is set."""
    env = wp.tid()
    if mask[env]:
        begin_episode(env, states[env], p, joint_q, joint_qd, obs, episode_length, episode_return)
