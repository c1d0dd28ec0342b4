"""Train the cartpole with rsl-rl PPO on the batched Warp/Newton env.

    python train.py --num-envs 4096 --device cpu          # a new run under logs/rsl_rl/cartpole/
    python train.py --resume                              # continue the newest run from its last checkpoint
    python train.py --config tutorial                     # a preset (configs/*.yaml) as the starting point
    python train.py --agent.algorithm.entropy-coef 0.01   # any config field is a flag; --help lists them all
    torchrun --nproc_per_node=2 train.py --device cuda --num-envs 4096   # 2 GPUs, 4096 envs on each

Each run folder holds config.yaml, model_<iteration>.pt, TensorBoard events, exported/policy.{onnx,pt},
learning_curve.png and summary.json. Ctrl-C stops after the current iteration and saves.
Also installed as ``python -m cartpole_warp.train``.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from .cli import asks_help, clean_errors, parse, peek, quiet_libraries, with_default_value
from .config import ConfigError
from .rl.config import TrainConfig, train_config
from .rl.distributed import Ranks
from .rl.metrics import SOLVED_LENGTH_FRACTION, SOLVED_REWARD_PER_STEP
from .rl.runs import RunError, latest_checkpoint, latest_run, load_config, new_run_dir
from .scene import StageError


@dataclass
class TrainArgs:
    cfg: Annotated[TrainConfig, tyro.conf.arg(name="")]
    config: str = "default"
    """Preset to start from: a name under configs/ (default, tutorial) or a YAML file of overrides.
    Precedence: dataclass defaults < preset (or a resumed run's config.yaml) < flags."""
    resume: str | None = None
    """Continue a run in place from its last checkpoint: a run folder, or 'latest' (a bare --resume) for the newest
    run under --log-dir. The run's config.yaml is the starting point; flags still override it."""
    checkpoint: Path | None = None
    """Continue from this checkpoint file, in its run folder (implies --resume)."""


def resolve(argv: list[str]) -> tuple[TrainConfig, Path, Path | None]:
    """(config, run folder, checkpoint to resume from or None) from the command line."""
    argv = with_default_value(argv, "--resume", "latest")
    first = peek(argv, config=None, resume=None, checkpoint=None, log_dir="logs")
    checkpoint = run_dir = None
    if (first.resume or first.checkpoint) and not asks_help(argv):
        if first.config:
            raise ConfigError("--config cannot change a resumed run; override its fields with flags instead")
        if first.checkpoint:
            checkpoint = Path(first.checkpoint)
            if not checkpoint.is_file():
                raise RunError(f"checkpoint {checkpoint} not found")
            run_dir = checkpoint.parent
        else:
            run_dir = latest_run(first.log_dir, "cartpole") if first.resume == "latest" else Path(first.resume)
            checkpoint = latest_checkpoint(run_dir)
        base = load_config(run_dir)
    else:
        base = train_config(first.config or "default")
    args = parse(TrainArgs, TrainArgs(cfg=base, config=first.config or "default"), argv, __doc__)
    cfg = args.cfg.validate()
    return cfg, run_dir or new_run_dir(cfg.log_dir, cfg.agent.experiment_name, cfg.agent.run_name), checkpoint


def main(argv: list[str] | None = None) -> int:
    quiet_libraries()
    with clean_errors(ConfigError, RunError, StageError):
        ranks = Ranks.from_environment()
        cfg, run_dir, checkpoint = resolve(sys.argv[1:] if argv is None else argv)
        import torch

        from .rl.training import Training

        say = print if ranks.writes else (lambda *args, **kwargs: None)
        say(f"run folder: {run_dir}" + (f" (resuming from {checkpoint.name})" if checkpoint else ""))
        where = f"{ranks.world_size} GPUs" if ranks.distributed else cfg.env.device
        say(f"building {cfg.env.num_envs} envs on {where} (the first run compiles Warp kernels, ~1 min)...", flush=True)
        try:
            training = Training(cfg, run_dir, resume_from=checkpoint, ranks=ranks)
            say(f"ready in {training.setup_time_s:.1f} s; solved = mean episode length >= "
                f"{SOLVED_LENGTH_FRACTION:.0%} of {training.max_episode_length} steps and reward/step >= "
                f"{SOLVED_REWARD_PER_STEP}", flush=True)
            summary = training.run()
        finally:
            if torch.distributed.is_initialized():
                torch.distributed.destroy_process_group()
    if summary is None:
        return 130 if training.runner.stop_reason == "interrupted" else 0
    print(f"{summary.status}: {summary.iterations} iterations, {summary.env_steps:,} env steps in "
          f"{summary.train_time_s:.1f} s ({summary.env_steps_per_s:,} steps/s)")
    if summary.solved_at:
        solved = summary.solved_at
        print(f"solved at iteration {solved['iterations']} after {solved['train_time_s']:.1f} s "
              f"({solved['env_steps']:,} env steps)")
    else:
        print("not solved yet: train longer (--max-iterations, or --resume)")
    print(f"artefacts in {run_dir}: {summary.checkpoint}, summary.json, learning_curve.png, "
          f"{', '.join(summary.exports)}\nwatch it: python play.py --headless --run {run_dir}")
    return 130 if summary.status == "interrupted" else 0


if __name__ == "__main__":
    sys.exit(main())
