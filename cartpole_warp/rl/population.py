"""Populations: K trainings of one task in one process, on one batched env, learning as one batched computation.

    python train.py --task cartpole-swingup --seeds 0 1 2 3 4 5 6 7 8 9 --device cuda
    python train.py --seeds 0 1 --population.vary agent.algorithm.learning-rate=1e-3,3e-4     # 4 members

Member k (``Member``: a seed and the settings it differs in) owns envs [k N, (k+1) N) of one env of K x N envs,
restarted as a solo run of its seed starts them (``BatchedEnv.restart``: the same start states and physics draws), and
networks initialised as that run's. ``BatchedPpoLearner`` (``learners.batched_ppo``) runs the members' iterations
together: one rollout of the whole env, then one batched PPO update (per member rsl-rl's PPO) of the members still
training. Everything else is per member, a run's record in the one training loop (``rl.loop``, ``rl.record``): its
progress, evaluations (on envs of their own, with its seed; all members' in one batched run), verdicts,
``model_best.pt``, checkpoints, exports, curve and ``summary.json`` in a run folder of its own, which ``play.py --run``
and ``train.py --resume`` take as any run's. Here: the members, what keeps a training from being one, and the
population's own files.
"""

from __future__ import annotations

from ..wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
import itertools
import json
import statistics
from typing import TYPE_CHECKING

from ..settings.config import ConfigError, refuse_present
from ..settings.deprecation import moved_names
from ..settings.files import write_text
from .config import TrainConfig
from .distributed import Ranks, from_every_rank
from .learners.batched_ppo.learner import VARIABLE_SETTINGS, Member, batched_ppo_problems
from .runs import MEMBERS_FILE, POPULATION_FILE, RunSummary, copy_policy

if TYPE_CHECKING:
    from pathlib import Path

    from .loop import TrainingLoop


def setting_name(flag: str) -> str:
    """A setting's name as ``agent.algorithm`` holds it, of its flag (``agent.algorithm.learning-rate``,
    ``learning-rate``)."""
    return flag.strip().replace("-", "_").removeprefix("agent.algorithm.")


def parse_vary(vary: list[str]) -> dict[str, list[float]]:
    """``--population.vary`` entries (``agent.algorithm.learning-rate=1e-3,3e-4``) as {setting: values};
    ConfigError in one line for a setting members cannot differ in, a value that is not a number, or a setting named
    twice."""
    grid: dict[str, list[float]] = {}
    for entry in vary:
        name, sep, values = entry.partition("=")
        setting = setting_name(name)
        flag = f"--population.vary {entry!r}"
        if not sep or not values:
            raise ConfigError(f"{flag}: write name=value1,value2 (agent.algorithm.learning-rate=1e-3,3e-4)")
        if setting not in VARIABLE_SETTINGS:
            raise ConfigError(f"--population.vary {name}: members share one env and their networks' shapes, so they "
                              f"may differ only in agent.algorithm's {', '.join(VARIABLE_SETTINGS)}")
        if setting in grid:
            raise ConfigError(f"--population.vary names {setting} twice: give all its values in one entry")
        try:
            grid[setting] = [float(value) for value in values.split(",")]
        except ValueError:
            raise ConfigError(f"{flag}: the values must be numbers, comma-separated") from None
    return grid


def members_of(seeds: list[int], vary: list[str] = ()) -> list[Member]:
    """One member per combination of the values of the ``vary`` settings (``--population.vary``) and seed;
    ConfigError in one line for no seeds or a seed given twice."""
    if not seeds:
        raise ConfigError("a population needs seeds: --seeds 0 1 2 ...")
    if len(set(seeds)) != len(seeds):
        twice = sorted({seed for seed in seeds if seeds.count(seed) > 1})
        raise ConfigError(f"--seeds names seed {', '.join(map(str, twice))} twice: each member needs its own seed")
    grid = parse_vary(list(vary))
    combinations = itertools.product(*[[(name, value) for value in values] for name, values in grid.items()])
    return [Member(seed, tuple(settings)) for settings in combinations for seed in seeds]


def check_population(cfg: TrainConfig):
    """ConfigError in one line where ``cfg`` cannot train as a population (``batched_ppo_problems``)."""
    problems = {f"--learner {cfg.agent.learner} (populations train with PPO)": cfg.agent.learner != "ppo",
                **batched_ppo_problems(cfg)}
    refuse_present(f"a population of {cfg.task} cannot train", problems)


