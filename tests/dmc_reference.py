"""dm_control's cartpole swing-up reward and observations, transcribed to plain numpy for tests.

Independent of cartpole_warp and of dm_control itself (which is not installed): a line-for-line transcription of
dm_control (github.com/google-deepmind/dm_control, commit 985d094, 2026-08-05) of what the ``swingup`` task
(``Balance(swing_up=True, sparse=False)``) computes each control step, batched over N envs of one pole each.

States are (N, 4) ``[cart_pos, cart_vel, pole_angle, pole_vel]`` (m, m/s, rad, rad/s) with pole_angle 0 upright;
actions are (N,) in dm_control's units (the motor's ``ctrl``, ``ctrlrange="-1 1"``, gear 10: 10 N per unit), as
passed: dm_control's ``physics.control()`` is ``data.ctrl``, which MuJoCo clamps only when it applies the force.
dm_control's pole angle (``hinge_1``, about +Y, the slide along +X) tips the pole towards +slide when positive; the
stage ``usd/cartpole_dmc.usda`` hinges about +X with the slide along +Y, so its ``poleJoint`` angle tips the pole
towards -slide: the same cosine, the opposite sine and angular velocity. The reward does not depend on that sign.
"""

import numpy as np

# dm_control/utils/rewards.py: the value tolerance() returns at `margin` distance from the bounds.
_DEFAULT_VALUE_AT_MARGIN = 0.1


# dm_control/utils/rewards.py: _sigmoids (its 'gaussian' and 'quadratic' branches; the others are not used here).
def _sigmoids(x, value_at_1, sigmoid):
    """1 where ``x`` == 0, ``value_at_1`` where |x| == 1, between 0 and 1 otherwise."""
    if sigmoid in ("cosine", "linear", "quadratic"):
        if not 0 <= value_at_1 < 1:
            raise ValueError(f"`value_at_1` must be nonnegative and smaller than 1, got {value_at_1}.")
    elif not 0 < value_at_1 < 1:
        raise ValueError(f"`value_at_1` must be strictly between 0 and 1, got {value_at_1}.")

    if sigmoid == "gaussian":
        scale = np.sqrt(-2 * np.log(value_at_1))
        return np.exp(-0.5 * (x * scale) ** 2)
    if sigmoid == "quadratic":
        scale = np.sqrt(1 - value_at_1)
        scaled_x = x * scale
        return np.where(abs(scaled_x) < 1, 1 - scaled_x**2, 0.0)
    raise ValueError(f"Unknown sigmoid type {sigmoid!r} (only 'gaussian' and 'quadratic' are transcribed).")


# dm_control/utils/rewards.py: tolerance
def tolerance(x, bounds=(0.0, 0.0), margin=0.0, sigmoid="gaussian", value_at_margin=_DEFAULT_VALUE_AT_MARGIN):
    """1 where ``x`` lies inside the inclusive ``bounds``; outside, a sigmoid of the distance to the nearest bound in
    units of ``margin`` (``value_at_margin`` at one margin), or 0 where ``margin`` is 0."""
    lower, upper = bounds
    if lower > upper:
        raise ValueError("Lower bound must be <= upper bound.")
    if margin < 0:
        raise ValueError("`margin` must be non-negative.")

    in_bounds = np.logical_and(lower <= x, x <= upper)
    if margin == 0:
        value = np.where(in_bounds, 1.0, 0.0)
    else:
        d = np.where(x < lower, lower - x, x - upper) / margin
        value = np.where(in_bounds, 1.0, _sigmoids(d, value_at_margin, sigmoid))

    return float(value) if np.isscalar(x) else value


def _split(states):
    states = np.asarray(states, dtype=np.float64)
    assert states.ndim == 2 and states.shape[1] == 4, f"states must be (N, 4), got {states.shape}"
    return states.T


