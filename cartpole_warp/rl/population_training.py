"""One population's run (``PopulationTraining``): the members' env, learner and runners built from a ``TrainConfig``
and the members (``rl.population``), the joint loop, Ctrl-C handling, every member's run folder, and the
population's own files: ``members.md`` (a row per member) and ``population.json``.

    training = PopulationTraining(cfg, members_of([0, 1, 2]), run_dir)   # members in run_dir/seed0, ...
    result = training.run()
"""

from __future__ import annotations

import dataclasses
import json
import statistics
import time
from pathlib import Path

import torch

from ..engine.runtime import free_memory_bytes, resolve_device, timed
from ..settings.config import ConfigError
from ..settings.files import write_text
from ..wrappers.rsl_rl import RslRlVecEnv
from .config import TrainConfig
from .distributed import SINGLE_PROCESS, Ranks, from_every_rank, from_rank_zero, join_population_group
from .learners.batched_ppo.learner import Member, MemberLearner, PopulationLearner
from .policies import to_rsl_rl
from .population import PopulationEvaluation, check_population
from .progress import format_duration
from .runner import TaskRunner
from .runs import MEMBERS_FILE, POPULATION_FILE, RunSummary, save_config
from .training import Interrupts, bytes_per_env_by_place, finish_run


def check_population_memory(cfg: TrainConfig, members: int, device: str):
    """ConfigError in one line, with the estimate, where ``members`` x ``env.num_envs`` envs (and the evaluation's)
    would not fit in the free memory of the host or of ``device``."""
    for where, need_per_env in bytes_per_env_by_place(cfg, device).items():
        per_member = (cfg.env.num_envs + cfg.eval.num_envs) * need_per_env
        need, free = members * per_member, free_memory_bytes(where)
        if need > free:
            raise ConfigError(f"a population of {members} members x {cfg.env.num_envs:,} envs of {cfg.task} needs "
                              f"about {need / 1e9:,.1f} GB on {where} (with {cfg.eval.num_envs} evaluation envs each); "
                              f"it has {free / 1e9:,.1f} GB free: at most ~{free // per_member} members of "
                              f"{cfg.env.num_envs:,} envs (fewer --seeds or --num-envs)")


