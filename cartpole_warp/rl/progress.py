"""What a training run reports after each iteration (``Report``): its console line (``ProgressLine``), its metrics
(``metrics``: tensorboard's or wandb's scalars, through rsl-rl's ``Logger``) and the time it has left (``eta_s``)."""

from __future__ import annotations

from ..wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

from rsl_rl.utils.logger import Logger

from ..evaluation.statistics import EpisodeSummary
from .config import TrainConfig
from .distributed import Ranks
from .learners import Learner

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


def run_eta_s(progress, start_s: float, span: tuple[int, int, int], evaluations, member: int = 0) -> float:
    """``eta_s`` of a run (``runs.Progress``, started at ``perf_counter`` ``start_s``) after iteration ``it`` of
    ``span`` (first, it, end: exclusive); the evaluations due are ``member``'s periodic ones of ``evaluations``
    (``rl.evaluations.Evaluations``: ``eval.max_interval``)."""
    first, it, end = span
    measured = [h["evaluation"]["seconds"] for h in progress.history if h["iteration"] >= first and "evaluation" in h]
    last = evaluations.last_iteration[member]
    due = (end - 1 - last) // evaluations.limits.max_interval if evaluations.enabled else 0
    return eta_s(time.perf_counter() - start_s, measured, it + 1 - first, end - it - 1, due)


class ProgressLine:
    """The console line of each iteration of ``member``'s run of ``cfg``'s task by ``learner`` (its ``num_envs`` envs,
    their time limit ``max_episode_length`` env steps, on ``device``)."""

    def __init__(self, cfg: TrainConfig, learner: Learner, member: int, num_envs: int, max_episode_length: int,
                 device: str):
        self.cfg, self.learner, self.member, self.device = cfg, learner, member, device
        self.num_envs, self.max_episode_length = num_envs, max_episode_length
        self.solved_rule, self.play_metric = cfg.task_spec.solved, cfg.task_spec.play_metric
        self.staggered_starts = False
        """The run started each env's time-out counter at a random step (its first iteration's line says so)."""

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
        if it == first and self.staggered_starts:
            line += ("\nnote: each env's time-out counter starts at a random step (agent.init_at_random_ep_len), "
                     "so the first episodes end early, a few at a time")
        if it == first and eta > LONG_RUN_S:
            line += "\n" + self.long_run_note(end - first, eta)
        return line

    def _episodes(self, stats: EpisodeSummary) -> str:
        """The training episodes' part of the line."""
        dt = self.cfg.env.sim.env_dt
        if not stats.episodes:  # a policy that balances ends no episode for many iterations: how long they have run
            running_s = self.learner.episode_steps[self.member].float().mean().item() * dt
            return f"no episode ended; {self.num_envs} running, {running_s:5.2f} s in on average".ljust(60)
        full = ""
        if self.solved_rule.full_episodes_only:  # the rule's own figure, padded so the columns stay aligned
            full = (f" (full {stats.full_reward_per_step:5.3f})" if stats.full_episodes else "").ljust(13)
        length = stats.mean_episode_length
        return (f"reward/step {stats.mean_reward_per_step:6.3f}{full} | ep len {length * dt:5.2f} s "
                f"({length:5.0f}/{self.max_episode_length}) | {stats.episodes:5d} ep")

    def long_run_note(self, iterations: int, eta: float) -> str:
        """What to do about a run that will take hours here."""
        return (f"note: at this pace the {iterations} iterations of {self.cfg.task} take about "
                f"{format_duration(eta)} more on {self.device} ({self.cfg.env.num_envs} envs): a GPU (--device cuda) "
                "is far faster (docs/results.md: each task's measured times), or set fewer --max-iterations")


def population_lines(metric: str, names: list[str], progresses: list, verdicts: dict[int, int], running: list[int],
                     span: tuple[int, int, int], elapsed_s: float, env_steps_per_iteration: int) -> list[str]:
    """A population's console after iteration ``it`` of ``span`` (it, first, end: exclusive), ``elapsed_s`` into its
    training: a line per member with a verdict (``verdicts``: member -> the iteration of the policy judged; its
    ``play metric`` from its ``progresses``' history, ``runs.Progress``), then the population's: the members
    ``running``, those solved, the spread of their rewards per step, its pace and the time it has left."""
    it, first, end = span
    lines = []
    for k in sorted(verdicts):
        entry = progresses[k].history[-1]
        value = entry["evaluation"][metric] or 0.0
        lines.append(f"  {names[k]}: eval of it {verdicts[k] + 1}'s policy {metric} {value:.3f}"
                     f"{': SOLVED' if entry['solved'] else ''}")
    solved = sum(progress.solved_at is not None for progress in progresses)
    last = {k: progresses[k].history[-1] for k in running}
    rewards = [entry["mean_reward_per_step"] for entry in last.values() if entry["episodes"]]
    spread = f" | reward/step {min(rewards):6.3f} .. {max(rewards):6.3f}" if rewards else ""
    done = it + 1 - first
    steps_per_s, eta = done * env_steps_per_iteration / elapsed_s, elapsed_s / done * (end - it - 1)
    lines.append(f"it {it + 1:>{len(str(end))}}/{end} | {len(running)} running, {solved} solved of {len(progresses)}"
                 f"{spread} | {steps_per_s / 1e6:6.2f}M steps/s | ETA {format_duration(eta)}")
    return lines


