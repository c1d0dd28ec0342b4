"""Compile the Warp kernels of the tasks ahead of time (a machine image, a CI cache), so that the next train.py or
play.py on this machine compiles nothing.

    python -m cartpole_warp.warmup                          # every task, on the CPU
    python -m cartpole_warp.warmup --device cuda:0 --task cartpole-balance
    python -m cartpole_warp.warmup --device cuda:0 --gradients   # also what tools.sysid and --learner shac compile
    WARP_CACHE_PATH=/cache python -m cartpole_warp.warmup   # into another kernel cache (Warp reads the variable)

Each task's env is built with one env and stepped once (every module its training and play load: Newton's solver and
model kernels, the machinery's and the task's), then recorded for a step as play.py --headless does (Newton's USD
viewer); with ``--gradients`` also the state tasks' kernels with their adjoints (what ``tools.sysid``,
``tools.gradcheck`` and ``--learner shac`` compile otherwise on their first run). Also installed as the command
``cartpole-warmup``.
"""

from __future__ import annotations

import sys
import tempfile
import time
from dataclasses import dataclass, field
from typing import Literal

from . import tasks
from .cli import clean_errors, parse, quiet_libraries
from .engine.scene import StageError
from .settings.config import ConfigError, require


@dataclass
class WarmupArgs:
    task: list[str] = field(default_factory=tasks.names)
    """The tasks whose kernels to compile (default: every registered task)."""
    device: str = "cpu"
    """Warp device to compile for: 'cpu', 'cuda' or 'cuda:N'."""
    solver: Literal["featherstone", "mujoco"] = "featherstone"
    """Newton solver whose kernels to compile (the tasks' default is featherstone)."""
    recording: bool = True
    """Also compile what play.py --headless records with (Newton's USD viewer)."""
    gradients: bool = False
    """Also compile the kernels with their adjoints that tools.sysid, tools.gradcheck and --learner shac run on
    (state tasks: Newton's with adjoints and the differentiable rollout's), one backward pass each."""


def warm_up(args: WarmupArgs) -> None:
    """Build, step and record each task's env once on ``args.device``, printing a line per task."""
    import torch
    import warp as wp

    from .viz.record import Recorder

    for name in args.task:
        start = time.perf_counter()
        env = tasks.make(name, num_envs=1, device=args.device, sim={"solver": args.solver})
        env.step(torch.zeros(1, env.num_actions, device=env.device))
        if args.recording:
            with tempfile.TemporaryDirectory() as out:
                recorder = Recorder.of_env(env, out)
                recorder(0)
                recorder.close()
        env.close()
        if args.gradients and not env.sees_images:
            warm_up_gradients(name, args.device)
        print(f"{name}: ready on {env.device} in {time.perf_counter() - start:.1f} s", flush=True)
    print(f"Warp kernel cache: {wp.config.kernel_cache_dir}")


def warm_up_gradients(name: str, device: str) -> None:
    """One step of task ``name``'s differentiable rollout and its backward pass, on an env built with adjoints."""
    import torch

    from .gradients.rollout import DifferentiableRollout

    env = tasks.make(name, num_envs=1, device=device, sim={"gradients": True})
    rollout = DifferentiableRollout(env, horizon=1)
    q, qd = env.joint_state()
    actions = torch.zeros(1, 1, env.num_actions, device=env.device, requires_grad=True)
    rollout(q, qd, actions=actions).rewards.sum().backward()
    env.close()


def main(argv: list[str] | None = None) -> int:
    quiet_libraries()
    with clean_errors(ConfigError, StageError):
        args = parse(WarmupArgs, WarmupArgs(), sys.argv[1:] if argv is None else argv, __doc__)
        unknown = sorted(set(args.task) - set(tasks.names()))
        require(not unknown, f"unknown task {', '.join(unknown)}; known tasks: {', '.join(tasks.names())}")
        warm_up(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
