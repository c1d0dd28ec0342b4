"""The rules of an env step that the env's kernels (``kernels.build_kernels``) and the differentiable rollout's
(``gradients.rollout``) both apply, written once as generic Warp functions (their vectors typed ``Any``: each task's
``Joints`` and ``Actions``): where each joint role's dof sits, the actions' clip to [-1, 1], the divergence rule, the
end codes and the time limit.
Each builds its result in a fresh vector (a copy of an argument modified in place gets wrong adjoints)."""

from typing import Any

import warp as wp

END_NONE = wp.constant(0)
END_TIME_LIMIT = wp.constant(1)
END_NONFINITE = wp.constant(2)
END_DIVERGED = wp.constant(3)


@wp.func
def role_state(joint_q: wp.array(dtype=float), joint_qd: wp.array(dtype=float), role_dofs: wp.array(dtype=int),
               base: int, like: Any):
    """The joint roles' positions and velocities (two vectors of ``like``'s type) of the env whose dofs start at
    ``base`` in Newton's ``joint_q`` and ``joint_qd``; ``role_dofs[r]``: role r's dof within an env's."""
    q, qd = type(like)(), type(like)()
    for r in range(len(like)):
        q[r] = joint_q[base + role_dofs[r]]
        qd[r] = joint_qd[base + role_dofs[r]]
    return q, qd


@wp.func
def set_role_state(q: Any, qd: Any, role_dofs: wp.array(dtype=int), base: int, joint_q: wp.array(dtype=float),
                   joint_qd: wp.array(dtype=float)):
    """Write the joint roles' positions ``q`` and velocities ``qd`` into the env's dofs (``role_state``'s inverse)."""
    for r in range(len(q)):
        joint_q[base + role_dofs[r]] = q[r]
        joint_qd[base + role_dofs[r]] = qd[r]


@wp.func
def clip_actions(a: Any):
    """Each action clipped to [-1, 1]."""
    clipped = type(a)()
    for i in range(len(a)):
        clipped[i] = wp.clamp(a[i], -1.0, 1.0)
    return clipped


@wp.func
def all_within(q: Any, qd: Any, limit: float):
    """Every joint position and velocity within +-``limit`` (so finite: a NaN fails the comparison); a state beyond it
    has diverged: it earns 0 and ends its episode."""
    ok = True
    for r in range(len(q)):
        ok = ok and wp.abs(q[r]) <= limit and wp.abs(qd[r]) <= limit
    return ok


@wp.func
def with_time_limit(reason: int, count: int, max_episode_length: int):
    """A step's end reason with the time limit: ``END_TIME_LIMIT`` where nothing else ends the episode and this is
    its ``count``-th step toward the limit of ``max_episode_length`` steps."""
    if reason == END_NONE and count >= max_episode_length:
        return END_TIME_LIMIT
    return reason
