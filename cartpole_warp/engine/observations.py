"""What the policy observes: one source the env asks for its observations, the task's state (``StateObservations``)
or camera frames with their stacks (``camera.CameraObservations``), picked once from ``CameraConfig.enabled``
(``observations_of``). A source gives the observation buffers and runs its work at three points of the env step:
after the physics, after the step kernel (with its results), and where new episodes start."""

from __future__ import annotations

import numpy as np
import warp as wp

from ..settings.config import CameraConfig


class StateObservations:
    """The policy observes the task's state as the step kernel writes it: no work of its own."""

    images = False
    modules: tuple = ()
    cameras: tuple = ()

    def attach(self, shards: list) -> None:
        """Nothing to place on the scenes."""

    def buffers(self, state_obs: wp.array, final_state_obs: wp.array) -> tuple[wp.array, wp.array]:
        """(the observations, the final observations of ended episodes): the task's state buffers themselves."""
        return state_obs, final_state_obs

    def after_physics(self, shard) -> None:
        """Nothing: the step kernel writes the observations."""

    def after_step(self, shard, results) -> None:
        """Nothing: the step kernel writes the observations."""

    def start(self, shard, mask: wp.array) -> None:
        """Nothing: the reset kernel writes the observations."""

    def space(self, shape: tuple[int, ...]):
        """One env's observation space: unbounded float32 (the task's docstring names the values)."""
        import gymnasium

        return gymnasium.spaces.Box(-np.inf, np.inf, shape, np.float32)


def observations_of(cfg: CameraConfig, num_envs: int, device: str):
    """The source of ``num_envs`` envs' observations on ``device`` (a camera's checks its memory first)."""
    if not cfg.enabled:
        return StateObservations()
    from .camera import CameraObservations

    return CameraObservations(cfg, num_envs, device)
