"""``TaskRunner``: rsl-rl's ``OnPolicyRunner`` with the training loop reporting each iteration, for any task.

    runner = TaskRunner(RslRlVecEnv(cfg.task_spec.env_class(cfg.env)), cfg, log_dir)
    runner.learn(cfg.agent.max_iterations)     # runner.request_stop() ends it after the current iteration

It overrides, openly, what rsl-rl offers no hook for: ``learn`` (rsl-rl's rollout / returns / update loop, then
episode statistics summed on the device, the progress, the task's "solved" decision, the metrics, one console line and
stop requests after each iteration), ``save`` / ``load`` (atomic checkpoints that carry the progress; clear errors),
and it adds ``policy`` and ``export``.
"""

from __future__ import annotations

from ..wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
import contextlib
import copy
import dataclasses
import io
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from rsl_rl.runners import OnPolicyRunner
from tensordict import TensorDict

from ..engine.env import BatchedEnv
from ..engine.streams import PhaseClock, TorchGraph
from ..evaluation.rollouts import FirstEpisodesRun, Policy, evaluate
from ..evaluation.statistics import EpisodeStats, EpisodeSummary
from ..settings.deprecation import moved_names, renamed
from ..settings.files import atomic_write
from ..wrappers.rsl_rl import RslRlVecEnv
from ..wrappers.tensordict_import import mark_for_compile
from .config import TrainConfig
from .distributed import joint_stop
from .policies import deterministic, export_policy, networks_must_fit, read_checkpoint, to_rsl_rl
from .ppo import SyncFreePPO
from .progress import ProgressLine, eta_s, metrics
from .runs import BEST_CHECKPOINT, Progress


def in_git_repository(path: str) -> bool:
    """Whether ``path`` lies in a git checkout (rsl-rl stores the code state of those, and prints a line for each
    other, e.g. an installed rsl_rl)."""
    return any((parent / ".git").exists() for parent in Path(path).resolve().parents)


@dataclass
class Judged:
    """An evaluation's verdict on the policy after iteration ``iteration``, trained on ``env_steps``."""

    summary: EpisodeSummary
    iteration: int
    env_steps: int
    state: dict | None = None
    """The policy's checkpoint state (``_state_dict``), where it is no longer the runner's own (None: it is)."""