def member_rows(members: list[Member], summaries: list[RunSummary], metric: str) -> list[dict]:
    """A row per member of the population's table: its seed, settings, status, iterations and seconds to solved and
    the play metric of the verdict (``summaries``: the members' ``summary.json``)."""
    rows = []
    for member, summary in zip(members, summaries):
        solved = summary.solved_at or {}
        rows.append({"member": member.name, "seed": member.seed, "settings": dict(member.settings),
                     "status": summary.status, "solved_iterations": solved.get("iterations"),
                     "solved_s": solved.get("train_time_s"), metric: solved.get(metric),
                     "iterations": summary.iterations, "train_time_s": summary.train_time_s})
    return rows


def write_population(loop: TrainingLoop, summaries: list[RunSummary], run_dir: Path, ranks: Ranks,
                     train_time_s: float, setup_time_s: float) -> dict:
    """A population's ``members.md`` and ``population.json`` in ``run_dir`` (rank 0 of ``ranks`` writes them; every
    process returns the whole), after ``loop`` trained this process's members (whose ``summaries`` these are) for
    ``train_time_s``: the members' rows (``member_rows``); the population's wall time (its slowest process's), env
    steps, and the pace of its median iterations (evaluations, checkpoints and lines included; summed over the
    processes); its modes' entries (``rl.modes``), and where it ended at its first solved member, that member's policy
    in ``run_dir`` (``runs.copy_policy``)."""
    cfg, metric = loop.config, loop.config.task_spec.play_metric
    median_s = statistics.median(loop.iteration_s) if loop.iteration_s else None
    rows, modes = member_rows(loop.members, summaries, metric), {}
    for mode in loop.modes:
        modes |= mode.annotate(loop, rows)
    parts = from_every_rank({"rows": rows, "train_time_s": train_time_s,
                             "evaluation_s": loop.evaluation_s, "setup_time_s": setup_time_s,
                             "num_envs": loop.env.num_envs, "median_iteration_s": median_s,
                             "env_steps": sum(summary.env_steps for summary in summaries),
                             "iteration_env_steps": loop.env.num_envs * cfg.agent.num_steps_per_env}, ranks)
    rows = [row for part in parts for row in part["rows"]]
    solved_s = [row["solved_s"] for row in rows if row["solved_s"] is not None]
    train_time_s, env_steps = max(part["train_time_s"] for part in parts), sum(part["env_steps"] for part in parts)
    medians = [part["median_iteration_s"] for part in parts]
    paced = None not in medians
    result = {"task": cfg.task, "members": rows, "solved": len(solved_s),
              "train_time_s": round(train_time_s, 3),
              "evaluation_s": round(max(part["evaluation_s"] for part in parts), 3),
              "setup_time_s": round(max(part["setup_time_s"] for part in parts), 3),
              "env_steps": env_steps, "env_steps_per_s": round(env_steps / train_time_s),
              "median_iteration_s": round(max(medians), 5) if paced else None,
              "median_iteration_env_steps_per_s": round(sum(part["iteration_env_steps"] / part["median_iteration_s"]
                                                            for part in parts)) if paced else None,
              "num_envs": sum(part["num_envs"] for part in parts), "device": loop.env.device,
              "processes": ranks.world_size,
              "median_solved_s": statistics.median(solved_s) if solved_s else None} | modes
    if result.get("first_solved") is not None:  # the population's policy: its first solved member's
        copy_policy(run_dir / result["first_solved"], run_dir)
    if ranks.writes:
        write_text(run_dir / POPULATION_FILE, json.dumps(result, indent=2) + "\n")
        write_text(run_dir / MEMBERS_FILE, members_table(rows, metric))
    return result


def members_table(rows: list[dict], metric: str) -> str:
    """The members' markdown table (``write_population``'s rows), with the states each took, under population-based
    training (``rl.modes.Exploitation``: iteration, member)."""
    lineage = any("lineage" in row for row in rows)
    extra = (" took the state of |", "---|") if lineage else ("", "")
    lines = [f"| member | status | solved at iteration | solved after s | {metric} | iterations | seconds |{extra[0]}",
             "|---|---|---|---|---|---|---|" + extra[1]]
    for row in rows:
        value = f"{row[metric]:.3f}" if row[metric] is not None else "-"
        took = ", ".join(f"{member} at {iteration}" for iteration, member in row.get("lineage", ())) or "-"
        lines.append(f"| {row['member']} | {row['status']} | {row['solved_iterations'] or '-'} | "
                     f"{row['solved_s'] if row['solved_s'] is not None else '-'} | {value} | {row['iterations']} | "
                     f"{row['train_time_s']} |" + (f" {took} |" if lineage else ""))
    return "\n".join(lines) + "\n"

__getattr__ = moved_names(__name__, f"{__package__}.learners.batched_ppo.learner")
"""The learner's parts that lived here (``BatchedPpoLearner``, ``Member``, ...), until
``settings.deprecation.REMOVED_IN``."""
