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
from dataclasses import dataclass
from pathlib import Path

import torch
from stable_baselines3 import PPO
from stable_baselines3.common.logger import configure

from .config import EnvConfig
from .env import CartpoleEnv
from .sb3_env import CartpoleSb3VecEnv

MODEL_FILE = "ppo_cartpole.zip"
"""File name of the trained model inside the run folder (the tutorial's ``model.save("ppo_cartpole")``)."""


@dataclass
class Sb3PpoConfig:
    """Keyword arguments of SB3 ``PPO("MlpPolicy", ...)``; the defaults are the tutorial's."""

    n_steps: int = 1000
    """Env steps per env in each rollout."""
    batch_size: int = 1000
    """Minibatch size (samples)."""
    n_epochs: int = 20
    """Passes over each rollout."""
    learning_rate: float = 0.001
    """Adam learning rate."""
    gamma: float = 0.99
    """Discount factor."""
    ent_coef: float = 0.0
    """Entropy bonus weight."""
    vf_coef: float = 0.5
    """Value loss weight."""
    max_grad_norm: float = 1.0
    """Gradient clipping norm."""


def train_tutorial_ppo(env_cfg: EnvConfig, run_dir: str | Path, total_timesteps: int = 100_000,
                       seed: int | None = None, device: str = "cpu", tensorboard: bool = True, verbose: int = 1,
                       ppo: Sb3PpoConfig | None = None, torch_threads: int | None = 1) -> dict:
    """Train SB3 PPO on ``CartpoleEnv(env_cfg)`` and save ``run_dir/ppo_cartpole.zip``.

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
    model = PPO("MlpPolicy", venv, seed=seed, device=device, verbose=verbose,
                **dataclasses.asdict(ppo or Sb3PpoConfig()))
    formats = (["stdout"] if verbose else []) + (["tensorboard"] if tensorboard else [])
    model.set_logger(configure(str(run_dir), formats))
    threads = torch.get_num_threads()
    torch.set_num_threads(torch_threads or threads)
    try:
        start = time.perf_counter()
        model.learn(total_timesteps=total_timesteps)
        wall_time_s = time.perf_counter() - start
    finally:
        torch.set_num_threads(threads)
    model_path = run_dir / MODEL_FILE
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
