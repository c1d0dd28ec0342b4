"""Running a policy on the batched env: the policy interface, evaluation statistics and recordings.

A policy is any ``policy(obs) -> actions`` callable on torch tensors: obs (N, 4) -> actions (N, 1) in [-1, 1],
so trained rsl-rl or SB3 policies, ``zero_policy`` and ``random_policy`` share ``rollout``, ``write_gif``,
``write_usd`` and ``view_interactively``.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from .env import CartpoleEnv
from .metrics import EpisodeStats, EpisodeSummary
from .render import Geometry

Policy = Callable[[torch.Tensor], torch.Tensor]


class ViewerUnavailable(RuntimeError):
    """Newton's interactive viewer cannot open here; the message says why and what to do instead."""


def zero_policy(obs: torch.Tensor) -> torch.Tensor:
    """Never pushes the cart."""
    return torch.zeros(obs.shape[0], 1, dtype=torch.float32, device=obs.device)


def random_policy(seed: int = 0) -> Policy:
    """Uniform random actions in [-1, 1] from a seeded generator."""
    generator = torch.Generator().manual_seed(seed)

    def policy(obs: torch.Tensor) -> torch.Tensor:
        return (torch.rand(obs.shape[0], 1, generator=generator) * 2 - 1).to(obs.device)

    return policy


@dataclass
class RolloutResult:
    """Statistics of each env's first episode, and the recorded env's body transforms per env step."""

    stats: EpisodeSummary
    steps: int
    frames: np.ndarray | None
    """(steps + 1, bodies, 7) world transforms of env 0's bodies, or None when not recorded."""
    geometry: Geometry | None


def rollout(env: CartpoleEnv, policy: Policy, steps: int, record: bool = True) -> RolloutResult:
    """Reset ``env`` and run ``policy`` for ``steps`` env steps without gradients.

    Statistics cover each env's first episode; an episode still running after ``steps`` counts as having
    reached the time limit (the run's step cap), which only happens when ``steps`` < max_episode_length.
    """
    geometry = Geometry(env.scene.model) if record else None
    obs, _ = env.reset()
    frames = [geometry.body_transforms(env.scene.state_0)] if record else []
    stats = EpisodeStats()
    finished = torch.zeros(env.num_envs, dtype=torch.bool, device=env.device)
    returns = torch.zeros(env.num_envs, dtype=torch.float32, device=env.device)
    with torch.inference_mode():
        for step in range(steps):
            obs, reward, terminated, truncated, _ = env.step(policy(obs).to(torch.float32))
            returns += torch.where(finished, 0.0, reward)
            ended = (terminated | truncated) & ~finished
            if ended.any():
                stats.add(returns[ended], torch.full_like(returns[ended], step + 1), truncated[ended])
            finished |= ended
            if record:
                frames.append(geometry.body_transforms(env.scene.state_0))
    running = ~finished
    if running.any():
        stats.add(returns[running], torch.full_like(returns[running], steps), torch.ones_like(returns[running]))
    return RolloutResult(stats.summary(), steps, np.stack(frames) if record else None, geometry)


def check_viewer():
    """Raise ViewerUnavailable unless a display and pyglet (needed by Newton's OpenGL viewer) are present."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise ViewerUnavailable("no display found ($DISPLAY is not set), so Newton's viewer cannot open; "
                                "run with --headless to write a GIF and a USD recording instead")
    try:
        import pyglet  # noqa: F401
    except ImportError:
        raise ViewerUnavailable("Newton's viewer needs pyglet: pip install -e '.[viz]' (or pip install pyglet); "
                                "or run with --headless") from None


def view_interactively(env: CartpoleEnv, policy: Policy):
    """Run ``policy`` in Newton's OpenGL viewer until its window closes; ViewerUnavailable if it cannot open."""
    check_viewer()
    import newton.viewer

    try:
        viewer = newton.viewer.ViewerGL()
    except Exception as err:  # GL context creation fails in many backend-specific ways
        raise ViewerUnavailable(f"cannot open Newton's viewer ({type(err).__name__}: {err}); "
                                "run with --headless instead") from None
    scene = env.scene
    geometry = Geometry(scene.model)
    viewer.set_model(scene.model)
    obs, _ = env.reset()
    sim_time_s = 0.0
    with torch.inference_mode():
        while viewer.is_running():
            if not viewer.is_paused():
                obs = env.step(policy(obs).to(torch.float32))[0]
                sim_time_s += env.env_dt
            geometry.body_transforms(scene.state_0)
            viewer.begin_frame(sim_time_s)
            viewer.log_state(scene.state_0)
            viewer.end_frame()
    viewer.close()
