"""rsl-rl PPO on the batched cartpole: runner config, atomic checkpoints, progress, summary, policy export.

    trainer = RslRlTrainer(cfg, run_dir)      # builds the env (compiles Warp kernels on first use)
    result = trainer.train()                  # Ctrl-C ends after the current iteration, saved
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib.util
import io
import logging
import os
import signal
import tempfile
import time
import warnings
from pathlib import Path

import onnx
import torch
from rsl_rl.runners import OnPolicyRunner
from rsl_rl.utils.log_writer import LogWriter
from tensordict import TensorDict

from .config import ConfigError, TrainConfig
from .env import CartpoleEnv
from .metrics import SOLVED_LENGTH_FRACTION, SOLVED_REWARD_PER_STEP, is_solved
from .render import plot_learning_curve
from .rollout import Policy
from .rsl_rl_env import RslRlVecEnv
from .runs import CURVE_FILE, EXPORT_DIR, RunError, atomic_write, latest_checkpoint, versions, write_summary

ALGO = "rsl_rl"


class NullLogWriter(LogWriter):
    """Metrics writer for ``logger: none``: checkpoints and summary are still written, metrics are not."""

    def __init__(self, log_dir: str):
        self.log_dir = log_dir

    def add_scalar(self, tag: str, scalar_value: float, global_step: int) -> None:
        """Drop the metric."""


def runner_cfg(cfg: TrainConfig) -> dict:
    """The ``train_cfg`` dict of rsl-rl's OnPolicyRunner for ``cfg``."""
    t, p = cfg.train, cfg.policy
    mlp = {"class_name": "MLPModel", "hidden_dims": list(p.hidden_dims), "activation": p.activation,
           "obs_normalization": p.obs_normalization}
    if t.logger == "tensorboard":
        logger = "tensorboard"
    elif t.logger == "wandb":
        logger = {"class_name": "WandbLogWriter", "project_name": t.wandb_project}
    else:
        logger = {"class_name": NullLogWriter}
    return {
        "num_steps_per_env": t.num_steps_per_env,
        "save_interval": t.save_interval,
        "obs_groups": {"actor": ["policy"], "critic": ["policy"]},
        "algorithm": {"class_name": "PPO", **dataclasses.asdict(cfg.ppo)},
        "actor": {**mlp, "distribution_cfg": {"class_name": "GaussianDistribution", "init_std": p.init_noise_std}},
        "critic": mlp,
        "logger": logger,
        "run_name": t.run_name,
    }


class CheckpointRunner(OnPolicyRunner):
    """OnPolicyRunner whose checkpoints are written atomically and carry the training progress (``infos``),
    whose ``load`` names the file on failure and resumes at the iteration after the checkpoint's, and which calls
    ``on_iteration(it)`` after rsl-rl logs each iteration (``quiet`` hides rsl-rl's console block)."""

    def __init__(self, env: RslRlVecEnv, train_cfg: dict, log_dir: str | None, device: str,
                 on_iteration=None, quiet: bool = False):
        with contextlib.redirect_stdout(io.StringIO()):
            super().__init__(env, train_cfg, log_dir, device)
        self.progress: dict = {}
        rsl_rl_log = self.logger.log

        def log(**kwargs):
            with contextlib.redirect_stdout(io.StringIO()) if quiet else contextlib.nullcontext():
                rsl_rl_log(**kwargs)
            if on_iteration is not None:
                on_iteration(kwargs["it"])

        self.logger.log = log

    def save(self, path: str, infos: dict | None = None) -> None:
        """Write the models, optimizer, iteration and progress to ``path`` atomically."""
        saved = self.alg.save()
        saved["iter"] = self.current_learning_iteration
        saved["infos"] = infos if infos is not None else self.progress
        atomic_write(Path(path), lambda tmp: torch.save(saved, tmp))
        self.logger.save_model(path, self.current_learning_iteration)

    def load(self, path: str, load_cfg: dict | None = None, strict: bool = True, map_location: str | None = None) -> dict:
        """Load a checkpoint (RunError naming the file if it is unreadable or does not fit); return its infos."""
        try:
            loaded = torch.load(path, weights_only=False, map_location=map_location or self.device)
        except Exception as err:  # torch.load raises many types for truncated or foreign files
            raise RunError(f"cannot read checkpoint {path}: {type(err).__name__}: {err}") from None
        if not isinstance(loaded, dict) or "actor_state_dict" not in loaded or "iter" not in loaded:
            raise RunError(f"{path} is not an rsl-rl checkpoint (no actor_state_dict / iter)")
        try:
            self.alg.load(loaded, load_cfg, strict)
        except (RuntimeError, KeyError, ValueError) as err:
            raise RunError(f"checkpoint {path} does not match the configured policy/PPO "
                           f"(e.g. policy.hidden_dims): {str(err).splitlines()[0]}") from None
        if load_cfg is None or load_cfg.get("iteration"):
            self.current_learning_iteration = loaded["iter"] + 1
        self.progress = loaded.get("infos") or {}
        return self.progress

    def policy(self) -> Policy:
        """The deterministic policy as ``policy(obs (N, 4)) -> actions (N, 1)``."""
        actor = self.get_inference_policy(self.device)

        def act(obs: torch.Tensor) -> torch.Tensor:
            return actor(TensorDict({"policy": obs}, batch_size=[obs.shape[0]]))

        return act

    def export(self, out_dir: Path) -> list[Path]:
        """Write the deterministic policy as ``policy.onnx`` (one self-contained file; input 'obs' (N, 4), output
        'actions' (N, 1)) and TorchScript ``policy.pt`` into ``out_dir``."""
        out_dir = Path(out_dir)
        captured = io.StringIO()
        onnx_logger = logging.getLogger("torch.onnx")
        level = onnx_logger.level
        onnx_logger.setLevel(logging.ERROR)
        try:
            with contextlib.redirect_stdout(captured), contextlib.redirect_stderr(captured), warnings.catch_warnings():
                warnings.simplefilter("ignore")
                with tempfile.TemporaryDirectory() as scratch:
                    self.export_policy_to_onnx(scratch, "policy.onnx")
                    model = onnx.load(os.path.join(scratch, "policy.onnx"))
                atomic_write(out_dir / "policy.onnx", lambda tmp: onnx.save_model(model, tmp))
                atomic_write(out_dir / "policy.pt", lambda tmp: self.export_policy_to_jit(str(Path(tmp).parent),
                                                                                            Path(tmp).name))
        except Exception as err:
            raise RuntimeError(f"policy export failed: {err}\n{captured.getvalue()}") from err
        finally:
            onnx_logger.setLevel(level)
        return [out_dir / "policy.onnx", out_dir / "policy.pt"]


