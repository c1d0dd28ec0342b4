"""``VectorSpaces``: gymnasium's view of a batched env, its observation and action spaces per env and for the batch
(gymnasium's vector-env convention, as Isaac Lab's)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import gymnasium


class VectorSpaces:
    """The spaces of an env with ``num_envs``, ``num_actions``, ``observations`` (its source) and ``obs_buf``."""

    @property
    def obs_shape(self) -> tuple[int, ...]:
        """One env's observation: (num_obs,) float32, or with a camera (channels x frame_stack, height, width) uint8
        (rgb) or float32 metres (depth), oldest frame first."""
        return tuple(self.obs_buf.shape[1:])

    @property
    def single_observation_space(self) -> gymnasium.spaces.Box:
        """One env's observations as a gymnasium space: ``num_obs`` unbounded float32 (the task's docstring names
        them), or with a camera its frames (``obs_shape``): uint8 in [0, 255] (rgb) or float32 metres (depth)."""
        return self.observations.space(self.obs_shape)

    @property
    def single_action_space(self) -> gymnasium.spaces.Box:
        """One env's actions as a gymnasium space: ``num_actions`` values in [-1, 1] (the env clips to it)."""
        import gymnasium

        return gymnasium.spaces.Box(-1.0, 1.0, (self.num_actions,), np.float32)

    @property
    def observation_space(self) -> gymnasium.spaces.Box:
        """The batch's observations, (num_envs, ...)."""
        from gymnasium.vector.utils import batch_space

        return batch_space(self.single_observation_space, self.num_envs)

    @property
    def action_space(self) -> gymnasium.spaces.Box:
        """The batch's actions, (num_envs, num_actions)."""
        from gymnasium.vector.utils import batch_space

        return batch_space(self.single_action_space, self.num_envs)