def in_git_repository(path: str) -> bool:
    """Whether ``path`` lies in a git checkout (rsl-rl stores the code state of those, and prints a line for each
    other, e.g. an installed rsl_rl)."""
    return any((parent / ".git").exists() for parent in Path(path).resolve().parents)


@dataclass
class Pace:
    """One iteration's speed: env steps per second and the seconds of collection and of learning (device time)."""

    steps_per_s: float
    collect_s: float
    learn_s: float


def history_entry(progress, it: int, stats: EpisodeSummary, pace: Pace, judged, evaluation_s: float,
                  solved: bool) -> dict:
    """Iteration ``it``'s entry of ``progress.history`` (``runs.Progress``): the training episodes, speed, whether
    solved, and the evaluation's verdict (``rl.evaluations.Judged``) where one came, with its seconds."""
    entry = {"iteration": it, "env_steps": progress.env_steps, "train_time_s": round(progress.train_time_s, 3),
             **dataclasses.asdict(stats), "env_steps_per_s": pace.steps_per_s, "collection_ms": pace.collect_s * 1e3,
             "learning_ms": pace.learn_s * 1e3, "solved": solved}
    if judged is not None:
        entry["evaluation"] = dataclasses.asdict(judged.summary) | {"seconds": round(evaluation_s, 3)}
        if judged.iteration != it:
            entry["evaluation"]["policy_iteration"] = judged.iteration
    return entry


def write_scalars(writer, scalars: dict[str, float], step: int):
    """``scalars`` at ``step`` through rsl-rl's metrics ``writer``: into TensorBoard's event file as one event (a
    population writes each of its members' every iteration; ``add_scalar`` makes an event per scalar), into any other
    writer (wandb, neptune, none) scalar by scalar."""
    if type(writer).__module__ != "torch.utils.tensorboard.writer":  # rsl-rl's tensorboard writer is torch's own
        for tag, value in scalars.items():
            writer.add_scalar(tag, value, step)
        return
    from tensorboard.compat.proto.summary_pb2 import Summary  # imported by the writer already

    values = [Summary.Value(tag=tag, simple_value=float(value)) for tag, value in scalars.items()]
    writer._get_file_writer().add_summary(Summary(value=values), step)


class Report:
    """Where each iteration of ``member``'s run of ``cfg`` by ``learner`` on ``env`` is reported: rsl-rl's ``logger``
    (its own console with ``console: rsl_rl``, else its metrics writer: TensorBoard, wandb or none, in ``log_dir``;
    None writes nothing) and, on the process that writes, the console line."""

    def __init__(self, cfg: TrainConfig, learner: Learner, member: int, env, rsl_rl_cfg: dict, log_dir: Path | None,
                 ranks: Ranks):
        num_envs = learner.episode_steps.shape[1]  # the envs the member's episodes are of
        self.logger = Logger(str(log_dir) if log_dir is not None else None, rsl_rl_cfg, env.cfg, num_envs,
                             ranks.distributed, ranks.world_size, ranks.rank, env.device)
        self.logger.git_status_repos = [path for path in (*self.logger.git_status_repos, __file__)
                                        if in_git_repository(path)]
        self.line = ProgressLine(cfg, learner, member, num_envs, env.max_episode_length, env.device)
        self.rsl_rl_console, self.writes = cfg.console == "rsl_rl", ranks.writes
        self.console = True
        """Print the console line (a population prints its own)."""

    def __call__(self, span: tuple[int, int, int], stats: EpisodeSummary, losses: dict, learning_rate: float,
                 action_std, pace: Pace, verdict: tuple[EpisodeSummary, int, bool] | None, eta: float):
        """Report iteration ``it`` of ``span`` (first, it, end: exclusive); ``verdict``: an evaluation's summary, the
        iteration of the policy it judged and whether it is solved."""
        first, it, end = span
        if self.rsl_rl_console:
            self.logger.log(it=it, start_it=first, total_it=end, collect_time=pace.collect_s,
                            learn_time=pace.learn_s, loss_dict=losses, learning_rate=learning_rate,
                            action_std=action_std, rnd_weight=None)
            return
        if not self.writes:
            return
        evaluation, judged_iteration, solved = verdict if verdict is not None else (None, None, False)
        if self.logger.writer is not None:
            scalars = metrics(stats, evaluation, losses, learning_rate, action_std.mean().item(), pace.steps_per_s,
                              pace.collect_s, pace.learn_s)
            by_step: dict[int, dict[str, float]] = {}  # an evaluation at the iteration of the policy it judged
            for tag, value in scalars.items():
                by_step.setdefault(judged_iteration if tag.startswith("Eval/") else it, {})[tag] = value
            for step, step_scalars in by_step.items():
                write_scalars(self.logger.writer, step_scalars, step)
        if self.console:
            print(self.line(it, first, end, stats, pace.steps_per_s, evaluation, solved, eta, judged_iteration),
                  flush=True)
