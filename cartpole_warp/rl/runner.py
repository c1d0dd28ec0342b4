"""``TaskRunner``: the training loop of one run over a learner (``rl.learners``), for any task.

    runner = TaskRunner(RslRlVecEnv(cfg.task_spec.env_class(cfg.env)), cfg, log_dir)
    runner.learn(cfg.agent.max_iterations)     # runner.request_stop() ends it after the current iteration

After each of the learner's iterations (act, step, learn): episode statistics, progress, the evaluations' verdict
(``rl.evaluations``), metrics and console line (``rl.progress.Report``), stop requests, checkpoints (rsl-rl's).
"""

from __future__ import annotations

from ..wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
import contextlib
import io
import time
from collections.abc import Callable
from pathlib import Path

import torch
from tensordict import TensorDict

from ..engine.env import BatchedEnv
from ..evaluation.rollouts import Policy
from ..evaluation.statistics import EpisodeStats, EpisodeSummary
from ..settings.deprecation import moved_names, renamed
from ..settings.files import atomic_write
from ..wrappers.rsl_rl import RslRlVecEnv
from .config import TrainConfig
from .distributed import Ranks, join_process_group, joint_stop
from .evaluations import Evaluations
from .learners import Learner, learner_class
from .policies import deterministic, export_policy, networks_must_fit, read_checkpoint, to_rsl_rl
from .progress import Pace, Report, history_entry, run_eta_s
from .runs import Progress


