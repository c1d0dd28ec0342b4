"""One training run: the env and ``TaskRunner`` built from a ``TrainConfig``, Ctrl-C handling, and the run
folder's artefacts (config, checkpoints, exports, learning curve, ``summary.json``).

    training = Training(cfg, run_dir)            # builds the env (compiles Warp kernels on first use)
    summary = training.run()                     # Ctrl-C ends after the current iteration, saved
"""

from __future__ import annotations

import dataclasses
import importlib.util
import signal
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import torch

from ..engine import camera
from ..engine.runtime import free_memory_bytes, resolve_device, timed
from ..evaluation.in_step import InStepEvaluation
from ..settings.config import ConfigError
from ..wrappers.rsl_rl import RslRlVecEnv
from .config import TrainConfig
from .distributed import SINGLE_PROCESS, Ranks
from .learners import learner_class
from .runner import TaskRunner
from .runs import CURVE_FILE, EXPORT_DIR, RunSummary, latest_checkpoint, play_checkpoint, save_config

ENV_BYTES_PER_ENV = 8_400
"""Host memory per env of a training process besides rsl-rl's storage (the env's buffers, its Newton scene, torch's
copies of each step): the growth per env of the balance's peak resident memory in a 1-iteration ``train.py`` run on
the CPU, less its storage estimate (docs/benchmarks.md, "Training memory per env"). Tasks of more bodies take more (a
floor for them)."""


def bytes_per_env(cfg: TrainConfig) -> dict[str, int]:
    """Memory a training run takes per env, by where it lies: 'host', ``ENV_BYTES_PER_ENV`` (measured), and
    'device': the camera's frames where the policy sees them (``camera.bytes_per_env``) and rsl-rl's rollout storage
    over ``num_steps_per_env`` steps (per step the observations, the critic's own where the policy sees frames, the
    actions with the Gaussian's mean and std, the reward, value, log-probability, return and advantage in float32,
    the done flag in a byte), plus one mini-batch's copy of it (twice with the mirror augmentation)."""
    env_class, camera_cfg, agent = cfg.task_spec.env_class, cfg.env.camera, cfg.agent
    obs_bytes, frames_bytes = 4 * env_class.num_obs, 0
    if camera_cfg.enabled:
        pixel_bytes = 1 if camera_cfg.image == "rgb" else 4
        obs_bytes += (camera_cfg.channels * camera_cfg.frame_stack * camera_cfg.height_px * camera_cfg.width_px
                      * pixel_bytes)
        frames_bytes = camera.bytes_per_env(camera_cfg)
    storage = agent.num_steps_per_env * (obs_bytes + 4 * 3 * env_class.num_actions + 4 * 5 + 1)
    mirrored = agent.algorithm.symmetry and env_class.obs_mirror is not None
    mini_batch = storage // agent.algorithm.num_mini_batches * (2 if mirrored else 1)
    return {"host": ENV_BYTES_PER_ENV, "device": frames_bytes + storage + mini_batch}


def bytes_per_env_by_place(cfg: TrainConfig, device: str) -> dict[str, int]:
    """``bytes_per_env`` by where it lies: all in the host's memory on the CPU, else the host's part and the GPU's."""
    per_env = bytes_per_env(cfg)
    return {"cpu": sum(per_env.values())} if device == "cpu" else {"cpu": per_env["host"], device: per_env["device"]}


def check_memory(cfg: TrainConfig, device: str):
    """ConfigError in one line, with the estimate (``bytes_per_env``), where ``cfg.env.num_envs`` envs (and the
    evaluation's inside the step, ``eval.in_step``, counted as training envs) would not fit in the free memory of the
    host or of ``device``, before anything is allocated."""
    evaluation_envs = cfg.eval.num_envs if cfg.eval.in_step else 0
    for where, need_per_env in bytes_per_env_by_place(cfg, device).items():
        need, free = (cfg.env.num_envs + evaluation_envs) * need_per_env, free_memory_bytes(where)
        if need > free:
            steps = cfg.agent.num_steps_per_env
            frames = ", the camera's frames" if cfg.env.camera.enabled else ""
            raise ConfigError(
                f"training {cfg.env.num_envs:,} envs of {cfg.task} needs about {need / 1e9:,.1f} GB on {where} "
                f"({need_per_env / 1e3:,.1f} kB per env: the scene{frames} and rsl-rl's storage of {steps} steps "
                f"per env); {where} has {free / 1e9:,.1f} GB free: use at most "
                f"~{free // need_per_env - evaluation_envs:,} envs (--num-envs) or fewer --agent.num-steps-per-env")