class PopulationTraining:
    """The population of ``members`` of ``cfg``'s task in ``run_dir``: member k trains on envs [k N, (k+1) N) of one
    env of K x N envs (N = ``env.num_envs``) and writes an ordinary run folder, ``run_dir / member.name``. In a
    torchrun job (``ranks``, default: torchrun's) each process trains its share of the members on its own GPU
    (``cuda:$LOCAL_RANK``), in rank 0's ``run_dir``; rank 0 writes the population's table."""

    def __init__(self, cfg: TrainConfig, members: list[Member], run_dir: Path,
                 timing_s: dict[str, float] | None = None, ranks: Ranks | None = None):
        self.ranks = ranks if ranks is not None else Ranks.from_environment()
        self.prefix = f"rank {self.ranks.rank}: " if self.ranks.distributed else ""
        """Before each console line of this process."""
        cfg = self._process_config(cfg.validate(), members)
        self.all_members, members = members, self.ranks.share(members)
        check_population_memory(cfg, len(members), cfg.env.device)
        join_population_group(self.ranks, cfg.env.device)
        run_dir = from_rank_zero(Path(run_dir), self.ranks)
        start = time.perf_counter()
        self.cfg, self.members, self.run_dir = cfg, members, Path(run_dir)
        self.timing_s = dict(timing_s or {})
        self.cfgs = [member.config(cfg) for member in members]
        cfg.apply_torch_threads()
        n, task = cfg.env.num_envs, cfg.task_spec
        env = task.env_class(dataclasses.replace(cfg.env, num_envs=len(members) * n))
        self.timing_s |= env.build_time_s
        for k, member in enumerate(members):  # each block as a solo run of its seed starts
            env.restart(k * n, (k + 1) * n, member.seed)
        self.env = RslRlVecEnv(env)
        with timed(self.timing_s, "networks"):
            rsl_rl_cfg = to_rsl_rl(cfg.agent, mirror=self.env.obs_mirror is not None, images=self.env.images)
            self.learner = PopulationLearner(self.env, self.cfgs, rsl_rl_cfg, cfg.env.seed)
            self.runners = []
            for k, (member, member_cfg) in enumerate(zip(members, self.cfgs)):
                learner = MemberLearner(self.learner, k)
                runner = TaskRunner(learner.env, member_cfg, self.run_dir / member.name, learner=learner,
                                    ranks=SINGLE_PROCESS)
                runner.report.console = False
                save_config(self.run_dir / member.name, member_cfg)
                self.runners.append(runner)
        with timed(self.timing_s, "eval_env"):
            eval_env = task.env_class(dataclasses.replace(cfg.env, num_envs=len(members) * cfg.eval.num_envs))
            self.evaluation = PopulationEvaluation(eval_env, self.learner, [m.seed for m in members], task.solved)
        self.evaluation_s = 0.0
        self.iteration_s: list[float] = []
        """Each iteration's wall seconds, its members' evaluations, checkpoints and lines included."""
        self.setup_time_s = time.perf_counter() - start
        self.interrupted = False

    def _process_config(self, cfg: TrainConfig, members: list[Member]) -> TrainConfig:
        """``cfg`` as this process trains it (ConfigError where a population cannot): on this process's device, and
        judged on envs of its own where the task evaluates inside the step (``eval.in_step``: a task's GPU default for
        long runs, made for one run's envs)."""
        if cfg.eval.in_step:
            print(f"{self.prefix}note: a population judges its members on envs of their own, not inside the "
                  "training's step (eval.in_step)", flush=True)
            cfg = dataclasses.replace(cfg, eval=dataclasses.replace(cfg.eval, in_step=False))
        check_population(cfg, members)
        device = resolve_device(self.ranks.device(cfg.env.device, torch.cuda.device_count()))
        return dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, device=device))

    def run(self) -> dict:
        """Train every member until its own stop (solved with ``stop_when_solved``, non-finite networks, Ctrl-C) or
        ``agent.max_iterations``; then each member's run folder is finished as a solo run's, and the population's
        table and ``population.json`` written (returned)."""
        def stop():
            self.interrupted = True

        def say(line: str):  # on a line of its own, after the terminal's ^C
            print(f"\n{self.prefix}{line}", flush=True)

        with Interrupts(stop, say, "stopping every member") as interrupts:
            start = time.perf_counter()
            try:
                self._loop()
            finally:
                interrupts.finishing = True
                self.learner.release_graphs()
            self.train_time_s = time.perf_counter() - start
            summaries = [finish_run(runner, self.run_dir / member.name, dict(self.timing_s), self.setup_time_s)
                         for runner, member in zip(self.runners, self.members)]
            return self._write(summaries)

    def _loop(self):
        iterations = self.cfg.agent.max_iterations
        for runner in self.runners:
            runner.start(iterations, self.cfg.agent.init_at_random_ep_len)
        obs, running = self.env.get_observations(), list(range(len(self.members)))
        loop_start = tick = time.perf_counter()
        for it in range(iterations):
            obs, losses = self.learner.iteration(obs, it)
            readout = self.learner.read(losses)
            finite = readout.finite
            self._evaluate_if_due(it, [k for k in running if finite[k]])
            for k in list(running):
                runner = self.runners[k]
                if not finite[k]:
                    runner.stop_reason = "non-finite"
                    print(f"{self.prefix}  {self.members[k].name}: its networks went non-finite in iteration {it + 1}; "
                          "it ends here, the others go on", flush=True)
                elif self.interrupted:
                    runner.request_stop("interrupted")
                if runner.stop_reason is not None or runner.after_iteration(it, readout.losses[k]):
                    running.remove(k)
                    self.learner.ppo.active[k] = False
                    runner.finish()
                self._judged_line(k)
            print(self.prefix + self._line(it, iterations, running, time.perf_counter() - loop_start), flush=True)
            self.iteration_s.append(time.perf_counter() - tick)
            tick = time.perf_counter()
            if not running:
                break
        for k in running:
            self.runners[k].finish()

    def _evaluate_if_due(self, it: int, running: list[int]):
        """Where any of the ``running`` members is due for an evaluation after iteration ``it`` (its own schedule:
        ``Evaluations.due``), every one of them is judged, in one batched run; each member's runner takes its
        verdict."""
        runners = self.runners
        if not any(runners[k].evaluations.due(it, runners[k].episodes.summary()) for k in running):
            return
        start = time.perf_counter()
        for k, summary in self.evaluation(running).items():
            runners[k].evaluations.give(summary)
        self.evaluation_s += time.perf_counter() - start

    def _judged_line(self, k: int):
        """A line where member ``k``'s latest iteration brought a verdict."""
        history = self.runners[k].progress.history
        evaluation = history[-1].get("evaluation") if history else None
        if evaluation is None:
            return
        metric = self.cfg.task_spec.play_metric
        policy = evaluation.get("policy_iteration", history[-1]["iteration"]) + 1
        print(f"{self.prefix}  {self.members[k].name}: eval of it {policy}'s policy {metric} "
              f"{evaluation[metric] or 0.0:.3f}{': SOLVED' if history[-1]['solved'] else ''}", flush=True)

    def _line(self, it: int, iterations: int, running: list[int], elapsed_s: float) -> str:
        """The population's console line after iteration ``it``."""
        solved = sum(runner.progress.solved_at is not None for runner in self.runners)
        rewards = [self.runners[k].progress.history[-1]["mean_reward_per_step"] for k in running
                   if self.runners[k].progress.history and self.runners[k].progress.history[-1]["episodes"]]
        spread = f" | reward/step {min(rewards):6.3f} .. {max(rewards):6.3f}" if rewards else ""
        steps_per_s = (it + 1) * self.env.num_envs * self.cfg.agent.num_steps_per_env / elapsed_s
        eta = elapsed_s / (it + 1) * (iterations - it - 1)
        return (f"it {it + 1:>{len(str(iterations))}}/{iterations} | {len(running)} running, {solved} solved of "
                f"{len(self.members)}{spread} | {steps_per_s / 1e6:6.2f}M steps/s | ETA {format_duration(eta)}")

    def _write(self, summaries: list[RunSummary]) -> dict:
        """``members.md`` and ``population.json`` (rank 0 writes them; every process returns the whole): per member its
        seed, settings, status, iterations and seconds to solved and the play metric of the verdict; the population's
        wall time (its slowest process's), env steps, and the pace of its median iterations (between evaluations and
        checkpoints; summed over the processes)."""
        metric = self.cfg.task_spec.play_metric
        rows = []
        for member, summary in zip(self.members, summaries):
            solved = summary.solved_at or {}
            rows.append({"member": member.name, "seed": member.seed, "settings": dict(member.settings),
                         "status": summary.status, "solved_iterations": solved.get("iterations"),
                         "solved_s": solved.get("train_time_s"), metric: solved.get(metric),
                         "iterations": summary.iterations, "train_time_s": summary.train_time_s})
        median_s = statistics.median(self.iteration_s) if self.iteration_s else None
        parts = from_every_rank({"rows": rows, "train_time_s": self.train_time_s, "evaluation_s": self.evaluation_s,
                                 "setup_time_s": self.setup_time_s, "num_envs": self.env.num_envs,
                                 "env_steps": sum(summary.env_steps for summary in summaries),
                                 "median_iteration_s": median_s,
                                 "iteration_env_steps": self.env.num_envs * self.cfg.agent.num_steps_per_env},
                                self.ranks)
        rows = [row for part in parts for row in part["rows"]]
        solved_s = [row["solved_s"] for row in rows if row["solved_s"] is not None]
        train_time_s, env_steps = max(part["train_time_s"] for part in parts), sum(part["env_steps"] for part in parts)
        medians = [part["median_iteration_s"] for part in parts]
        paced = None not in medians
        result = {"task": self.cfg.task, "members": rows, "solved": len(solved_s),
                  "train_time_s": round(train_time_s, 3),
                  "evaluation_s": round(max(part["evaluation_s"] for part in parts), 3),
                  "setup_time_s": round(max(part["setup_time_s"] for part in parts), 3),
                  "env_steps": env_steps, "env_steps_per_s": round(env_steps / train_time_s),
                  "median_iteration_s": round(max(medians), 5) if paced else None,
                  "median_iteration_env_steps_per_s": round(sum(part["iteration_env_steps"] / part["median_iteration_s"]
                                                                for part in parts)) if paced else None,
                  "num_envs": sum(part["num_envs"] for part in parts), "device": self.env.device,
                  "processes": self.ranks.world_size,
                  "median_solved_s": statistics.median(solved_s) if solved_s else None}
        if self.ranks.writes:
            write_text(self.run_dir / POPULATION_FILE, json.dumps(result, indent=2) + "\n")
            write_text(self.run_dir / MEMBERS_FILE, members_table(rows, metric))
        return result


def members_table(rows: list[dict], metric: str) -> str:
    """The members' markdown table (``PopulationTraining._write``'s rows)."""
    lines = [f"| member | status | solved at iteration | solved after s | {metric} | iterations | seconds |",
             "|---|---|---|---|---|---|---|"]
    for row in rows:
        value = f"{row[metric]:.3f}" if row[metric] is not None else "-"
        lines.append(f"| {row['member']} | {row['status']} | {row['solved_iterations'] or '-'} | "
                     f"{row['solved_s'] if row['solved_s'] is not None else '-'} | {value} | {row['iterations']} | "
                     f"{row['train_time_s']} |")
    return "\n".join(lines) + "\n"