# dm_control/suite/cartpole.py: Balance._get_reward(physics, sparse=False), the smooth reward of `swingup`.
def swingup_reward(states, actions):
    """(N,) reward in [0, 1]: upright x centered x small_control x small_velocity, 1 upright at rest and centred."""
    cart_pos, _, pole_angle, pole_vel = _split(states)
    control = np.asarray(actions, dtype=np.float64).reshape(-1)
    upright = (np.cos(pole_angle) + 1) / 2  # physics.pole_angle_cosine(): the pole's xmat zz; .mean() over 1 pole
    centered = tolerance(cart_pos, margin=2)
    centered = (1 + centered) / 2
    small_control = tolerance(control, margin=1, value_at_margin=0, sigmoid="quadratic")
    small_control = (4 + small_control) / 5
    small_velocity = tolerance(pole_vel, margin=5)  # physics.angular_vel(): qvel[1:]; .min() over 1 pole
    small_velocity = (1 + small_velocity) / 2
    return upright * small_control * small_velocity * centered


# dm_control/suite/cartpole.py: Balance.get_observation and Physics.bounded_position, flattened in their order
# (position = [cart_position, xmat zz, xmat xz], then velocity = qvel).
def swingup_observations(states):
    """(N, 5) ``[cart_pos, cos(pole_angle), sin(pole_angle), cart_vel, pole_vel]``."""
    cart_pos, cart_vel, pole_angle, pole_vel = _split(states)
    return np.stack([cart_pos, np.cos(pole_angle), np.sin(pole_angle), cart_vel, pole_vel], axis=1)


# dm_control/suite/cartpole.py for a chain of poles (``two_poles``, ``three_poles``: ``_make_model(n)``), batched:
# ``q`` and ``qd`` are (N, 1 + n) [cart, hinge_1, ..., hinge_n] positions and velocities, each hinge's angle relative
# to the body below it (MuJoCo's qpos). Physics.pole_angle_cosine() is each pole's xmat zz, the cosine of its angle in
# the world (the sum of the hinge angles up to it); Physics.angular_vel() is qvel[1:], the hinges' own velocities.
def _chain(q):
    q = np.asarray(q, dtype=np.float64)
    world = np.cumsum(q[:, 1:], axis=1)
    return q[:, 0], np.cos(world), np.sin(world)


# Balance._get_reward(physics, sparse=False) over n poles.
def chain_swingup_reward(q, qd, actions):
    """(N,) ``upright.mean() * small_control * small_velocity * centered`` with upright and small_velocity over
    the poles."""
    cart_position, pole_angle_cosine, _ = _chain(q)
    control = np.asarray(actions, dtype=np.float64).reshape(-1)
    upright = (pole_angle_cosine + 1) / 2
    centered = tolerance(cart_position, margin=2)
    centered = (1 + centered) / 2
    small_control = tolerance(control, margin=1, value_at_margin=0, sigmoid="quadratic")
    small_control = (4 + small_control) / 5
    small_velocity = tolerance(np.asarray(qd, dtype=np.float64)[:, 1:], margin=5).min(axis=1)
    small_velocity = (1 + small_velocity) / 2
    return upright.mean(axis=1) * small_control * small_velocity * centered


# Balance._get_reward(physics, sparse=True), with Balance._CART_RANGE = (-.25, .25), _ANGLE_COSINE_RANGE = (.995, 1).
def sparse_reward(q):
    """(N,) 1 where the cart is within 0.25 m of the centre and every pole's cosine is in [0.995, 1], else 0."""
    cart_position, pole_angle_cosine, _ = _chain(q)
    cart_in_bounds = tolerance(cart_position, (-0.25, 0.25))
    angle_in_bounds = tolerance(pole_angle_cosine, (0.995, 1)).prod(axis=1)
    return cart_in_bounds * angle_in_bounds


# Balance.get_observation over n poles: position = [cart_position, (xmat zz, xmat xz) per pole], velocity = qvel; xz
# is the sine of the pole's world angle with this project's sign (see the module's docstring).
def chain_observations(q, qd):
    """(N, 3n + 2) ``[cart_pos, cos phi_1, sin phi_1, ..., cos phi_n, sin phi_n, cart_vel, hinge velocities]``."""
    cart_position, cosines, sines = _chain(q)
    position = np.stack([cosines, sines], axis=2).reshape(len(cart_position), -1)
    return np.concatenate([cart_position[:, None], position, np.asarray(qd, dtype=np.float64)], axis=1)


def on_the_edge(cart_pos, cosine):
    """Where float32 and float64 may disagree about the sparse band: within 1e-5 of its cart or cosine bound."""
    return (np.abs(np.abs(cart_pos) - 0.25) < 1e-5) | (np.abs(cosine - 0.995) < 1e-5)
