"""Throughput benchmark: env-steps/s of the physics alone and of the full env step, over a sweep of num_envs.

Run: ``python -m cartpole_warp.bench --device cpu [--num-envs 64 1024 4096] [--solver featherstone mujoco]``

"Physics alone" replays a captured graph of random cart forces + ``decimation`` solver steps, without
observations, rewards or resets; "full step" times ``env.step`` (action copy, captured step, output tensors).
One env-step is one cartpole advanced by one env step (``decimation`` physics steps).
"""

from __future__ import annotations

import itertools
import platform
import sys
import time
from dataclasses import dataclass, field

import torch
import warp as wp

from . import kernels
from .cli import clean_errors, parse, quiet_libraries
from .config import Capture, ConfigError, EnvConfig, Solver, env_config
from .env import CartpoleEnv
from .runtime import GraphReplay, shard_bounds
from .scene import SHARDABLE_SOLVERS, StageError, build_scene


def _rate(run_once, num_envs: int, min_seconds: float, sync) -> float:
    """env-steps/s of ``run_once`` after a warm-up, timed over at least ``min_seconds``."""
    for _ in range(3):
        run_once()
    sync()
    steps, start = 0, time.perf_counter()
    while True:
        for _ in range(10):
            run_once()
        steps += 10
        sync()
        elapsed = time.perf_counter() - start
        if elapsed >= min_seconds:
            return steps * num_envs / elapsed


def shards(cfg: EnvConfig) -> list[tuple[int, int]]:
    """The env's shard bounds for ``cfg``."""
    return shard_bounds(cfg.num_envs, cfg.device, cfg.sim.cpu_threads, cfg.sim.solver in SHARDABLE_SOLVERS)


def physics_rate(cfg: EnvConfig, min_seconds: float) -> float:
    """env-steps/s of captured graphs of random cart forces + ``decimation`` solver steps on fresh scenes,
    sharded (and threaded on the CPU) like the env."""
    graphs = []
    for start, stop in shards(cfg):
        scene, num_envs = build_scene(stop - start, cfg.device, cfg.sim), stop - start
        layout = kernels.dof_layout(scene.dofs_per_env, scene.cart_dof, scene.pole_dof)
        rng_state = wp.zeros(num_envs, dtype=wp.uint32, device=cfg.device)
        wp.launch(kernels.init_rng, dim=num_envs, inputs=[cfg.seed, start], outputs=[rng_state], device=cfg.device)
        with wp.ScopedCapture(device=cfg.device) as capture:
            wp.launch(kernels.random_forces, dim=num_envs, inputs=[rng_state, kernels.task_params(cfg.task), layout],
                      outputs=[scene.control.joint_f], device=cfg.device)
            scene.simulate(cfg.sim.physics_dt, cfg.sim.decimation)
        graphs.append(capture.graph)
    replay = GraphReplay(graphs)
    try:
        return _rate(replay, cfg.num_envs, min_seconds, lambda: wp.synchronize_device(cfg.device))
    finally:
        replay.close()


def full_step_rate(cfg: EnvConfig, min_seconds: float) -> float:
    """env-steps/s of ``CartpoleEnv.step`` with fixed random actions."""
    env = CartpoleEnv(cfg)
    actions = torch.rand((cfg.num_envs, 1), device=env.device) * 2 - 1
    try:
        return _rate(lambda: env.step(actions), cfg.num_envs, min_seconds, lambda: wp.synchronize_device(env.device))
    finally:
        env.close()


def device_name(device: str) -> str:
    if device.startswith("cuda"):
        return torch.cuda.get_device_name(device)
    return f"{platform.processor() or platform.machine()} CPU, {torch.get_num_threads()} threads visible"


@dataclass
class BenchArgs:
    device: str = "cpu"
    """'cpu' or 'cuda:N'."""
    num_envs: list[int] | None = None
    """Sweep of num_envs (default: 64 1024 4096 on the CPU; 4096 16384 65536 on CUDA)."""
    solver: list[Solver] = field(default_factory=lambda: ["featherstone"])
    """Solvers to measure."""
    capture: list[Capture] = field(default_factory=lambda: ["auto"])
    """Graph capture settings of the full env step to measure."""
    cpu_threads: list[int] = field(default_factory=lambda: [0])
    """sim.cpu_threads values to sweep on the CPU (0 = one per core)."""
    preset: str = "default"
    """Config preset of the env."""
    seconds: float = 2.0
    """Minimum timed seconds per figure."""


def main(argv: list[str] | None = None) -> int:
    quiet_libraries()
    with clean_errors(ConfigError, StageError):
        args = parse(BenchArgs, BenchArgs(), sys.argv[1:] if argv is None else argv, __doc__)
        sweep = args.num_envs or ([4096, 16384, 65536] if args.device.startswith("cuda") else [64, 1024, 4096])
        sweeps = itertools.product(args.solver, args.capture, args.cpu_threads, sweep)
        configs = [env_config(args.preset, num_envs=n, device=args.device, seed=0,
                              sim={"solver": solver, "capture": capture, "cpu_threads": threads})
                   for solver, capture, threads, n in sweeps]
        from .runtime import resolve_device

        print(f"device: {args.device} ({device_name(resolve_device(args.device))})")
        print(f"preset: {args.preset}; env-steps/s (one env-step = one cartpole advanced one env step)")
        print(f"{'solver':<13} {'capture':>7} {'shards':>6} {'num_envs':>9} {'physics alone':>15} {'full step':>15} "
              f"{'full/physics':>13}")
        for cfg in configs:
            physics, full = physics_rate(cfg, args.seconds), full_step_rate(cfg, args.seconds)
            print(f"{cfg.sim.solver:<13} {cfg.sim.capture:>7} {len(shards(cfg)):>6} {cfg.num_envs:>9} "
                  f"{physics:>15,.0f} {full:>15,.0f} {full / physics:>12.1%}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
