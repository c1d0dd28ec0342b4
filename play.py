"""Watch a policy on the cartpole: ``python play.py --help`` lists every flag (the code: cartpole_warp/play.py)."""

import sys

from cartpole_warp.play import main

if __name__ == "__main__":
    sys.exit(main())