class TaskRunner:
    """The loop of one training run of ``cfg`` on ``env`` by ``learner`` (default: ``cfg.agent.learner``'s, built here);
    ``log_dir`` None writes nothing (no metrics, no checkpoints). Evaluations (``Evaluations``) run on ``eval_env`` or,
    where ``env`` carries an ``InStepEvaluation`` (``eval.in_step``), inside the training's step. ``ranks``: the
    processes the run spans (default: torchrun's). ``cfg`` is rsl-rl's ``train_cfg`` dict."""

    def __init__(self, env: RslRlVecEnv, cfg: TrainConfig, log_dir: Path | None, eval_env: BatchedEnv | None = None,
                 learner: Learner | None = None, ranks: Ranks | None = None):
        self.env, self.train_cfg, self.device = env, cfg, env.device
        self.ranks = ranks if ranks is not None else Ranks.from_environment()
        self.cfg = to_rsl_rl(cfg.agent, mirror=env.obs_mirror is not None, images=env.images)
        if learner is None:
            self.cfg["multi_gpu"] = join_process_group(self.ranks, self.device)
            learner = learner_class(cfg.agent.learner)(env, cfg, self.cfg,
                                                       EpisodeStats(env.device, env.max_episode_length))
        self.learner, self.episodes = learner, learner.episodes
        self.in_step = env.evaluation  # the evaluation inside the training's step (None: on eval_env, if any)
        self.evaluations = Evaluations(cfg, self.learner, eval_env, self.in_step)
        self.report = Report(cfg, learner, self.cfg, log_dir, self.ranks)
        self.logger = self.report.logger  # rsl-rl's, with the metrics writer
        if cfg.console == "rsl_rl":
            self.learner.on_step = self.logger.process_env_step
        self.current_learning_iteration, self.progress = 0, Progress()
        self.stop_reason = self._stop_requested = None  # str | None: why learn stops, and a stop request's reason
        self.on_iteration: Callable[[int, EpisodeSummary], None] | None = None
        """Called after each iteration's console line (rank 0) with the iteration and its episodes' summary (the
        browser viewer's hook)."""

    @property
    def alg(self):
        """rsl-rl's algorithm object of the PPO learner (AttributeError for a learner without one)."""
        return self.learner.alg

    @property
    def run_dir(self) -> Path | None:
        return Path(self.logger.log_dir) if self.logger.log_dir is not None else None

    @property
    def stop_requested(self) -> str | None:
        """The reason of a pending ``request_stop`` (None: none)."""
        return self._stop_requested

    def request_stop(self, reason: str = "interrupted"):
        """End ``learn`` after the iteration in progress (which is saved); in a torchrun job every process stops
        after that same iteration."""
        self._stop_requested = reason

    def learn(self, num_learning_iterations: int, init_at_random_ep_len: bool = False) -> None:
        """``num_learning_iterations`` iterations, ending early on a stop request or, with ``stop_when_solved``, once
        solved. Non-finite states never reach the learner (the env resets them), so there is no per-step NaN check;
        episode statistics stay on the device until the iteration ends."""
        obs = self.start(num_learning_iterations, init_at_random_ep_len)
        for it in range(self._first_iteration, self._end_iteration):
            obs, losses = self.learner.iteration(obs, it)
            if self.after_iteration(it, losses):
                break
        self.finish()

    def start(self, num_learning_iterations: int, init_at_random_ep_len: bool = False) -> TensorDict:
        """``learn``'s start (a loop that drives the learner itself calls it, ``after_iteration`` and ``finish``): the
        env's observations out."""
        if init_at_random_ep_len:
            self.env.episode_length_buf = torch.randint_like(self.env.episode_length_buf,
                                                             high=int(self.env.max_episode_length))
        self.report.line.staggered_starts = init_at_random_ep_len and self.train_cfg.env.task.has_time_limit
        self._first_iteration = self.current_learning_iteration
        self._end_iteration = self._first_iteration + num_learning_iterations
        self.learner.begin(self._first_iteration, self._end_iteration)
        with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl says where it stores the code's git state
            self.logger.init_logging_writer()
        self.evaluations.last_iteration = self._first_iteration - 1
        self._start = self._tick = time.perf_counter()
        return self.env.get_observations().to(self.device)

    def after_iteration(self, it: int, losses: dict) -> bool:
        """The runner's part of iteration ``it`` (whose ``losses`` the learner gave); whether training stops."""
        self.current_learning_iteration = it
        self._end_of_iteration(it, losses)
        if self.stop_reason is None and self.run_dir is not None and it % self.cfg["save_interval"] == 0:
            self.save(str(self.run_dir / f"model_{it}.pt"))
        return self.stop_reason is not None

    def finish(self):
        """The last checkpoint; the metrics writer closed."""
        if self.run_dir is not None:
            self.save(str(self.run_dir / f"model_{self.current_learning_iteration}.pt"))
            self.logger.stop_logging_writer()

    def _end_of_iteration(self, it: int, losses: dict):
        """After iteration ``it``: statistics, progress, the evaluations' verdict, the report, the stop decision."""
        stats = self.episodes.pop(all_processes=self.ranks.distributed)
        now = time.perf_counter()
        steps = self.env.num_envs * self.cfg["num_steps_per_env"] * self.ranks.world_size
        pace = Pace(steps / (now - self._tick), *self.learner.clock.seconds())
        p = self.progress
        p.iterations, p.env_steps = it + 1, p.env_steps + steps
        judged = self.evaluations.judge(it, stats, p.env_steps)
        solved = judged is not None and self.evaluations.rule(judged.summary)
        done = time.perf_counter()
        p.train_time_s += done - self._tick
        p.history.append(history_entry(p, it, stats, pace, judged, done - now, solved))
        self._tick = done
        if judged is not None:
            self.evaluations.record(judged, solved, p, self.run_dir, self._write)
        self.report((self._first_iteration, it, self._end_iteration), stats, losses, self.learner.learning_rate,
                    self.learner.action_std, pace, judged and (judged.summary, judged.iteration, solved),
                    run_eta_s(p, self._start, (self._first_iteration, it, self._end_iteration), self.evaluations)
                    if self.report.console else 0.0)
        if self.on_iteration is not None and self.ranks.writes:
            self.on_iteration(it, stats)
        wanted = self._stop_requested or ("solved" if solved and self.train_cfg.stop_when_solved else None)
        self.stop_reason = joint_stop(wanted, self.device, self.ranks.distributed)

    def release_graphs(self):
        """Free the learner's captured graphs (before the process group is destroyed); ``learn`` captures again."""
        self.learner.release_graphs()

    def save(self, path: str, infos: dict | None = None) -> None:
        """Write the learner's state, the iteration and the progress to ``path`` atomically."""
        self._write(Path(path), self.learner.state_dict(), self.current_learning_iteration,
                    infos if infos is not None else self.progress.infos())

    def _write(self, path: Path, state: dict, iteration: int, infos: dict):
        """``save`` of ``state`` (``Learner.state_dict``'s) as the checkpoint of ``iteration``."""
        saved = dict(state, iter=iteration, infos=infos)
        atomic_write(path, lambda tmp: torch.save(saved, tmp))
        self.logger.save_model(str(path), iteration)

    def load(self, path: str, load_cfg: dict | None = None, strict: bool = True,
             map_location: str | None = None) -> dict:
        """Load a checkpoint (RunError naming the file if it is unreadable or does not fit); return its progress.
        Where ``load_cfg`` loads the iteration (the default: resuming) training continues after it with the
        checkpoint's progress; otherwise (e.g. ``{"actor": True}``: the best policy, to export) the run's own progress
        stays."""
        loaded = read_checkpoint(path, map_location or self.device)
        with networks_must_fit(path):
            self.learner.load_state_dict(loaded, load_cfg, strict)
        infos = loaded.get("infos") or {}
        if load_cfg is None or load_cfg.get("iteration"):
            self.current_learning_iteration = loaded["iter"] + 1
            self.progress = Progress.from_infos(infos)
        return infos

    def policy(self) -> Policy:
        """The deterministic policy (the Gaussian's mean); the learner in eval mode."""
        self.learner.eval_mode()
        return deterministic(self.learner.actor)

    def export(self, out_dir: Path) -> list[Path]:
        """The actor's exports in ``out_dir`` (``policies.export_policy``)."""
        return export_policy(self.learner.actor, out_dir)


_renamed = renamed(__name__, {"CartpoleRunner": "TaskRunner"})
_moved = moved_names(__name__, f"{__package__}.policies")


def __getattr__(name: str) -> object:
    """The old names (``CartpoleRunner``) and the policy functions that lived here (``load_policy``, ``to_rsl_rl``,
    ...: now in ``rl.policies``), until ``settings.deprecation.REMOVED_IN``."""
    return _renamed(name) if name == "CartpoleRunner" else _moved(name)
