"""The Isaac Sim tutorial's Stable-Baselines3 PPO: train it into a run folder, load it back as a policy.

    from cartpole_warp import env_config
    from cartpole_warp.sb3_agent import load_sb3_policy, train_tutorial_ppo

    stats = train_tutorial_ppo(env_config("tutorial"), "runs/sb3_tutorial")  # saves ppo_cartpole.zip
    policy = load_sb3_policy("runs/sb3_tutorial/ppo_cartpole.zip")          # policy(obs (N, 4)) -> (N, 1)

Needs the ``[sb3]`` extra (stable-baselines3).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path

import torch
from stable_baselines3 import PPO
from stable_baselines3.common.logger import configure

from .config import EnvConfig, Sb3PpoConfig, TrainConfig
from .env import CartpoleEnv
from .metrics import is_solved
from .runs import SB3_MODEL_FILE, versions, write_summary
from .sb3_env import CartpoleSb3VecEnv

def train_tutorial_ppo(env_cfg: EnvConfig, run_dir: str | Path, ppo: Sb3PpoConfig | None = None,
                       seed: int | None = None, device: str = "cpu", tensorboard: bool = True, verbose: int = 1,
                       torch_threads: int | None = 1) -> dict:
    """Train SB3 PPO (``ppo``: the tutorial's settings and 100k steps by default) on ``CartpoleEnv(env_cfg)``
    and save ``run_dir/ppo_cartpole.zip``.

    ``seed`` (default ``env_cfg.seed``) seeds torch, numpy and the env. ``device`` is the policy's torch device.
    TensorBoard events go to ``run_dir``; ``verbose=1`` prints SB3's progress table. ``torch_threads`` CPU threads
    run the updates (restored afterwards; None keeps torch's): 1 is fastest for this small MLP, and on a busy
    2-core CPU several times faster than 2.
    Returns ``model_path``, ``timesteps``, ``wall_time_s``, ``episodes`` (ended during training) and
    ``ep_len_mean`` / ``ep_rew_mean`` (SB3's means over the last 100 episodes; nan if none ended).
    """
    run_dir = Path(run_dir)
    seed = env_cfg.seed if seed is None else seed
    venv = CartpoleSb3VecEnv(CartpoleEnv(env_cfg))
    ppo = ppo or Sb3PpoConfig()
    kwargs = {k: v for k, v in dataclasses.asdict(ppo).items() if k != "total_timesteps"}
    model = PPO("MlpPolicy", venv, seed=seed, device=device, verbose=verbose, **kwargs)
    formats = (["stdout"] if verbose else []) + (["tensorboard"] if tensorboard else [])
    model.set_logger(configure(str(run_dir), formats))
    threads = torch.get_num_threads()
    torch.set_num_threads(torch_threads or threads)
    try:
        start = time.perf_counter()
        model.learn(total_timesteps=ppo.total_timesteps)
        wall_time_s = time.perf_counter() - start
    finally:
        torch.set_num_threads(threads)
    model_path = run_dir / SB3_MODEL_FILE
    model.save(model_path)
    episodes = list(model.ep_info_buffer)
    return {
        "model_path": str(model_path),
        "timesteps": model.num_timesteps,
        "wall_time_s": wall_time_s,
        "episodes": venv.episode_count,
        "ep_len_mean": sum(e["l"] for e in episodes) / len(episodes) if episodes else math.nan,
        "ep_rew_mean": sum(e["r"] for e in episodes) / len(episodes) if episodes else math.nan,
    }


def train_run(cfg: TrainConfig, run_dir: Path) -> dict:
    """``train.py --algo sb3``: train per ``cfg`` into ``run_dir`` and write its ``summary.json``; return the summary."""
    stats = train_tutorial_ppo(cfg.env, run_dir, ppo=cfg.sb3, device=cfg.env.device,
                               tensorboard=cfg.train.logger == "tensorboard", torch_threads=cfg.train.torch_threads or None)
    per_step = stats["ep_rew_mean"] / stats["ep_len_mean"] if stats["episodes"] else None
    max_length = cfg.env.max_episode_length
    has_limit = cfg.env.task.episode_length_s is not None
    summary = {
        "algo": "sb3",
        "status": "completed",
        "env_steps": stats["timesteps"],
        "train_time_s": round(stats["wall_time_s"], 3),
        "env_steps_per_s": round(stats["timesteps"] / stats["wall_time_s"]),
        "episodes": stats["episodes"],
        "final": {"mean_episode_length": round(stats["ep_len_mean"], 2) if stats["episodes"] else None,
                  "mean_return": round(stats["ep_rew_mean"], 3) if stats["episodes"] else None,
                  "mean_reward_per_step": round(per_step, 4) if per_step is not None else None,
                  "over": "SB3's last 100 episodes"},
        "max_episode_length": max_length if has_limit else None,
        "solved": is_solved(stats["ep_len_mean"], per_step, max_length) if has_limit and stats["episodes"] else None,
        "num_envs": cfg.env.num_envs,
        "device": cfg.env.device,
        "checkpoint": SB3_MODEL_FILE,
        "versions": versions(),
    }
    write_summary(run_dir, summary)
    return summary


def load_sb3_policy(path: str | Path, device: str = "cpu") -> Callable[[torch.Tensor], torch.Tensor]:
    """Load an SB3 PPO model (e.g. ``run_dir/ppo_cartpole.zip``) as a deterministic policy.

    The returned ``policy(obs)`` maps (N, 4) float32 observations to (N, 1) actions in [-1, 1] on ``obs.device``;
    the network runs on ``device``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no SB3 model at {path}; train one with train_tutorial_ppo (train.py --algo sb3)")
    net = PPO.load(path, device=device).policy
    net.set_training_mode(False)

    def policy(obs: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            actions = net.get_distribution(obs.to(net.device, torch.float32)).get_actions(deterministic=True)
        return actions.reshape(-1, 1).clamp(-1.0, 1.0).to(obs.device)

    return policy
