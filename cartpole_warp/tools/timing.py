"""Where the time of one PPO iteration goes, for the training settings given as train.py flags.

    python -m cartpole_warp.tools.timing --device cuda:0                            # the default task and settings
    python -m cartpole_warp.tools.timing --device cuda:0 --config isaac_lab         # Isaac Lab's
    python -m cartpole_warp.tools.timing --device cuda:0 --task cartpole-swingup    # another task

Times (device-synchronised, means over repeats after three warm-up iterations, by which time training has captured
its CUDA graphs on a GPU): ``env.step`` alone; one rollout step launched op by op (policy ``act`` + ``env.step`` +
``process_env_step`` + episode statistics); one iteration's rollout and returns as training runs them (one graph
replay on a GPU with ``agent.cuda_graph``); the PPO update as training runs it; whole iterations of
``TrainingLoop.learn``.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

import torch

from ..cli import clean_errors, quiet_libraries
from ..engine.scene import StageError
from ..rl.loop import TrainingLoop
from ..rl.runs import RunError
from ..settings.config import ConfigError, require
from ..train import resolve
from ..wrappers.rsl_rl import RslRlVecEnv


def timed_ms(work: Callable[[], object], device: str, repeats: int) -> float:
    """Mean milliseconds of ``work()``, the device synchronised before and after."""
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    sync()
    start = time.perf_counter()
    for _ in range(repeats):
        work()
    sync()
    return (time.perf_counter() - start) / repeats * 1e3


def main(argv: list[str] | None = None) -> int:
    quiet_libraries()
    with clean_errors(ConfigError, RunError, StageError):
        cfg, _, _ = resolve(sys.argv[1:] if argv is None else argv)
        require(cfg.agent.learner == "ppo", f"tools.timing splits a PPO iteration; a --learner {cfg.agent.learner} "
                                            "run's collection and learning ms are in its summary.json and tools.sweep")
    torch.manual_seed(cfg.env.seed)
    cfg.apply_torch_threads()
    env = RslRlVecEnv(cfg.task_spec.env_class(cfg.env))
    loop = TrainingLoop(env, cfg, None)
    device, steps, alg = env.device, cfg.agent.num_steps_per_env, loop.learner.alg
    loop.learn(3)
    obs = env.get_observations()

    def rollout_step():
        nonlocal obs
        with torch.inference_mode():
            obs, rewards, dones, extras = env.step(alg.act(obs))
            alg.process_env_step(obs, rewards, dones, extras)
            loop.learner.episodes.add(dones.bool(), extras["episode_return"], extras["episode_length"],
                                      extras["time_outs"])

    def rollout():
        nonlocal obs
        with torch.inference_mode():
            obs = loop.learner.collect(obs)

    zeros = torch.zeros(env.num_envs, 1, device=device)
    rows = {"env.step alone": timed_ms(lambda: env.step(zeros), device, 50)}
    rows["rollout step launched op by op (act + env.step + storage + stats)"] = timed_ms(rollout_step, device, steps)
    alg.storage.clear()
    rows[f"rollout of {steps} steps + returns, as training runs it"] = timed_ms(rollout, device, 1)
    rows["update (all mini-batches), as training runs it"] = timed_ms(alg.update, device, 1)
    iterations = 10
    rows["whole iteration (TrainingLoop.learn)"] = timed_ms(lambda: loop.learn(iterations), device, 1) / iterations
    per_iteration = rows["whole iteration (TrainingLoop.learn)"]
    name = torch.cuda.get_device_name(device) if device.startswith("cuda") else "CPU"
    print(f"\n{name}, {env.num_envs} envs, {steps} steps per env, {type(alg).__name__}, "
          f"{alg.num_learning_epochs} epochs x {alg.num_mini_batches} mini-batches")
    for what, ms in rows.items():
        print(f"  {what:<66} {ms:9.3f} ms")
    print(f"  {'env steps per second including PPO':<66} {env.num_envs * steps / per_iteration * 1e3:12,.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
