"""What a training run reports after each iteration: its console line (``ProgressLine``), its metrics
(``metrics``: tensorboard's or wandb's scalars) and the time it has left (``eta_s``)."""

from __future__ import annotations

from ..evaluation.statistics import EpisodeSummary
from ..wrappers.rsl_rl import RslRlVecEnv
from .config import TrainConfig

LONG_RUN_S = 3600.0
"""A run whose first iteration foretells more than this says so, with what makes it shorter."""


def format_duration(seconds: float) -> str:
    seconds = int(round(seconds))
    if seconds >= 3600:
        return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"
    return f"{seconds // 60}m{seconds % 60:02d}s" if seconds >= 60 else f"{seconds}s"


def eta_s(elapsed_s: float, evaluation_s: list[float], iterations_done: int, iterations_left: int,
          evaluations_left: int) -> float:
    """Seconds to a run's end: the iterations left at the mean pace of those done (their evaluations taken out), and
    the evaluations still due at the mean of those measured so far (none counted before the first has run)."""
    per_iteration_s = (elapsed_s - sum(evaluation_s)) / iterations_done
    per_evaluation_s = sum(evaluation_s) / len(evaluation_s) if evaluation_s else 0.0
    return per_iteration_s * iterations_left + per_evaluation_s * evaluations_left


def metrics(stats: EpisodeSummary, evaluation: EpisodeSummary | None, loss_dict: dict, learning_rate: float,
            mean_std: float, steps_per_s: float, collect_s: float, learn_s: float) -> dict[str, float]:
    """One iteration's scalars by tag (rsl-rl's tags where it has one): losses, learning rate, action noise, speed,
    the training episodes' means and the evaluation's."""
    scalars = {f"Loss/{name}": value for name, value in loss_dict.items()}
    scalars.update({"Loss/learning_rate": learning_rate, "Policy/mean_std": mean_std, "Perf/total_fps": steps_per_s,
                    "Perf/collection_time": collect_s, "Perf/learning_time": learn_s})
    if stats.episodes:
        scalars.update({"Train/mean_reward": stats.mean_return, "Train/mean_episode_length": stats.mean_episode_length,
                        "Episode/reward_per_step": stats.mean_reward_per_step,
                        "Episode/time_limit_fraction": stats.time_limit_fraction})
    if stats.full_episodes:
        scalars["Episode/full_reward_per_step"] = stats.full_reward_per_step
    if evaluation is not None:
        scalars.update({f"Eval/{name}": getattr(evaluation, name) for name in
                        ("mean_reward_per_step", "time_limit_fraction", "full_reward_per_step", "mean_return")
                        if getattr(evaluation, name) is not None})
    return scalars


class ProgressLine:
    """The console line of each iteration of one run of ``cfg``'s task on ``env``."""

    def __init__(self, cfg: TrainConfig, env: RslRlVecEnv, device: str):
        self.cfg, self.env, self.device = cfg, env, device
        self.solved_rule, self.play_metric = cfg.task_spec.solved, cfg.task_spec.play_metric

    def __call__(self, it: int, first: int, end: int, stats: EpisodeSummary, steps_per_s: float,
                 evaluation: EpisodeSummary | None, solved: bool, eta: float, policy_iteration: int | None = None,
                 ) -> str:
        """The line after iteration ``it`` of iterations ``first`` to ``end`` (exclusive), ``eta`` seconds left;
        ``policy_iteration``: the iteration of the policy ``evaluation`` judged, where not ``it``'s."""
        width = len(str(end))
        line = (f"it {it + 1:>{width}}/{end} | {self._episodes(stats)} | {steps_per_s / 1e3:6.1f}k steps/s"
                f" | ETA {format_duration(eta)}")
        if evaluation is not None:
            policy = f" of it {policy_iteration + 1}'s policy" if policy_iteration not in (None, it) else ""
            line += (f" | eval{policy} {self.play_metric} {getattr(evaluation, self.play_metric) or 0.0:.3f}"
                     f"{': SOLVED' if solved else ''}")
            if evaluation.cut_at_step is not None:
                line += (f" (cut at step {evaluation.cut_at_step}: {evaluation.episodes} episodes had failed, too many"
                         " for the rule)")
        if it == first and eta > LONG_RUN_S:
            line += "\n" + self.long_run_note(end - first, eta)
        return line

    def _episodes(self, stats: EpisodeSummary) -> str:
        """The training episodes' part of the line."""
        dt = self.cfg.env.sim.env_dt
        if not stats.episodes:  # a policy that balances ends no episode for many iterations: how long they have run
            running_s = self.env.episode_length_buf.float().mean().item() * dt
            return f"no episode ended; {self.env.num_envs} running, {running_s:5.2f} s in on average".ljust(60)
        full = ""
        if self.solved_rule.full_episodes_only:  # the rule's own figure, padded so the columns stay aligned
            full = (f" (full {stats.full_reward_per_step:5.3f})" if stats.full_episodes else "").ljust(13)
        length = stats.mean_episode_length
        return (f"reward/step {stats.mean_reward_per_step:6.3f}{full} | ep len {length * dt:5.2f} s "
                f"({length:5.0f}/{self.env.max_episode_length}) | {stats.episodes:5d} ep")

    def long_run_note(self, iterations: int, eta: float) -> str:
        """What to do about a run that will take hours here."""
        return (f"note: at this pace the {iterations} iterations of {self.cfg.task} take about "
                f"{format_duration(eta)} more on {self.device} ({self.cfg.env.num_envs} envs): a GPU (--device cuda) "
                "is far faster (docs/results.md: each task's measured times), or set fewer --max-iterations")
