"""Train the cartpole with rsl-rl PPO on the batched Warp/Newton env.

    python train.py --num-envs 4096 --device cpu          # a new run under logs/rsl_rl/cartpole/
    python train.py --resume                              # continue the newest run from its last checkpoint
    python train.py --algo sb3 --config configs/tutorial.yaml   # the Isaac Sim tutorial's SB3 PPO, one env
    python train.py --help                                # every flag and config field

Each run folder holds config.yaml, model_<iteration>.pt, TensorBoard events, exported/policy.{onnx,pt},
learning_curve.png and summary.json. Ctrl-C stops after the current iteration and saves.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cartpole_warp.cli import add_config_arguments, apply_sets, clean_errors
from cartpole_warp.config import ALGOS, LOGGERS, ConfigError, train_config
from cartpole_warp.metrics import SOLVED_LENGTH_FRACTION, SOLVED_REWARD_PER_STEP
from cartpole_warp.runs import RunError, create_run_dir, latest_checkpoint, latest_run, load_config, save_config


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--algo", choices=ALGOS,
                        help="rsl_rl: rsl-rl PPO (default); sb3: Stable-Baselines3 PPO as in the Isaac Sim tutorial "
                             "(needs pip install -e '.[sb3]'; its settings are the sb3.* fields)")
    parser.add_argument("--num-envs", type=int, help="parallel cartpoles (env.num_envs; default 4096)")
    parser.add_argument("--device", help="'cpu' or 'cuda:N' (env.device; default cpu)")
    parser.add_argument("--seed", type=int, help="env reset RNG and torch seed (env.seed; default 0)")
    parser.add_argument("--max-iterations", type=int, help="PPO iterations to run, or to add on --resume (default 150)")
    parser.add_argument("--logger", choices=LOGGERS, help="metrics writer (train.logger; default tensorboard)")
    parser.add_argument("--console", choices=("compact", "rsl_rl"), help="one line per iteration or rsl-rl's block")
    parser.add_argument("--stop-when-solved", action="store_true", help="end at the first solved iteration")
    parser.add_argument("--run-name", help="suffix of the run folder name")
    parser.add_argument("--log-dir", help="root of all runs (train.log_dir; default logs)")
    parser.add_argument("--resume", nargs="?", const="latest", metavar="RUN_DIR",
                        help="continue a run in place from its last checkpoint (default: the newest run)")
    parser.add_argument("--checkpoint", type=Path, metavar="FILE",
                        help="continue from this checkpoint, in its run folder (implies --resume)")
    add_config_arguments(parser)
    return parser.parse_args(argv)


def resolve(args: argparse.Namespace):
    """(config, run folder, checkpoint to resume from or None) from the command line."""
    log_dir = args.log_dir
    if args.resume or args.checkpoint:
        if args.algo == "sb3":
            raise ConfigError("--resume and --checkpoint continue rsl_rl runs; an sb3 run always starts fresh")
        if args.config:
            raise ConfigError("--config cannot change a resumed run; use --set or flags to override its saved config")
        if args.checkpoint:
            checkpoint = args.checkpoint
            if not checkpoint.is_file():
                raise RunError(f"checkpoint {checkpoint} not found")
            run_dir = checkpoint.parent
        else:
            run_dir = (latest_run(log_dir or "logs", "rsl_rl", "cartpole") if args.resume == "latest"
                       else Path(args.resume))
            checkpoint = latest_checkpoint(run_dir)
        cfg = load_config(run_dir)
    else:
        cfg, run_dir, checkpoint = train_config(args.config or "default"), None, None
    apply_sets(cfg, args.set)
    if args.algo:
        cfg.algo = args.algo
    flags = {
        "env.num_envs": args.num_envs, "env.device": args.device, "env.seed": args.seed,
        "train.max_iterations": args.max_iterations, "train.logger": args.logger, "train.console": args.console,
        "train.run_name": args.run_name, "train.log_dir": log_dir,
        "train.stop_when_solved": True if args.stop_when_solved else None,
    }
    for key, value in flags.items():
        if value is not None:
            section, name = key.split(".")
            setattr(getattr(cfg, section), name, value)
    cfg.validate()
    if run_dir is None:
        run_dir = create_run_dir(cfg.train.log_dir, cfg.algo, cfg.train.experiment_name, cfg.train.run_name)
    return cfg, run_dir, checkpoint


def main(argv=None) -> int:
    args = parse_args(argv)
    from cartpole_warp.scene import StageError

    with clean_errors(ConfigError, RunError, StageError):
        cfg, run_dir, checkpoint = resolve(args)
        import torch

        torch.manual_seed(cfg.env.seed)
        if cfg.train.torch_threads:
            torch.set_num_threads(cfg.train.torch_threads)
        print(f"run folder: {run_dir}" + (f" (resuming from {checkpoint.name})" if checkpoint else ""))
        save_config(run_dir, cfg)
        if cfg.algo == "sb3":
            return train_sb3(cfg, run_dir)
        from cartpole_warp.trainer import RslRlTrainer

        print(f"building {cfg.env.num_envs} envs on {cfg.env.device} (the first run compiles Warp kernels, ~1 min)...",
              flush=True)
        trainer = RslRlTrainer(cfg, run_dir, resume_from=checkpoint)
        print(f"ready in {trainer.setup_time_s:.1f} s; solved = mean episode length >= {SOLVED_LENGTH_FRACTION:.0%} of "
              f"{trainer.max_episode_length} steps and reward/step >= {SOLVED_REWARD_PER_STEP}", flush=True)
        summary = trainer.train()
    solved = summary["solved_at"]
    print(f"{summary['status']}: {summary['iterations']} iterations, {summary['env_steps']:,} env steps in "
          f"{summary['train_time_s']:.1f} s ({summary['env_steps_per_s']:,} steps/s)")
    if solved:
        print(f"solved at iteration {solved['iterations']} after {solved['train_time_s']:.1f} s "
              f"({solved['env_steps']:,} env steps)")
    else:
        print("not solved yet: train longer (--max-iterations, or --resume)")
    print(f"artefacts in {run_dir}: {summary['checkpoint']}, summary.json, learning_curve.png, "
          f"{', '.join(summary['exports'])}\nwatch it: python play.py --headless --run {run_dir}")
    return 130 if summary["status"] == "interrupted" else 0


def train_sb3(cfg, run_dir: Path) -> int:
    """The tutorial's SB3 PPO: SB3's progress table, then ppo_cartpole.zip and summary.json in ``run_dir``."""
    try:
        from cartpole_warp.sb3_agent import train_run
    except ModuleNotFoundError as err:
        raise ConfigError(f"--algo sb3 needs stable-baselines3 ({err}): pip install -e '.[sb3]'") from None
    print(f"SB3 PPO on {cfg.env.num_envs} env(s), {cfg.sb3.total_timesteps:,} timesteps "
          f"(the first run compiles Warp kernels, ~1 min)...", flush=True)
    summary = train_run(cfg, run_dir)
    final = summary["final"]
    print(f"completed: {summary['env_steps']:,} env steps in {summary['train_time_s']:.1f} s "
          f"({summary['env_steps_per_s']:,} steps/s); {summary['episodes']} episodes ended; last 100: mean length "
          f"{final['mean_episode_length']}, mean return {final['mean_return']}")
    print(f"artefacts in {run_dir}: {summary['checkpoint']}, summary.json, TensorBoard events\n"
          f"watch it: python play.py --headless --run {run_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
