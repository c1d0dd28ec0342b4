"""Watch a policy on the cartpole: statistics, a GIF and a USD recording (--headless) or Newton's viewer.

    python play.py --headless                    # newest run's latest checkpoint -> <run>/play/
    python play.py --headless --run DIR          # or --checkpoint FILE
    python play.py --agent zero --headless       # no checkpoint needed (also: random)
    python play.py --algo sb3 --headless         # the newest SB3 run (train.py --algo sb3)
    python play.py                               # Newton's interactive viewer (needs a display)

The env is rebuilt from the run's saved config.yaml; the policy acts deterministically (the Gaussian's mean).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from cartpole_warp.cli import add_config_arguments, apply_sets, clean_errors
from cartpole_warp.config import ALGOS, ConfigError, train_config
from cartpole_warp.runs import (CONFIG_FILE, EXPORT_DIR, PLAY_DIR, SB3_MODEL_FILE, RunError, latest_checkpoint, latest_run,
                                load_config, write_text)

DEFAULT_PLAY_ENVS = 256
NO_LIMIT_STEPS = 1000


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--agent", choices=("trained", "zero", "random"), default="trained",
                        help="trained: a checkpoint's policy; zero: no push; random: uniform in [-1, 1]")
    parser.add_argument("--algo", choices=ALGOS, default="rsl_rl",
                        help="where to look for the newest run: logs/<algo>/cartpole (default rsl_rl); a --run or "
                             "--checkpoint is played whatever trained it")
    parser.add_argument("--run", type=Path, metavar="DIR", help="run folder (default: the newest run under --log-dir)")
    parser.add_argument("--checkpoint", type=Path, metavar="FILE", help="checkpoint file (default: the run's latest)")
    parser.add_argument("--log-dir", default="logs", help="root of all runs (default logs)")
    parser.add_argument("--headless", action="store_true",
                        help="no window: print statistics, write <run>/play/cartpole.gif and cartpole.usda")
    parser.add_argument("--export", action="store_true", help="write <run>/exported/policy.onnx and policy.pt")
    parser.add_argument("--num-envs", type=int, default=DEFAULT_PLAY_ENVS,
                        help=f"episodes evaluated in parallel (default {DEFAULT_PLAY_ENVS}); env 0 is recorded")
    parser.add_argument("--device", help="'cpu' or 'cuda:N' (default: the run's)")
    parser.add_argument("--seed", type=int, help="reset RNG seed (default: the run's)")
    parser.add_argument("--steps", type=int,
                        help=f"env steps to run (default: the time limit, or {NO_LIMIT_STEPS} without one)")
    parser.add_argument("--output", type=Path, metavar="DIR",
                        help="folder for the GIF/USD/result (default <run>/play, or <log-dir>/play/<agent>)")
    add_config_arguments(parser)
    return parser.parse_args(argv)


def resolve(args: argparse.Namespace):
    """(config, checkpoint or None, folder for the outputs, run folder or None)."""
    if args.agent != "trained":
        if args.run or args.checkpoint or args.export:
            raise ConfigError(f"--agent {args.agent} takes no --run, --checkpoint or --export")
        cfg, checkpoint, run_dir = train_config(args.config or "default"), None, None
        output = args.output or Path(args.log_dir) / PLAY_DIR / args.agent
    else:
        if args.checkpoint:
            checkpoint = args.checkpoint
            if not checkpoint.is_file():
                raise RunError(f"checkpoint {checkpoint} not found")
        else:
            checkpoint = latest_checkpoint(args.run or latest_run(args.log_dir, args.algo, "cartpole"))
        run_dir = checkpoint.parent
        if args.export and checkpoint.name == SB3_MODEL_FILE:
            raise ConfigError("--export writes rsl-rl policies; an SB3 model is already a self-contained .zip")
        if (run_dir / CONFIG_FILE).is_file():
            if args.config:
                raise ConfigError(f"--config conflicts with the run's saved {run_dir / CONFIG_FILE}; use --set")
            cfg = load_config(run_dir)
        else:
            cfg = train_config(args.config or "default")
        output = args.output or run_dir / PLAY_DIR
    if args.steps is not None and args.steps < 1:
        raise ConfigError(f"--steps must be >= 1, got {args.steps}")
    apply_sets(cfg, args.set)
    cfg.env.num_envs = args.num_envs
    cfg.env.device = args.device or cfg.env.device
    cfg.env.seed = cfg.env.seed if args.seed is None else args.seed
    cfg.validate()
    return cfg, checkpoint, output, run_dir


def main(argv=None) -> int:
    args = parse_args(argv)
    from cartpole_warp.scene import StageError

    with clean_errors(ConfigError, RunError, StageError):
        cfg, checkpoint, output, run_dir = resolve(args)
        import torch

        from cartpole_warp.env import CartpoleEnv
        from cartpole_warp.render import write_gif, write_usd
        from cartpole_warp.rollout import (ViewerUnavailable, check_viewer, random_policy, rollout, view_interactively,
                                           zero_policy)
        from cartpole_warp.trainer import load_policy

        if not args.headless:
            try:
                check_viewer()
            except ViewerUnavailable as err:
                print(f"error: {err}", file=sys.stderr)
                return 1
        if cfg.train.torch_threads:
            torch.set_num_threads(cfg.train.torch_threads)
        env = CartpoleEnv(cfg.env)
        if checkpoint is not None and checkpoint.name == SB3_MODEL_FILE:
            policy = load_sb3(checkpoint, env.device)
            print(f"policy: {checkpoint}")
        elif checkpoint is not None:
            runner = load_policy(cfg, checkpoint, env)
            policy = runner.policy()
            print(f"policy: {checkpoint}")
            if args.export:
                for path in runner.export(run_dir / EXPORT_DIR):
                    print(f"exported {path}")
        else:
            policy = zero_policy if args.agent == "zero" else random_policy(cfg.env.seed)
            print(f"policy: {args.agent}")
        if not args.headless:
            try:
                view_interactively(env, policy)
            except ViewerUnavailable as err:
                print(f"error: {err}", file=sys.stderr)
                return 1
            return 0
        has_limit = cfg.env.task.episode_length_s is not None
        steps = args.steps or (env.max_episode_length if has_limit else NO_LIMIT_STEPS)
        result = rollout(env, policy, steps)
        stats = result.stats
        limit = f"the {cfg.env.task.episode_length_s:g} s time limit" if has_limit and steps >= env.max_episode_length \
            else f"the {steps}-step cap"
        print(f"{stats.episodes} episodes ({env.num_envs} envs, first episode each, {steps} steps): "
              f"mean return {stats.mean_return:.2f}, mean length {stats.mean_length:.1f} steps "
              f"({stats.mean_length * env.env_dt:.2f} s), reached {limit}: {stats.time_limit_fraction:.1%}")
        gif = write_gif(output / "cartpole.gif", result.geometry, result.frames, env.env_dt)
        usd = write_usd(output / "cartpole.usda", result.geometry, result.frames, env.env_dt)
        record = {"agent": args.agent, "checkpoint": str(checkpoint) if checkpoint else None, "num_envs": env.num_envs,
                  "steps": steps, "episodes": stats.episodes, "mean_return": stats.mean_return,
                  "mean_episode_length": stats.mean_length, "time_limit_fraction": stats.time_limit_fraction}
        result_file = write_text(output / "result.json", json.dumps(record, indent=2) + "\n")
        print(f"wrote {gif}, {usd} (open with usdview) and {result_file}")
    return 0


def load_sb3(path: Path, device: str):
    """The SB3 model at ``path`` as a deterministic policy; clear errors for a missing extra or a bad file."""
    try:
        from cartpole_warp.sb3_agent import load_sb3_policy
    except ModuleNotFoundError as err:
        raise ConfigError(f"playing {path} needs stable-baselines3 ({err}): pip install -e '.[sb3]'") from None
    try:
        return load_sb3_policy(path, device)
    except Exception as err:  # SB3 raises zipfile, pickle and key errors for damaged files
        raise RunError(f"cannot load SB3 model {path}: {type(err).__name__}: {err}") from None


if __name__ == "__main__":
    sys.exit(main())
