"""The Isaac Sim tutorial's ``cartpole_train.py`` on cartpole_warp: Stable-Baselines3 PPO on one cartpole.

    pip install -e '.[sb3]'
    python examples/sb3_cartpole_train.py       # 100k steps: logs/sb3/ppo_cartpole.zip, TensorBoard logs
    python examples/sb3_cartpole_play.py        # runs the trained policy

The tutorial's script line for line, except: ``VecEnvBase(headless=True)`` + ``CartpoleTask`` become the registered
gymnasium env (the tutorial's task and timing, one env, no time limit), the device is a flag (the tutorial's
``cuda:0``; this small MLP is as fast on the CPU), and torch runs on one CPU thread (several times faster than
two on a busy 2-core CPU).
"""

from dataclasses import dataclass

import tyro


@dataclass
class Args:
    total_timesteps: int = 100_000
    """Env steps to train for (the tutorial's model.learn(total_timesteps=100000))."""
    model_path: str = "logs/sb3/ppo_cartpole"
    """Where the model is saved; SB3 adds .zip (the tutorial's model.save("ppo_cartpole"), under logs/ like every run
    here, which git ignores)."""
    tensorboard_log: str = "logs/sb3/cartpole_tensorboard"
    """TensorBoard folder (the tutorial's ./cartpole_tensorboard, under logs/)."""
    device: str = "cpu"
    """Torch device of the policy and of the env."""
    seed: int = 0
    """Seed of the env's reset RNG and of SB3."""
    torch_threads: int = 1
    """CPU threads for torch."""


args = tyro.cli(Args, description=__doc__)

# create the environment: the tutorial's cartpole task
import gymnasium as gym  # noqa: E402
import torch  # noqa: E402

import cartpole_warp  # noqa: E402, F401  (registers the gymnasium ids)
from cartpole_warp.cli import quiet_libraries  # noqa: E402

quiet_libraries()  # no Warp or Newton info lines

torch.set_num_threads(args.torch_threads)
env = gym.make("cartpole_warp/CartpoleTutorial-v0", device=args.device, seed=args.seed)

from stable_baselines3 import PPO  # noqa: E402

# create agent from stable baselines
model = PPO(
    "MlpPolicy",
    env,
    n_steps=1000,
    batch_size=1000,
    n_epochs=20,
    learning_rate=0.001,
    gamma=0.99,
    device=args.device,
    ent_coef=0.0,
    vf_coef=0.5,
    max_grad_norm=1.0,
    verbose=1,
    tensorboard_log=args.tensorboard_log,
    seed=args.seed,
)
model.learn(total_timesteps=args.total_timesteps)
model.save(args.model_path)

env.close()
