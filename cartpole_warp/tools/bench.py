"""Throughput benchmark: env-steps/s of the physics alone and of the full env step, over a sweep of num_envs.

Run: ``python -m cartpole_warp.tools.bench --device cpu [--task cartpole-swingup] [--num-envs 64 1024 4096]
[--solver featherstone mujoco] [--tile-gemm off on] [--randomization off robust]``

"Physics alone" replays a captured graph of random actions -> the task's joint forces -> ``decimation`` solver steps
(``BatchedEnv.physics_step``), without observations, rewards or resets; "full step" times ``env.step`` (action copy,
captured step, output tensors). One env-step is one robot advanced by one env step (``decimation`` physics steps).
``--randomization off robust`` measures both without and with a preset's domain randomization (its cost: the ratio
of the two rows' full-step rates).
"""

from __future__ import annotations

import itertools
import math
import platform
import sys
import time
from dataclasses import dataclass, field

import torch
import warp as wp

from .. import tasks
from ..cli import clean_errors, parse, quiet_libraries
from ..engine.runtime import GraphReplay, collection_paused, resolve_device
from ..engine.scene import StageError
from ..settings.config import Capture, ConfigError, EnvConfig, Solver, Switch, require
from ..settings.presets import load_preset


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


def physics_rate(task: str, cfg: EnvConfig, min_seconds: float) -> float:
    """env-steps/s of captured graphs of ``physics_step`` on a fresh env, sharded (and threaded on the CPU) as the
    env steps."""
    env = tasks.get(task).env_class(cfg)
    graphs = []
    for shard in env.shards:
        with collection_paused(), wp.ScopedCapture(device=env.device) as capture:
            env.physics_step(shard)
        graphs.append(capture.graph)
    replay = GraphReplay(graphs)
    try:
        return _rate(replay, cfg.num_envs, min_seconds, lambda: wp.synchronize_device(env.device))
    finally:
        replay.close()
        env.close()


def full_step_rate(task: str, cfg: EnvConfig, min_seconds: float) -> tuple[float, int]:
    """(env-steps/s of ``env.step`` with fixed random actions, the env's shards)."""
    env = tasks.get(task).env_class(cfg)
    actions = torch.rand((cfg.num_envs, env.num_actions), device=env.device) * 2 - 1
    try:
        rate = _rate(lambda: env.step(actions), cfg.num_envs, min_seconds, lambda: wp.synchronize_device(env.device))
        return rate, len(env.shards)
    finally:
        env.close()


def tile_setting(tiles: Switch | None) -> dict:
    """``sim.tile_gemm`` where the sweep names it (None: the task's own)."""
    return {} if tiles is None else {"tile_gemm": tiles}


def device_name(device: str) -> str:
    if device.startswith("cuda"):
        return torch.cuda.get_device_name(device)
    return f"{platform.processor() or platform.machine()} CPU, {torch.get_num_threads()} threads visible"


@dataclass
class BenchArgs:
    task: str = tasks.DEFAULT_TASK
    """The registered task to step."""
    device: str = "cpu"
    """'cpu' or 'cuda:N'."""
    num_envs: list[int] | None = None
    """Sweep of num_envs (default: 64 1024 4096 on the CPU; 4096 16384 65536 on CUDA)."""
    solver: list[Solver] = field(default_factory=lambda: ["featherstone"])
    """Solvers to measure."""
    capture: list[Capture] = field(default_factory=lambda: ["auto"])
    """Graph capture settings of the full env step to measure."""
    tile_gemm: list[Switch] | None = None
    """SolverFeatherstone's paths to measure (``sim.tile_gemm``: 'auto', 'on', 'off'; default: the task's own)."""
    cpu_threads: list[int] = field(default_factory=lambda: [0])
    """sim.cpu_threads values to sweep on the CPU (0 = one per core)."""
    preset: str | None = None
    """Config preset of the env (None: the task's defaults)."""
    randomization: list[str] = field(default_factory=lambda: ["off"])
    """Domain randomization to measure: 'off' (the preset's own), or a preset whose ``env.randomization`` section
    replaces it (e.g. 'robust')."""
    seconds: float = 2.0
    """Minimum timed seconds per figure."""


def main(argv: list[str] | None = None) -> int:
    quiet_libraries()
    with clean_errors(ConfigError, StageError):
        args = parse(BenchArgs, BenchArgs(), sys.argv[1:] if argv is None else argv, __doc__)
        require(math.isfinite(args.seconds) and args.seconds > 0, f"--seconds must be finite and > 0, got "
                                                                  f"{args.seconds}")
        sweep = args.num_envs or ([4096, 16384, 65536] if args.device.startswith("cuda") else [64, 1024, 4096])
        sweeps = itertools.product(args.solver, args.tile_gemm or [None], args.capture, args.cpu_threads, sweep,
                                   args.randomization)
        configs = [(randomized, tasks.env_config(
            args.task, args.preset, num_envs=n, device=args.device, seed=0,
            sim={"solver": solver, "capture": capture, "cpu_threads": threads} | tile_setting(tiles),
            randomization=None if randomized == "off" else load_preset(randomized).get("env", {})["randomization"]))
            for solver, tiles, capture, threads, n, randomized in sweeps]
        print(f"device: {args.device} ({device_name(resolve_device(args.device))})")
        print(f"task: {args.task}, preset: {args.preset}; env-steps/s (one env-step = one robot advanced one env "
              "step)")
        print(f"{'solver':<13} {'tiles':>5} {'capture':>7} {'shards':>6} {'num_envs':>9} {'randomization':>13} "
              f"{'physics alone':>15} "
              f"{'full step':>15} {'full/physics':>13}")
        for randomized, cfg in configs:
            physics = physics_rate(args.task, cfg, args.seconds)
            full, shards = full_step_rate(args.task, cfg, args.seconds)
            tiles = "on" if cfg.sim.tiles(args.device) else "off"
            print(f"{cfg.sim.solver:<13} {tiles:>5} {cfg.sim.capture:>7} {shards:>6} {cfg.num_envs:>9} "
                  f"{randomized:>13} {physics:>15,.0f} {full:>15,.0f} {full / physics:>12.1%}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
