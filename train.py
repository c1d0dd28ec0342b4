"""Train the cartpole with rsl-rl PPO: ``python train.py --help`` lists every flag (code: cartpole_warp/train.py)."""

import sys

from cartpole_warp.train import main

if __name__ == "__main__":
    sys.exit(main())
