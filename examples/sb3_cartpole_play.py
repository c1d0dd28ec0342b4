"""The Isaac Sim tutorial's ``cartpole_play.py`` on cartpole_warp: run a policy trained by sb3_cartpole_train.py.

    python examples/sb3_cartpole_play.py [--model-path logs/sb3/ppo_cartpole] [--steps 2000]

The tutorial's loop (``model.predict`` then ``env.step``, the env continuing into the next episode by itself),
for a number of steps instead of until the Isaac Sim window closes; it prints each episode as it ends.
"""

import os
import sys
from dataclasses import dataclass

import tyro


@dataclass
class Args:
    model_path: str = "logs/sb3/ppo_cartpole"
    """The model saved by sb3_cartpole_train.py (.zip added by SB3)."""
    steps: int = 2000
    """Env steps to run."""
    device: str = "cpu"
    """Torch device of the policy and of the env."""
    seed: int = 1
    """Seed of the env's reset RNG."""


args = tyro.cli(Args, description=__doc__)
if not any(os.path.isfile(path) for path in (args.model_path, f"{args.model_path}.zip")):
    sys.exit(f"error: no model at {args.model_path}.zip (relative to {os.getcwd()}): train one with "
             "python examples/sb3_cartpole_train.py from this folder, or pass --model-path")

# create the environment: the tutorial's cartpole task
import gymnasium as gym  # noqa: E402

import cartpole_warp  # noqa: E402, F401  (registers the gymnasium ids)
from cartpole_warp.cli import quiet_libraries  # noqa: E402

quiet_libraries()  # no Warp or Newton info lines

env = gym.make("cartpole_warp/CartpoleTutorial-v0", device=args.device, seed=args.seed)

# import stable baselines
from stable_baselines3 import PPO  # noqa: E402

# Run inference on the trained policy
model = PPO.load(args.model_path, device=args.device)
obs, _ = env.reset()
episode_return, episode_length = 0.0, 0
for _ in range(args.steps):
    action, _states = model.predict(obs, deterministic=True)
    obs, rewards, terminated, truncated, info = env.step(action)
    episode_return, episode_length = episode_return + rewards, episode_length + 1
    if terminated or truncated:
        print(f"episode ended ({info['end_reason']}): return {info['episode_return']:.1f}, "
              f"{info['episode_length']} steps", flush=True)
        episode_return, episode_length = 0.0, 0
print(f"{args.steps} steps run; the last episode was still running after {episode_length} steps "
      f"(return {episode_return:.1f})")

env.close()