class _StopTraining(Exception):
    """Raised from the per-iteration hook to leave ``runner.learn`` after a complete iteration."""


def _format_duration(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 60}m{seconds % 60:02d}s" if seconds >= 60 else f"{seconds}s"


class RslRlTrainer:
    """One training run in ``run_dir``: env + OnPolicyRunner, per-iteration progress and the closing artefacts."""

    def __init__(self, cfg: TrainConfig, run_dir: Path, resume_from: Path | None = None):
        self.cfg = cfg.validate()
        if cfg.train.logger == "wandb" and importlib.util.find_spec("wandb") is None:
            raise ConfigError("--logger wandb needs the wandb package: pip install wandb (and wandb login)")
        self.run_dir = Path(run_dir)
        start = time.perf_counter()
        self.env = RslRlVecEnv(CartpoleEnv(cfg.env))
        self.runner = CheckpointRunner(self.env, runner_cfg(cfg), str(self.run_dir), self.env.device,
                                       on_iteration=self._on_iteration, quiet=cfg.train.console == "compact")
        self.runner.logger.git_status_repos = [__file__]
        self.setup_time_s = time.perf_counter() - start
        self.progress = {"iterations": 0, "env_steps": 0, "train_time_s": 0.0, "solved": None, "history": []}
        if resume_from is not None:
            self.progress.update(self.runner.load(str(resume_from)))
        self.runner.progress = self.progress
        self._interrupt_requested = False
        self._stop_reason = "completed"

    @property
    def max_episode_length(self) -> int:
        """The env's time limit in env steps."""
        return self.env.max_episode_length

    def _request_stop(self, signum, frame):
        if self._interrupt_requested:
            raise KeyboardInterrupt
        self._interrupt_requested = True
        print("\nCtrl-C: stopping after this iteration and saving (press again to abort without saving)", flush=True)

    def _on_iteration(self, it: int):
        now = time.perf_counter()
        iteration_time_s = now - self._last_tick
        self._last_tick = now
        steps = self.cfg.env.num_envs * self.cfg.train.num_steps_per_env
        stats = self.env.episode_stats.pop()
        p = self.progress
        p["iterations"] = it + 1
        p["env_steps"] += steps
        p["train_time_s"] += iteration_time_s
        solved = is_solved(stats.mean_length, stats.mean_reward_per_step, self.max_episode_length)
        p["history"].append({
            "iteration": it, "env_steps": p["env_steps"], "train_time_s": round(p["train_time_s"], 3),
            "episodes": stats.episodes, "mean_return": stats.mean_return, "mean_episode_length": stats.mean_length,
            "mean_reward_per_step": stats.mean_reward_per_step, "time_limit_fraction": stats.time_limit_fraction,
            "env_steps_per_s": steps / iteration_time_s, "solved": solved,
        })
        if solved and p["solved"] is None:
            p["solved"] = {"iterations": it + 1, "env_steps": p["env_steps"], "train_time_s": round(p["train_time_s"], 3)}
        if self.cfg.train.console == "compact":
            print(self._progress_line(it, stats, steps / iteration_time_s, now), flush=True)
        if self._interrupt_requested:
            self._stop_reason = "interrupted"
            raise _StopTraining
        if solved and self.cfg.train.stop_when_solved:
            self._stop_reason = "solved"
            raise _StopTraining

    def _progress_line(self, it: int, stats, steps_per_s: float, now: float) -> str:
        done = it + 1 - self._first_iteration
        eta_s = (now - self._learn_start) / done * (self._end_iteration - it - 1)
        dt = self.cfg.env.sim.env_dt
        if stats.episodes:
            episodes = (f"reward/step {stats.mean_reward_per_step:6.3f} | ep len {stats.mean_length * dt:5.2f} s "
                        f"({stats.mean_length:5.0f}/{self.max_episode_length}) | {stats.episodes:5d} ep")
        else:
            episodes = "no episode finished this iteration".ljust(60)
        mark = " | SOLVED" if self.progress["history"][-1]["solved"] else ""
        width = len(str(self._end_iteration))
        return (f"it {it + 1:>{width}}/{self._end_iteration} | {episodes} | {steps_per_s / 1e3:6.1f}k steps/s"
                f" | ETA {_format_duration(eta_s)}{mark}")

    def train(self) -> dict:
        """Run ``train.max_iterations`` iterations (Ctrl-C stops after the current one); save the last checkpoint,
        export the policy, draw the learning curve and write ``summary.json``; return the summary."""
        self._first_iteration = self.runner.current_learning_iteration
        self._end_iteration = self._first_iteration + self.cfg.train.max_iterations
        previous = signal.signal(signal.SIGINT, self._request_stop)
        self._learn_start = self._last_tick = time.perf_counter()
        try:
            self.runner.learn(self.cfg.train.max_iterations)
        except _StopTraining:
            self.runner.save(str(self.run_dir / f"model_{self.runner.current_learning_iteration}.pt"))
        finally:
            signal.signal(signal.SIGINT, previous)
            writer = self.runner.logger.writer
            if writer is not None and hasattr(writer, "close"):
                writer.close()
        exports = self.runner.export(self.run_dir / EXPORT_DIR) if self.progress["iterations"] else []
        self.plot()
        summary = self.summary(exports)
        write_summary(self.run_dir, summary)
        return summary

    def plot(self) -> Path:
        """Draw ``learning_curve.png`` from the progress history."""
        dt = self.cfg.env.sim.env_dt
        history = [{**h, "mean_episode_length_s": h["mean_episode_length"] * dt if h["mean_episode_length"] else None}
                   for h in self.progress["history"]]
        limit_s = self.max_episode_length * dt if self.cfg.env.task.episode_length_s else None
        return plot_learning_curve(self.run_dir / CURVE_FILE, history, [
            ("mean reward per step (finished episodes; red: solved threshold)", "mean_reward_per_step",
             SOLVED_REWARD_PER_STEP),
            ("mean episode length (s) (red: solved threshold)", "mean_episode_length_s",
             SOLVED_LENGTH_FRACTION * limit_s if limit_s else None),
        ])

    def summary(self, exports: list[Path]) -> dict:
        """The run's ``summary.json`` content."""
        p = self.progress
        last = next((h for h in reversed(p["history"]) if h["episodes"]), {})
        return {
            "algo": ALGO,
            "status": self._stop_reason,
            "iterations": p["iterations"],
            "env_steps": p["env_steps"],
            "train_time_s": round(p["train_time_s"], 3),
            "setup_time_s": round(self.setup_time_s, 3),
            "env_steps_per_s": round(p["env_steps"] / p["train_time_s"]) if p["train_time_s"] else None,
            "final": {k: last.get(k) for k in ("iteration", "episodes", "mean_return", "mean_episode_length",
                                                "mean_reward_per_step", "time_limit_fraction")},
            "max_episode_length": self.max_episode_length if self.cfg.env.task.episode_length_s else None,
            "env_dt_s": self.cfg.env.sim.env_dt,
            "solved": p["solved"] is not None,
            "solved_at": p["solved"],
            "solved_definition": (f"mean episode length >= {SOLVED_LENGTH_FRACTION:.0%} of the time limit and mean "
                                  f"reward per step >= {SOLVED_REWARD_PER_STEP} over one iteration's finished episodes"),
            "num_envs": self.cfg.env.num_envs,
            "device": self.env.device,
            "checkpoint": latest_checkpoint(self.run_dir).name,
            "exports": [str(e.relative_to(self.run_dir)) for e in exports],
            "versions": versions(),
        }


def load_policy(cfg: TrainConfig, checkpoint: Path, env: CartpoleEnv) -> CheckpointRunner:
    """A runner (no logging) on ``env`` holding the checkpoint's weights: use ``.policy()`` and ``.export()``."""
    runner = CheckpointRunner(RslRlVecEnv(env), runner_cfg(cfg), None, env.device)
    runner.load(str(checkpoint), load_cfg={"actor": True})
    return runner

