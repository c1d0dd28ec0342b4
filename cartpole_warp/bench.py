"""Throughput benchmark: env-steps/s of the physics alone and of the full env step, over a sweep of num_envs.

Run: ``python -m cartpole_warp.bench --device cpu [--num-envs 64 1024 4096] [--solver featherstone mujoco]``

"Physics alone" replays a captured graph of random cart forces + ``decimation`` solver steps, without
observations, rewards or resets; "full step" times ``env.step`` (action copy, captured step, output tensors).
One env-step is one cartpole advanced by one env step (``decimation`` physics steps).
"""

from __future__ import annotations

import argparse
import itertools
import platform
import time

import torch
import warp as wp

from . import kernels
from .config import EnvConfig, SimConfig, env_config
from .env import CartpoleEnv, GraphReplay, task_params
from .scene import build_scene, shard_bounds


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


def physics_rate(cfg: EnvConfig, min_seconds: float) -> float:
    """env-steps/s of captured graphs of random cart forces + ``decimation`` solver steps on fresh scenes,
    sharded (and threaded on the CPU) like the env."""
    graphs = []
    for start, stop in shard_bounds(cfg.num_envs, cfg.device, cfg.sim):
        scene, num_envs = build_scene(stop - start, cfg.device, cfg.sim), stop - start
        rng_state = wp.zeros(num_envs, dtype=wp.uint32, device=cfg.device)
        wp.launch(kernels.init_rng, dim=num_envs, inputs=[cfg.seed, start], outputs=[rng_state], device=cfg.device)
        with wp.ScopedCapture(device=cfg.device) as capture:
            wp.launch(kernels.random_forces, dim=num_envs, inputs=[rng_state, task_params(cfg, scene)],
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


def measure(num_envs: int, device: str, solver: str, capture: str, cpu_threads: int, preset: str,
            min_seconds: float) -> dict:
    """Physics-only and full-step env-steps/s for one configuration."""
    cfg = env_config(preset, num_envs=num_envs, device=device, seed=0,
                     sim={"solver": solver, "capture": capture, "cpu_threads": cpu_threads})
    return {"physics": physics_rate(cfg, min_seconds), "full": full_step_rate(cfg, min_seconds)}


def device_name(device: str) -> str:
    if device.startswith("cuda"):
        return torch.cuda.get_device_name(device)
    return f"{platform.processor() or platform.machine()} CPU, {torch.get_num_threads()} threads visible"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cpu", help="'cpu' or 'cuda:N' (default: cpu)")
    parser.add_argument("--num-envs", type=int, nargs="+", default=None,
                        help="sweep of num_envs (default: 64 1024 4096 on CPU; 4096 16384 65536 on CUDA)")
    parser.add_argument("--solver", nargs="+", default=["featherstone"], choices=["featherstone", "mujoco"])
    parser.add_argument("--capture", nargs="+", default=["auto"], choices=["auto", "on", "off"],
                        help="graph capture of the full env step (default: auto)")
    parser.add_argument("--cpu-threads", type=int, nargs="+", default=[0],
                        help="sim.cpu_threads values to sweep on the CPU (default: 0 = one per core)")
    parser.add_argument("--preset", default="default", help="config preset (default: default)")
    parser.add_argument("--seconds", type=float, default=2.0, help="minimum timed seconds per figure (default: 2)")
    args = parser.parse_args(argv)
    sweep = args.num_envs or ([4096, 16384, 65536] if args.device.startswith("cuda") else [64, 1024, 4096])

    print(f"device: {args.device} ({device_name(args.device) if args.device == 'cpu' or torch.cuda.is_available() else '?'})")
    print(f"preset: {args.preset}; env-steps/s (one env-step = one cartpole advanced one env step)")
    print(f"{'solver':<13} {'capture':>7} {'shards':>6} {'num_envs':>9} {'physics alone':>15} {'full step':>15} "
          f"{'full/physics':>13}")
    for solver, capture, threads, n in itertools.product(args.solver, args.capture, args.cpu_threads, sweep):
        r = measure(n, args.device, solver, capture, threads, args.preset, args.seconds)
        shards = len(shard_bounds(n, args.device, SimConfig(solver=solver, cpu_threads=threads)))
        print(f"{solver:<13} {capture:>7} {shards:>6} {n:>9} {r['physics']:>15,.0f} {r['full']:>15,.0f} "
              f"{r['full'] / r['physics']:>12.1%}", flush=True)


if __name__ == "__main__":
    main()