class TaskRunner(OnPolicyRunner):
    """OnPolicyRunner for one training run: ``log_dir`` None writes nothing (no metrics, no checkpoints).

    With an ``eval_env`` (``cfg.eval.num_envs`` envs of the task, seeded with the run's seed) the deterministic policy
    is evaluated over whole episodes (``evaluation.evaluate``: play.py's episodes) when an iteration's training
    episodes meet the task's rule (at most every ``eval.min_interval`` iterations) and at least every
    ``eval.max_interval``; only an evaluation decides 'solved', and the best one so far is kept as ``model_best.pt``.
    Where ``env`` carries an ``InStepEvaluation`` (``eval.in_step``) the same evaluations run on its extra envs
    instead, beside the training steps: one at a time, on a frozen copy of the policy as it was when due, judged
    iterations later (``Judged.iteration`` names the policy).
    """

    def __init__(self, env: RslRlVecEnv, cfg: TrainConfig, log_dir: Path | None, eval_env: BatchedEnv | None = None):
        if cfg.agent.torch_compile_mode is not None:
            mark_for_compile()
        with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl prints its resolved observation sets
            super().__init__(env, to_rsl_rl(cfg.agent, mirror=env.obs_mirror is not None, images=env.images),
                             str(log_dir) if log_dir is not None else None, env.device)
        self.train_cfg = cfg
        task = cfg.task_spec
        self.solved_rule, self.play_metric = task.solved, task.play_metric
        self.eval_env = eval_env
        self._evaluation: FirstEpisodesRun | None = None
        self.in_step = env.evaluation
        """The evaluation inside the training's step (None: evaluations run on ``eval_env``, if any)."""
        self._in_step_policy: tuple[int, int, dict] | None = None
        """The iteration, env steps and checkpoint state of the policy the in-step evaluation plays."""
        if self.in_step is not None:
            self._frozen_actor = copy.deepcopy(self.alg.get_policy()).eval().requires_grad_(False)
            self.in_step.policy = deterministic(self._frozen_actor)
        self._last_eval_iteration = -1
        self.progress = Progress()
        self.episodes = EpisodeStats(env.device, env.max_episode_length)
        self.stop_reason: str | None = None
        self._stop_requested: str | None = None
        graphable = (cfg.agent.cuda_graph and cfg.agent.algorithm.class_name == "SyncFreePPO"
                     and cfg.console != "rsl_rl"
                     and torch.device(self.device).type == "cuda")
        self._rollout_graph = TorchGraph(self.device) if graphable else None
        self._rollout_input: TensorDict | None = None
        self.progress_line = ProgressLine(cfg, env, self.device)
        self._clock = PhaseClock(self.device, phases=2)
        """Collection and learning time of each iteration, on the device."""
        self.on_iteration: Callable[[int, EpisodeSummary], None] | None = None
        """Called after each iteration's console line (rank 0) with the iteration and its episodes' summary (the
        browser viewer's hook)."""
        self.logger.git_status_repos = [path for path in (*self.logger.git_status_repos, __file__)
                                        if in_git_repository(path)]

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
        """rsl-rl's loop for ``num_learning_iterations`` iterations, ending early on a stop request or, with
        ``stop_when_solved``, once solved. Non-finite states never reach PPO (the env resets them), so there is no
        per-step NaN check; episode statistics stay on the device until the iteration ends."""
        if init_at_random_ep_len:
            self.env.episode_length_buf = torch.randint_like(self.env.episode_length_buf,
                                                             high=int(self.env.max_episode_length))
        obs = self.env.get_observations().to(self.device)
        self.alg.train_mode()
        if self.is_distributed:
            self.alg.broadcast_parameters()
        with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl says where it stores the code's git state
            self.logger.init_logging_writer()
        self._first_iteration = self.current_learning_iteration
        self._last_eval_iteration = self._first_iteration - 1
        self._end_iteration = self._first_iteration + num_learning_iterations
        self._start = self._tick = time.perf_counter()
        for it in range(self._first_iteration, self._end_iteration):
            obs, loss_dict = self._iteration(obs)
            self.current_learning_iteration = it
            self._end_of_iteration(it, loss_dict)
            if self.stop_reason is not None:
                break
            if self.run_dir is not None and it % self.cfg["save_interval"] == 0:
                self.save(str(self.run_dir / f"model_{it}.pt"))
        if self.run_dir is not None:
            self.save(str(self.run_dir / f"model_{self.current_learning_iteration}.pt"))
            self.logger.stop_logging_writer()

    def _iteration(self, obs: TensorDict) -> tuple[TensorDict, dict]:
        """One iteration: the rollout (``_collect``), then PPO's update, timed apart; the last observations and the
        losses out."""
        self._clock.mark(0)
        with torch.inference_mode():
            obs = self._collect(obs)
        self._clock.mark(1)
        loss_dict = self.alg.update()
        self._clock.mark(2)
        return obs, loss_dict

    def release_graphs(self):
        """Free the captured rollout and update (``TorchGraph.release``: before the process group is destroyed);
        ``learn`` captures them again."""
        if self._rollout_graph is not None:
            self._rollout_graph.release()
        if isinstance(self.alg, SyncFreePPO):
            self.alg.release_graph()

    def _rollout(self, obs: TensorDict) -> TensorDict:
        """One iteration's experience: ``num_steps_per_env`` x (act, env step, storage, episode statistics), then
        the returns; the last observations out. Only device work unless the console is rsl-rl's."""
        rsl_rl_console = self.train_cfg.console == "rsl_rl"
        for _ in range(self.cfg["num_steps_per_env"]):
            actions = self.alg.act(obs)
            obs, rewards, dones, extras = self.env.step(actions.to(self.env.device))
            obs, rewards, dones = obs.to(self.device), rewards.to(self.device), dones.to(self.device)
            self.alg.process_env_step(obs, rewards, dones, extras)
            self.episodes.add(dones.bool(), extras["episode_return"], extras["episode_length"], extras["time_outs"])
            if rsl_rl_console:
                self.logger.process_env_step(rewards, dones, extras)
        self.alg.compute_returns(obs)
        return obs

    def _collect(self, obs: TensorDict) -> TensorDict:
        """``_rollout``; on a GPU with ``cuda_graph``, run op by op the first time (which also makes the lazily
        allocated storage), captured the second time with the env's Warp kernels, replayed after."""
        if self._rollout_graph is None:
            return self._rollout(obs)
        if self._rollout_input is None:
            self._rollout_input = obs.clone()
        self._rollout_input.copy_(obs)
        return self._rollout_graph(lambda: self._rollout(self._rollout_input))

    def _end_of_iteration(self, it: int, loss_dict: dict):
        stats = self.episodes.pop(all_processes=self.is_distributed)
        collect_time, learn_time = self._clock.seconds()
        now = time.perf_counter()
        iteration_time = now - self._tick
        steps = self.env.num_envs * self.cfg["num_steps_per_env"] * self.gpu_world_size
        p = self.progress
        p.iterations, p.env_steps = it + 1, p.env_steps + steps
        judged = self._evaluate_if_due(it, stats)
        self._tick = time.perf_counter()
        evaluation = judged.summary if judged is not None else None
        solved = evaluation is not None and self.solved_rule(evaluation)
        p.train_time_s += self._tick - now + iteration_time
        record = {"iteration": it, "env_steps": p.env_steps, "train_time_s": round(p.train_time_s, 3),
                  **dataclasses.asdict(stats), "env_steps_per_s": steps / iteration_time,
                  "collection_ms": collect_time * 1e3, "learning_ms": learn_time * 1e3, "solved": solved}
        if judged is not None:
            record["evaluation"] = dataclasses.asdict(evaluation) | {"seconds": round(self._tick - now, 3)}
            if judged.iteration != it:
                record["evaluation"]["policy_iteration"] = judged.iteration
        p.history.append(record)
        if solved and p.solved_at is None:
            p.solved_at = {"iterations": judged.iteration + 1, "env_steps": judged.env_steps,
                           "train_time_s": round(p.train_time_s, 3),
                           self.play_metric: getattr(evaluation, self.play_metric)}
        if judged is not None:
            self._keep_if_best(judged, solved)
        if self.train_cfg.console == "rsl_rl":
            self.logger.log(it=it, start_it=self._first_iteration, total_it=self._end_iteration,
                            collect_time=collect_time, learn_time=learn_time, loss_dict=loss_dict,
                            learning_rate=self.alg.learning_rate, action_std=self.action_std,
                            rnd_weight=None)
        elif self.gpu_global_rank == 0:
            if self.logger.writer is not None:
                scalars = metrics(stats, evaluation, loss_dict, self.alg.learning_rate,
                                  self.action_std.mean().item(), steps / iteration_time, collect_time,
                                  learn_time)
                for tag, value in scalars.items():  # an evaluation at the iteration of the policy it judged
                    self.logger.writer.add_scalar(tag, value, judged.iteration if tag.startswith("Eval/") else it)
            print(self.progress_line(it, self._first_iteration, self._end_iteration, stats, steps / iteration_time,
                                     evaluation, solved, self._eta_s(it), judged and judged.iteration), flush=True)
        if self.on_iteration is not None and self.gpu_global_rank == 0:
            self.on_iteration(it, stats)
        wanted = self._stop_requested or ("solved" if solved and self.train_cfg.stop_when_solved else None)
        self.stop_reason = joint_stop(wanted, self.device, self.is_distributed)

    def _evaluation_due(self, it: int, stats: EpisodeSummary) -> bool:
        """Whether the policy after iteration ``it`` is to be evaluated (``eval.min_interval``, ``max_interval``)."""
        since = it - self._last_eval_iteration
        limits = self.train_cfg.eval
        return since >= limits.max_interval or (since >= limits.min_interval and self.solved_rule(stats))

    def _evaluate_if_due(self, it: int, stats: EpisodeSummary) -> Judged | None:
        """The verdict of an evaluation after iteration ``it``: on ``eval_env``, of the policy after ``it`` where one is
        due; in the step, of the policy it froze, where its episodes are over (one is begun where it is due and none
        runs). None otherwise, and always without an evaluation."""
        if self.in_step is not None:
            return self._in_step_verdict(it, stats)
        if self.eval_env is None or not self._evaluation_due(it, stats):
            return None
        self._last_eval_iteration = it
        self.prepare_evaluation()
        self.alg.eval_mode()
        try:
            return Judged(evaluate(self._evaluation, self.train_cfg.env.seed, self.solved_rule), it,
                          self.progress.env_steps)
        finally:
            self.alg.train_mode()

    def _in_step_verdict(self, it: int, stats: EpisodeSummary) -> Judged | None:
        """``_evaluate_if_due`` for the evaluation inside the step."""
        judged = None
        if self.in_step.running:
            summary = self.in_step.verdict(self.cfg["num_steps_per_env"], self.solved_rule)
            if summary is not None:
                judged = Judged(summary, *self._in_step_policy)
        if not self.in_step.running and self._evaluation_due(it, stats):
            self._last_eval_iteration = it
            self._frozen_actor.load_state_dict(self.alg.get_policy().state_dict())
            self._in_step_policy = (it, self.progress.env_steps, copy.deepcopy(self._state_dict()))
            self.in_step.begin()
        return judged

    def prepare_evaluation(self):
        """Make the evaluation's run of the policy on ``eval_env`` (on a GPU: capture its CUDA graph) if not made yet;
        ``Training`` calls it while setting up, so that the first evaluation costs no capture."""
        if self.eval_env is not None and self._evaluation is None:
            self._evaluation = FirstEpisodesRun(self.eval_env, self.policy())
            self.alg.train_mode()

    def _keep_if_best(self, judged: Judged, solved: bool):
        """Save the judged policy as ``model_best.pt`` where its evaluation beats the best so far (solved first, then
        the play metric)."""
        score = (solved, getattr(judged.summary, self.play_metric) or 0.0)
        best = self.progress.best
        if best is not None and score <= (best["solved"], best[self.play_metric] or 0.0):
            return
        self.progress.best = {"iteration": judged.iteration, "solved": solved, self.play_metric: score[1]}
        if self.run_dir is not None:
            if judged.state is None:
                self.save(str(self.run_dir / BEST_CHECKPOINT))
            else:  # an earlier policy: resuming from it continues its progress, verdicts included
                self._write(str(self.run_dir / BEST_CHECKPOINT), judged.state, judged.iteration,
                            self._progress_at(judged.iteration))

    def _progress_at(self, iteration: int) -> dict:
        """The progress as it stood after ``iteration`` (a checkpoint's ``infos``), with the verdicts since."""
        history = [h for h in self.progress.history if h["iteration"] <= iteration]
        return dict(dataclasses.asdict(self.progress), iterations=iteration + 1, env_steps=history[-1]["env_steps"],
                    train_time_s=history[-1]["train_time_s"], history=history)

    def _eta_s(self, it: int) -> float:
        """``eta_s`` after iteration ``it``: the evaluations due are the periodic ones (``eval.max_interval``)."""
        left = self._end_iteration - it - 1
        evaluations = [h["evaluation"]["seconds"] for h in self.progress.history
                       if h["iteration"] >= self._first_iteration and "evaluation" in h]
        due = (self._end_iteration - 1 - self._last_eval_iteration) // self.train_cfg.eval.max_interval
        evaluates = self.eval_env is not None or self.in_step is not None
        return eta_s(time.perf_counter() - self._start, evaluations, it + 1 - self._first_iteration, left,
                     due if evaluates else 0)

    def save(self, path: str, infos: dict | None = None) -> None:
        """Write the models, optimizer, iteration and progress to ``path`` atomically."""
        self._write(path, self._state_dict(), self.current_learning_iteration, infos)

    def _write(self, path: str, state: dict, iteration: int, infos: dict | None = None):
        """``save`` of ``state`` (``_state_dict``'s) as the checkpoint of ``iteration``."""
        saved = dict(state, iter=iteration, infos=infos if infos is not None else dataclasses.asdict(self.progress))
        atomic_write(Path(path), lambda tmp: torch.save(saved, tmp))
        self.logger.save_model(path, iteration)

    def load(self, path: str, load_cfg: dict | None = None, strict: bool = True,
             map_location: str | None = None) -> dict:
        """Load a checkpoint (RunError naming the file if it is unreadable or does not fit); return its progress.
        Where ``load_cfg`` loads the iteration (the default: resuming) training continues after it with the
        checkpoint's progress; otherwise (e.g. ``{"actor": True}``: the best policy, to export) the run's own progress
        stays."""
        loaded = read_checkpoint(path, map_location or self.device)
        with networks_must_fit(path):
            self._load_state_dict(loaded, load_cfg, strict)
        infos = loaded.get("infos") or {}
        if load_cfg is None or load_cfg.get("iteration"):
            self.current_learning_iteration = loaded["iter"] + 1
            self.progress = Progress(**{f.name: infos[f.name] for f in dataclasses.fields(Progress)
                                        if f.name in infos})
        return infos

    @property
    def action_std(self) -> torch.Tensor:
        """The standard deviation of the training's actions, per action."""
        return self.alg.get_policy().output_std

    def _state_dict(self) -> dict:
        """What a checkpoint holds besides the iteration and the progress: rsl-rl's networks and optimizer."""
        return self.alg.save()

    def _load_state_dict(self, loaded: dict, load_cfg: dict | None, strict: bool):
        """Load what ``_state_dict`` saved (``load_cfg``: rsl-rl's choice of parts; None: all)."""
        self.alg.load(loaded, load_cfg, strict)

    def policy(self) -> Policy:
        """The deterministic policy (the Gaussian's mean)."""
        return deterministic(self.get_inference_policy(self.device))

    def export(self, out_dir: Path) -> list[Path]:
        """The actor's exports in ``out_dir`` (``policies.export_policy``)."""
        return export_policy(self.alg.get_policy(), out_dir)

_renamed = renamed(__name__, {"CartpoleRunner": "TaskRunner"})
_moved = moved_names(__name__, f"{__package__}.policies")


def __getattr__(name: str) -> object:
    """The old names (``CartpoleRunner``) and the policy functions that lived here (``load_policy``, ``to_rsl_rl``,
    ...: now in ``rl.policies``), for one more release."""
    return _renamed(name) if name == "CartpoleRunner" else _moved(name)
