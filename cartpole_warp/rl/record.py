"""One run's books in a training (``RunRecord``: member k of a learner, the only one of a solo run): its progress,
its evaluations' verdicts and best checkpoint, its metrics and console line (``rl.progress.Report``), its checkpoints
(rsl-rl's format), and its run folder's end: exports, learning curve, ``summary.json`` (``summarize``).
"""

from __future__ import annotations

from ..wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
import contextlib
import io
import statistics
from pathlib import Path

import torch

from ..engine.runtime import timed
from ..evaluation.rollouts import Policy
from ..evaluation.statistics import EpisodeSummary
from ..settings.files import atomic_write
from ..wrappers.rsl_rl import RslRlVecEnv
from .config import TrainConfig
from .distributed import Ranks, joint_stop
from .evaluations import Evaluations, Judged
from .learners import Learner
from .policies import deterministic, export_policy, networks_must_fit, read_checkpoint
from .progress import Pace, Report, history_entry, run_eta_s
from .runs import BEST_CHECKPOINT, CURVE_FILE, EXPORT_DIR, Progress, RunSummary, latest_checkpoint, play_checkpoint


def median_of(history: list[dict], key: str) -> float | None:
    """Median of ``key`` over the iterations that recorded it, rounded to microseconds (None if none did)."""
    values = [h[key] for h in history if key in h]
    return round(statistics.median(values), 3) if values else None


def solved_definition(cfg: TrainConfig) -> str:
    """The task's solved rule and what it judges, in words."""
    return (f"{cfg.task_spec.solved.describe()}, over the deterministic policy's whole episodes in "
            f"{cfg.eval.num_envs} evaluation envs (play.py --headless's)")