class Interrupts:
    """SIGINT and SIGTERM (which torchrun sends its processes) while a training runs, as a context: the first calls
    ``stop`` (training ends after the iteration in progress, which is saved) and ``say``s so; a second
    aborts (KeyboardInterrupt, nothing saved); once ``finishing`` (training has ended, the run's files are being
    written) a signal waits for them, saying so."""

    def __init__(self, stop: Callable[[], None], say: Callable[[str], None], stopping: str):
        self.stop, self.say, self.stopping = stop, say, stopping
        self.count, self.finishing = 0, False
        self._previous: dict = {}

    def __enter__(self) -> Interrupts:
        self._previous = {sig: signal.signal(sig, self._on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
        return self

    def __exit__(self, *exc):
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def _on_signal(self, signum, frame):
        if self.finishing:  # the run's files are being written: they come first, and quickly
            self.say("writing the run's exports, curve and summary first")
            return
        self.count += 1
        if self.count > 1:
            raise KeyboardInterrupt
        self.stop()
        self.say(f"{self.stopping} after this iteration and saving (Ctrl-C again aborts without saving)")


def median_of(history: list[dict], key: str) -> float | None:
    """Median of ``key`` over the iterations that recorded it, rounded to microseconds (None if none did)."""
    values = [h[key] for h in history if key in h]
    return round(statistics.median(values), 3) if values else None


def solved_definition(cfg: TrainConfig) -> str:
    """The task's solved rule and what it judges, in words."""
    return (f"{cfg.task_spec.solved.describe()}, over the deterministic policy's whole episodes in "
            f"{cfg.eval.num_envs} evaluation envs (play.py --headless's)")


def finish_run(runner: TaskRunner, run_dir: Path, timing_s: dict[str, float], setup_time_s: float,
               trained_before_s: float = 0.0, processes: int = 1) -> RunSummary:
    """The end of ``runner``'s run in ``run_dir``: the exports of the policy play.py plays (``model_best.pt``'s where
    an evaluation ran, else the last), the learning curve, ``summary.json`` (returned). ``timing_s`` gains the
    training's seconds in this process (less ``trained_before_s``: a resumed run's earlier processes') and the
    exports' and the curve's."""
    cfg, progress = runner.train_cfg, runner.progress
    timing_s["training"] = progress.train_time_s - trained_before_s
    with timed(timing_s, "export"):
        exports = []
        if progress.iterations:  # play's policy: a policy can get worse after its best evaluation
            runner.load(str(play_checkpoint(run_dir)), load_cfg={"actor": True})
            exports = runner.export(run_dir / EXPORT_DIR)
    with timed(timing_s, "curve"):
        plot(runner, run_dir)
    last = next((h for h in reversed(progress.history) if h["episodes"]), {})
    evaluated = next((h for h in reversed(progress.history) if "evaluation" in h), None)
    summary = RunSummary(
        status=runner.stop_reason or "completed", iterations=progress.iterations, env_steps=progress.env_steps,
        train_time_s=round(progress.train_time_s, 3),
        setup_time_s=round(setup_time_s, 3),
        env_steps_per_s=round(progress.env_steps / progress.train_time_s) if progress.train_time_s else None,
        collection_ms=median_of(progress.history, "collection_ms"),
        learning_ms=median_of(progress.history, "learning_ms"),
        final={k: last.get(k) for k in ("iteration", "episodes", "mean_return", "mean_episode_length",
                                        "mean_reward_per_step", "time_limit_fraction", "full_episodes",
                                        "full_reward_per_step")},
        evaluation=({"iteration": evaluated["iteration"], **evaluated["evaluation"]} if evaluated else None),
        evaluations=sum("evaluation" in h for h in progress.history),
        evaluation_s=round(sum(h["evaluation"]["seconds"] for h in progress.history if "evaluation" in h), 3),
        best=progress.best,
        max_episode_length=runner.env.max_episode_length if cfg.env.task.has_time_limit else None,
        env_dt_s=cfg.env.sim.env_dt,
        solved=progress.solved_at is not None, solved_at=progress.solved_at,
        solved_definition=solved_definition(cfg),
        task=cfg.task,
        num_envs=cfg.env.num_envs * processes,
        processes=processes,
        device=runner.env.device,
        checkpoint=latest_checkpoint(run_dir).name,
        exports=[str(e.relative_to(run_dir)) for e in exports],
        timing_s={phase: round(seconds, 3) for phase, seconds in timing_s.items()},
    )
    summary.write(run_dir)
    return summary


def plot(runner: TaskRunner, run_dir: Path) -> Path:
    """Draw ``learning_curve.png`` from ``runner``'s progress history (matplotlib imported only now, so that start-up
    does not pay for it)."""
    from .curve import plot_learning_curve

    task = runner.train_cfg.task_spec
    return plot_learning_curve(run_dir / CURVE_FILE, runner.progress.history, task, f"{task.name}: run {run_dir.name}")


class Training:
    """A run in ``run_dir`` (created, with its ``config.yaml``, only once the env is built and a checkpoint to resume
    from is loaded). In a torchrun job (``ranks``) each process trains its own envs on its own GPU with seed + rank,
    and rank 0 alone writes the run folder."""

    def __init__(self, cfg: TrainConfig, run_dir: Path, resume_from: Path | None = None,
                 ranks: Ranks = SINGLE_PROCESS, timing_s: dict[str, float] | None = None):
        self.cfg = cfg.validate()
        if cfg.agent.logger == "wandb" and importlib.util.find_spec("wandb") is None:
            raise ConfigError("--logger wandb needs the wandb package: pip install wandb (and wandb login)")
        self.run_dir, self.ranks = Path(run_dir), ranks
        start = time.perf_counter()
        env_cfg = learner_class(cfg.agent.learner).env_config(cfg, ranks.env_config(cfg.env, torch.cuda.device_count()),
                                                              ranks)
        check_memory(dataclasses.replace(cfg, env=env_cfg), resolve_device(env_cfg.device))
        torch.manual_seed(env_cfg.seed)
        cfg.apply_torch_threads()
        self.task = cfg.task_spec
        in_step = cfg.eval.in_step and ranks.writes  # the process that writes the run evaluates
        extra = cfg.eval.num_envs if in_step else 0
        batched = self.task.env_class(dataclasses.replace(env_cfg, num_envs=env_cfg.num_envs + extra))
        self.env = RslRlVecEnv(batched, InStepEvaluation(batched, extra, cfg.env.seed) if in_step else None)
        self.timing_s = (timing_s if timing_s is not None else {}) | batched.build_time_s
        """Where the run's seconds went, by phase (after those of ``timing_s``, e.g. train.py's); summary.json keeps
        them."""
        self.eval_env = None
        """The evaluation's envs where they are an env of their own (``TaskRunner``)."""
        if ranks.writes and not in_step:
            with timed(self.timing_s, "eval_env"):
                self.eval_env = self.task.env_class(dataclasses.replace(env_cfg, num_envs=cfg.eval.num_envs,
                                                                        seed=cfg.env.seed))
        with timed(self.timing_s, "networks"):
            self.runner = TaskRunner(self.env, dataclasses.replace(cfg, env=env_cfg),
                                     self.run_dir if ranks.writes else None, self.eval_env, ranks=ranks)
        with timed(self.timing_s, "eval_env"):
            self.runner.evaluations.prepare()
            if resume_from is not None:
                self.runner.load(str(resume_from))
            if ranks.writes:
                save_config(self.run_dir, cfg)
        self.setup_time_s = time.perf_counter() - start

    @property
    def solved_definition(self) -> str:
        """The task's solved rule and what it judges, in words."""
        return solved_definition(self.cfg)

    @property
    def max_episode_length(self) -> int:
        """The env's time limit in env steps."""
        return self.env.max_episode_length

    def run(self) -> RunSummary | None:
        """Train ``agent.max_iterations`` iterations (fewer on Ctrl-C or SIGTERM, which torchrun sends its processes,
        or, with stop_when_solved, once solved); then export the policy play.py plays (``model_best.pt``'s where an
        evaluation ran, else the last), draw the learning curve and write ``summary.json``, and return it (None in
        the processes that do not write). A signal once training has ended waits until summary.json is written."""
        def say(line: str):  # on a line of its own, after the terminal's ^C
            if self.ranks.writes:
                print(f"\n{line}", flush=True)

        with Interrupts(lambda: self.runner.request_stop("interrupted"), say, "stopping") as interrupts:
            trained_before_s = self.runner.progress.train_time_s  # a resumed run's earlier processes
            try:
                self.runner.learn(self.cfg.agent.max_iterations, self.cfg.agent.init_at_random_ep_len)
            finally:
                interrupts.finishing = True
                self.runner.release_graphs()
            return self._finish(trained_before_s) if self.ranks.writes else None

    def _finish(self, trained_before_s: float) -> RunSummary:
        """The end of a run: exports, the learning curve, ``summary.json``."""
        return finish_run(self.runner, self.run_dir, self.timing_s, self.setup_time_s, trained_before_s,
                          self.ranks.world_size)
