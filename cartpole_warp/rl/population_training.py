"""One population's run (``PopulationTraining``): the members' env, learner and runners built from a ``TrainConfig``
and the members (``rl.population``), the joint loop, Ctrl-C handling, every member's run folder, and the
population's own files: ``members.md`` (a row per member) and ``population.json``.

    training = PopulationTraining(cfg, members_of([0, 1, 2]), run_dir)   # members in run_dir/seed0, ...
    result = training.run()
"""

from __future__ import annotations

import dataclasses
import json
import signal
import statistics
import time
from pathlib import Path

from ..engine.runtime import free_memory_bytes, resolve_device, timed
from ..settings.config import ConfigError
from ..settings.files import write_text
from ..wrappers.rsl_rl import RslRlVecEnv
from .config import TrainConfig
from .distributed import Ranks
from .policies import to_rsl_rl
from .population import Member, MemberLearner, PopulationEvaluation, PopulationLearner, check_population
from .progress import format_duration
from .runner import TaskRunner
from .runs import MEMBERS_FILE, POPULATION_FILE, RunSummary, save_config
from .training import bytes_per_env, finish_run


def check_population_memory(cfg: TrainConfig, members: int, device: str):
    """ConfigError in one line, with the estimate, where ``members`` x ``env.num_envs`` envs (and the evaluation's)
    would not fit in the free memory of the host or of ``device``."""
    per_env = bytes_per_env(cfg)
    needs = {"cpu": sum(per_env.values())} if device == "cpu" else {"cpu": per_env["host"], device: per_env["device"]}
    for where, need_per_env in needs.items():
        per_member = (cfg.env.num_envs + cfg.eval.num_envs) * need_per_env
        need, free = members * per_member, free_memory_bytes(where)
        if need > free:
            raise ConfigError(f"a population of {members} members x {cfg.env.num_envs:,} envs of {cfg.task} needs "
                              f"about {need / 1e9:,.1f} GB on {where} (with {cfg.eval.num_envs} evaluation envs each); "
                              f"it has {free / 1e9:,.1f} GB free: at most ~{free // per_member} members of "
                              f"{cfg.env.num_envs:,} envs (fewer --seeds or --num-envs)")


class PopulationTraining:
    """The population of ``members`` of ``cfg``'s task in ``run_dir``: member k trains on envs [k N, (k+1) N) of one
    env of K x N envs (N = ``env.num_envs``) and writes an ordinary run folder, ``run_dir / member.name``."""

    def __init__(self, cfg: TrainConfig, members: list[Member], run_dir: Path,
                 timing_s: dict[str, float] | None = None):
        cfg = cfg.validate()
        check_population(cfg, members)
        if Ranks.from_environment().distributed:
            raise ConfigError("a population trains in one process: run train.py --seeds without torchrun")
        device = resolve_device(cfg.env.device)
        check_population_memory(cfg, len(members), device)
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
                runner = TaskRunner(learner.env, member_cfg, self.run_dir / member.name, learner=learner)
                runner.report.console = False
                save_config(self.run_dir / member.name, member_cfg)
                self.runners.append(runner)
        with timed(self.timing_s, "eval_env"):
            eval_env = task.env_class(dataclasses.replace(cfg.env, num_envs=len(members) * cfg.eval.num_envs))
            self.evaluation = PopulationEvaluation(eval_env, self.learner, [m.seed for m in members], task.solved)
        self.evaluation_s = 0.0
        self.setup_time_s = time.perf_counter() - start
        self.interrupted = False

    def _on_signal(self, signum, frame):
        if self.interrupted:
            raise KeyboardInterrupt
        self.interrupted = True
        print("\nstopping every member after this iteration and saving (Ctrl-C again aborts without saving)",
              flush=True)

    def run(self) -> dict:
        """Train every member until its own stop (solved with ``stop_when_solved``, non-finite networks, Ctrl-C) or
        ``agent.max_iterations``; then each member's run folder is finished as a solo run's, and the population's
        table and ``population.json`` written (returned)."""
        previous = {sig: signal.signal(sig, self._on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            start = time.perf_counter()
            self._loop()
            self.train_time_s = time.perf_counter() - start
        finally:
            self.learner.release_graphs()
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        summaries = [finish_run(runner, self.run_dir / member.name, dict(self.timing_s), self.setup_time_s)
                     for runner, member in zip(self.runners, self.members)]
        return self._write(summaries)

    def _loop(self):
        iterations = self.cfg.agent.max_iterations
        for runner in self.runners:
            runner.start(iterations, self.cfg.agent.init_at_random_ep_len)
        obs, running = self.env.get_observations(), list(range(len(self.members)))
        loop_start = time.perf_counter()
        for it in range(iterations):
            obs, losses = self.learner.iteration(obs, it)
            readout = self.learner.read(losses)
            finite = readout.finite
            self._evaluate_if_due(it, [k for k in running if finite[k]])
            for k in list(running):
                runner = self.runners[k]
                if not finite[k]:
                    runner.stop_reason = "non-finite"
                    print(f"  {self.members[k].name}: its networks went non-finite in iteration {it + 1}; it ends "
                          "here, the others go on", flush=True)
                elif self.interrupted:
                    runner.request_stop("interrupted")
                if runner.stop_reason is not None or runner.after_iteration(it, readout.losses[k]):
                    running.remove(k)
                    self.learner.ppo.active[k] = False
                    runner.finish()
                self._judged_line(k)
            print(self._line(it, iterations, running, time.perf_counter() - loop_start), flush=True)
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
        print(f"  {self.members[k].name}: eval of it {policy}'s policy {metric} {evaluation[metric] or 0.0:.3f}"
              f"{': SOLVED' if history[-1]['solved'] else ''}", flush=True)

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
        """``members.md`` and ``population.json``: per member its seed, settings, status, iterations and seconds to
        solved and the play metric of the verdict; the population's wall time and env steps."""
        metric = self.cfg.task_spec.play_metric
        rows = []
        for member, summary in zip(self.members, summaries):
            solved = summary.solved_at or {}
            rows.append({"member": member.name, "seed": member.seed, "settings": dict(member.settings),
                         "status": summary.status, "solved_iterations": solved.get("iterations"),
                         "solved_s": solved.get("train_time_s"), metric: solved.get(metric),
                         "iterations": summary.iterations, "train_time_s": summary.train_time_s})
        solved_s = [row["solved_s"] for row in rows if row["solved_s"] is not None]
        env_steps = sum(summary.env_steps for summary in summaries)
        result = {"task": self.cfg.task, "members": rows, "solved": len(solved_s),
                  "train_time_s": round(self.train_time_s, 3), "evaluation_s": round(self.evaluation_s, 3),
                  "setup_time_s": round(self.setup_time_s, 3),
                  "env_steps": env_steps, "env_steps_per_s": round(env_steps / self.train_time_s),
                  "num_envs": self.env.num_envs, "device": self.env.device,
                  "median_solved_s": statistics.median(solved_s) if solved_s else None}
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