class RunRecord:
    """The books of ``member``'s run of ``config`` (its seed and settings) in a training by ``learner`` on ``env``:
    ``log_dir`` None writes nothing (no metrics, no checkpoints); ``ranks``: the processes the run spans (a
    population's member: its own process's alone); ``evaluations``: the training's (their schedule foretells the
    run's end). ``rsl_rl_cfg`` is rsl-rl's ``train_cfg`` dict of it."""

    def __init__(self, config: TrainConfig, learner: Learner, member: int, env: RslRlVecEnv, log_dir: Path | None,
                 rsl_rl_cfg: dict, ranks: Ranks, evaluations: Evaluations):
        self.config, self.learner, self.member, self.ranks = config, learner, member, ranks
        self.device, self.evaluations, self.save_interval = env.device, evaluations, rsl_rl_cfg["save_interval"]
        self.report = Report(config, learner, member, env, rsl_rl_cfg, log_dir, ranks)
        self.logger = self.report.logger  # rsl-rl's, with the metrics writer
        self.progress, self.next_iteration = Progress(), 0
        self.stop_reason: str | None = None
        """Why its training ended (None: it goes on)."""
        self._span = (0, 0)

    @property
    def run_dir(self) -> Path | None:
        return Path(self.logger.log_dir) if self.logger.log_dir is not None else None

    def start(self, first_iteration: int, end_iteration: int, staggered_starts: bool):
        """The metrics writer opened for iterations ``first_iteration`` to ``end_iteration`` (exclusive)."""
        self._span = (first_iteration, end_iteration)
        self.report.line.staggered_starts = staggered_starts and self.config.env.task.has_time_limit
        with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl says where it stores the code's git state
            self.logger.init_logging_writer()

    def count(self, it: int, env_steps: int) -> int:
        """Iteration ``it`` done, of ``env_steps`` env steps: the run's env steps so far."""
        self.progress.iterations = it + 1
        self.progress.env_steps += env_steps
        return self.progress.env_steps

    def after_iteration(self, it: int, stats: EpisodeSummary, losses: dict, learning_rate: float, action_std,
                        pace: Pace, judged: Judged | None, timing: tuple[float, float, float],
                        wanted: str | None):
        """Iteration ``it``'s books (after ``count``): its training episodes' ``stats`` and the learner's figures,
        ``judged`` (a verdict for this run, or None), ``timing``: the iteration's wall seconds, its evaluation's, and
        the training's start (``perf_counter``); ``wanted``: a stop asked for (None: none). The history, the verdict
        (the best checkpoint), the report, the stop decision (``stop_reason``), a checkpoint every ``save_interval``."""
        first, end = self._span
        iteration_s, evaluation_s, start_s = timing
        p = self.progress
        p.train_time_s += iteration_s
        solved = judged is not None and self.config.task_spec.solved(judged.summary)
        p.history.append(history_entry(p, it, stats, pace, judged, evaluation_s, solved))
        if judged is not None:
            self._record(judged, solved)
        eta = (run_eta_s(p, start_s, (first, it, end), self.evaluations, self.member) if self.report.console
               else 0.0)
        self.report((first, it, end), stats, losses, learning_rate, action_std, pace,
                    judged and (judged.summary, judged.iteration, solved), eta)
        wanted = wanted or ("solved" if solved and self.config.stop_when_solved else None)
        self.stop_reason = joint_stop(wanted, self.device, self.ranks.distributed)
        self.next_iteration = it + 1
        if self.stop_reason is None and self.run_dir is not None and it % self.save_interval == 0:
            self.save(self.run_dir / f"model_{it}.pt")

    def _record(self, judged: Judged, solved: bool):
        """Enter a verdict: the first solved one as ``solved_at`` (the judged policy's iterations and env steps, the
        training seconds until the verdict); the best so far (solved first, then the play metric) as ``best``, its
        policy written as ``model_best.pt`` with the progress as it stood after its iteration, so that a resume from
        it continues there."""
        progress, metric = self.progress, self.config.task_spec.play_metric
        if solved and progress.solved_at is None:
            progress.solved_at = {"iterations": judged.iteration + 1, "env_steps": judged.env_steps,
                                  "train_time_s": round(progress.train_time_s, 3),
                                  metric: getattr(judged.summary, metric)}
        score = (solved, getattr(judged.summary, metric) or 0.0)
        best = progress.best
        if best is not None and score <= (best["solved"], best[metric] or 0.0):
            return
        progress.best = {"iteration": judged.iteration, "solved": solved, metric: score[1]}
        if self.run_dir is not None:
            state = judged.state if judged.state is not None else self.learner.state_dict(self.member)
            infos = progress.as_of(judged.iteration) if judged.state is not None else progress.infos()
            self._write(self.run_dir / BEST_CHECKPOINT, state, judged.iteration, infos)

    def stop_nonfinite(self, it: int):
        """The run stops: its networks went non-finite in iteration ``it``, which counts in none of its books; its
        state is that iteration's (the last checkpoint, ``model_<it>.pt``, holds it: no earlier one is overwritten)."""
        self.stop_reason, self.next_iteration = "non-finite", it + 1

    @property
    def state_iteration(self) -> int:
        """The iteration of the learner's state of the run: the last one done (0 before any)."""
        return max(self.next_iteration - 1, 0)

    def finish(self):
        """The last checkpoint; the metrics writer closed."""
        if self.run_dir is not None:
            self.save(self.run_dir / f"model_{self.state_iteration}.pt")
            self.logger.stop_logging_writer()

    def save(self, path: Path | str, infos: dict | None = None):
        """Write the run's state (``Learner.state_dict``'s), its last iteration and its progress to ``path``
        atomically."""
        self._write(Path(path), self.learner.state_dict(self.member), self.state_iteration,
                    infos if infos is not None else self.progress.infos())

    def _write(self, path: Path, state: dict, iteration: int, infos: dict):
        """A checkpoint of ``state`` as iteration ``iteration``'s."""
        saved = dict(state, iter=iteration, infos=infos)
        atomic_write(path, lambda tmp: torch.save(saved, tmp))
        self.logger.save_model(str(path), iteration)

    def load(self, path: Path | str, load_cfg: dict | None = None, strict: bool = True,
             map_location: str | None = None) -> dict:
        """Load a checkpoint (RunError naming the file if it is unreadable or does not fit); return its progress.
        Where ``load_cfg`` loads the iteration (the default: resuming) training continues after it with the
        checkpoint's progress; otherwise (e.g. ``{"actor": True}``: the best policy, to export) the run's own progress
        stays."""
        loaded = read_checkpoint(str(path), map_location or self.device)
        with networks_must_fit(str(path)):
            self.learner.load_state_dict(loaded, load_cfg, strict, self.member)
        infos = loaded.get("infos") or {}
        if load_cfg is None or load_cfg.get("iteration"):
            self.next_iteration = loaded["iter"] + 1
            self.progress = Progress.from_infos(infos)
        return infos

    def policy(self) -> Policy:
        """The deterministic policy (the Gaussian's mean); the learner in eval mode."""
        return deterministic(self.learner.member_actor(self.member))

    def export(self, out_dir: Path) -> list[Path]:
        """The actor's exports in ``out_dir`` (``policies.export_policy``)."""
        exports = export_policy(self.learner.member_actor(self.member), out_dir)
        self.learner.train_mode()
        return exports

    def summarize(self, timing_s: dict[str, float], setup_time_s: float, trained_before_s: float = 0.0,
                  processes: int = 1) -> RunSummary:
        """The end of the run in its folder: the exports of the policy play.py plays (``model_best.pt``'s where an
        evaluation ran, else the last), the learning curve, ``summary.json`` (returned). ``timing_s`` gains the
        training's seconds in this process (less ``trained_before_s``: a resumed run's earlier processes') and the
        exports' and the curve's."""
        cfg, progress, run_dir = self.config, self.progress, self.run_dir
        timing_s["training"] = progress.train_time_s - trained_before_s
        with timed(timing_s, "export"):
            exports = []
            if progress.iterations:  # play's policy: a policy can get worse after its best evaluation
                self.load(play_checkpoint(run_dir), load_cfg={"actor": True})
                exports = self.export(run_dir / EXPORT_DIR)
        with timed(timing_s, "curve"):
            self.plot()
        last = next((h for h in reversed(progress.history) if h["episodes"]), {})
        evaluated = next((h for h in reversed(progress.history) if "evaluation" in h), None)
        summary = RunSummary(
            status=self.stop_reason or "completed", iterations=progress.iterations, env_steps=progress.env_steps,
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
            max_episode_length=self.report.line.max_episode_length if cfg.env.task.has_time_limit else None,
            env_dt_s=cfg.env.sim.env_dt,
            solved=progress.solved_at is not None, solved_at=progress.solved_at,
            solved_definition=solved_definition(cfg),
            task=cfg.task,
            num_envs=cfg.env.num_envs * processes,
            processes=processes,
            device=self.device,
            checkpoint=latest_checkpoint(run_dir).name,
            exports=[str(e.relative_to(run_dir)) for e in exports],
            timing_s={phase: round(seconds, 3) for phase, seconds in timing_s.items()},
        )
        summary.write(run_dir)
        return summary

    def plot(self) -> Path:
        """Draw ``learning_curve.png`` from the progress history (matplotlib imported only now, so that start-up
        does not pay for it)."""
        from .curve import plot_learning_curve

        task = self.config.task_spec
        return plot_learning_curve(self.run_dir / CURVE_FILE, self.progress.history, task,
                                   f"{task.name}: run {self.run_dir.name}")
