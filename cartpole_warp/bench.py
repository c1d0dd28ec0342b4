"""Throughput benchmark: env-steps/s of the physics alone and of the full env step, over a sweep of num_envs.

Run: ``python -m cartpole_warp.bench --device cpu [--num-envs 64 1024 4096] [--solver featherstone mujoco]``

"Physics alone" replays a captured graph of random cart forces + ``decimation`` solver steps, without
observations, rewards or resets; "full step" times ``env.step`` (action copy, captured step, output tensors).
One env-step is one cartpole advanced by one env step (``decimation`` physics steps).
"""

from __future__ import annotations

import argparse
import platform
import time

import torch
import warp as wp

from . import kernels
from .config import env_config
from .env import CartpoleEnv


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


def measure(num_envs: int, device: str, solver: str, preset: str, min_seconds: float) -> dict:
    """Physics-only and full-step env-steps/s for one configuration."""
    cfg = env_config(preset, num_envs=num_envs, device=device, seed=0, sim={"solver": solver})
    env = CartpoleEnv(cfg)
    scene, sim = env.scene, cfg.sim
    sync = (lambda: torch.cuda.synchronize(device)) if device.startswith("cuda") else (lambda: None)

    with wp.ScopedCapture(device=env.device) as capture:
        wp.launch(kernels.random_forces, dim=num_envs, inputs=[env._rng_state, env.params],
                  outputs=[scene.control.joint_f], device=env.device)
        scene.simulate(sim.physics_dt, sim.decimation)
    physics = _rate(lambda: wp.capture_launch(capture.graph), num_envs, min_seconds, wp.synchronize_device)

    env.reset()
    actions = torch.rand((num_envs, 1), device=env.device) * 2 - 1
    full = _rate(lambda: env.step(actions), num_envs, min_seconds, sync)
    return {"num_envs": num_envs, "solver": solver, "physics": physics, "full": full}


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
    parser.add_argument("--preset", default="default", help="config preset (default: default)")
    parser.add_argument("--seconds", type=float, default=2.0, help="minimum timed seconds per figure (default: 2)")
    args = parser.parse_args(argv)
    sweep = args.num_envs or ([4096, 16384, 65536] if args.device.startswith("cuda") else [64, 1024, 4096])

    print(f"device: {args.device} ({device_name(args.device) if args.device == 'cpu' or torch.cuda.is_available() else '?'})")
    print(f"preset: {args.preset}; env-steps/s (one env-step = one cartpole advanced one env step)")
    print(f"{'solver':<13} {'num_envs':>9} {'physics alone':>15} {'full step':>15} {'full/physics':>13}")
    for solver in args.solver:
        for n in sweep:
            r = measure(n, args.device, solver, args.preset, args.seconds)
            print(f"{solver:<13} {n:>9} {r['physics']:>15,.0f} {r['full']:>15,.0f} {r['full'] / r['physics']:>12.1%}",
                  flush=True)


if __name__ == "__main__":
    main()
