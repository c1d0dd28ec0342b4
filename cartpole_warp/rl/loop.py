"""``TrainingLoop``: the one training loop, of one run or K (a population's members) trained at once by one learner
(``rl.learners``), for any task.

    loop = TrainingLoop(RslRlVecEnv(cfg.task_spec.env_class(cfg.env)), cfg, log_dir)
    loop.learn(cfg.agent.max_iterations)       # loop.request_stop() ends it after the current iteration
    loop.records[0].progress                   # the run's books (rl.record.RunRecord)

After each of the learner's iterations (act, step, learn of every member still training): its figures per member
(``Learner.read``), the evaluations' verdicts (``rl.evaluations``), then each member's books: progress, verdict,
metrics and console line, stop decision, checkpoints. A member whose run stops (solved with ``stop_when_solved``,
non-finite networks, a stop request) is retired from the learner; the others go on.
"""

from __future__ import annotations

from ..wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
import functools
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import torch
from tensordict import TensorDict

from ..engine.env import BatchedEnv
from ..evaluation.statistics import EpisodeStats, EpisodeSummary
from ..settings.deprecation import renamed
from ..wrappers.rsl_rl import RslRlVecEnv
from .config import TrainConfig
from .distributed import SINGLE_PROCESS, Ranks, join_process_group
from .evaluations import Evaluations
from .learners import Learner, Readout, learner_class
from .policies import to_rsl_rl
from .progress import Pace, population_lines
from .record import RunRecord

if TYPE_CHECKING:
    from .learners.batched_ppo.learner import Member


class PopulationMode(Protocol):
    """A population's mode (``rl.modes``), called after each iteration's books: ``after_iteration`` gives the members
    still running; at the end ``annotate`` adds its entries to the members' rows (in place) and gives the
    population's (``population.json``); ``describe`` says what it does, in words."""

    def after_iteration(self, loop: TrainingLoop, it: int, running: list[int]) -> list[int]: ...
    def annotate(self, loop: TrainingLoop, rows: list[dict]) -> dict: ...
    def describe(self) -> str: ...


class TrainingLoop:
    """The training of ``cfg`` on ``env``: one run (``members`` empty; by ``learner``, default: ``cfg.agent.learner``'s,
    built here; ``ranks``: the processes it spans, default torchrun's), or one run per member of ``members`` by
    ``learner`` (a population's, member k on block k of ``env``; the members' runs span this process alone; ValueError
    where the learner trains another number of members). ``log_dir`` None
    writes nothing; else the run's folder, or the folder of the members' (``log_dir / member.name``). Evaluations run
    on ``eval_env`` (K blocks for K members) or, where ``env`` carries an ``InStepEvaluation`` (``eval.in_step``),
    inside the training's step. ``rsl_rl_cfg`` is rsl-rl's ``train_cfg`` dict of ``cfg``; ``prefix`` comes before
    each of the loop's own console lines. ``modes``: a population's (``rl.modes``: until its first solved member,
    population-based training), called in order after each iteration's books."""

    def __init__(self, env: RslRlVecEnv, cfg: TrainConfig, log_dir: Path | None, eval_env: BatchedEnv | None = None,
                 learner: Learner | None = None, ranks: Ranks | None = None, members: Sequence[Member] = (),
                 prefix: str = "", modes: Sequence[PopulationMode] = ()):
        self.env, self.config, self.device = env, cfg, env.device
        self.ranks = ranks if ranks is not None else SINGLE_PROCESS if members else Ranks.from_environment()
        rsl_rl = functools.partial(to_rsl_rl, mirror=env.obs_mirror is not None, images=env.images)
        self.rsl_rl_cfg = rsl_rl(cfg.agent)
        if learner is None:
            self.rsl_rl_cfg["multi_gpu"] = join_process_group(self.ranks, self.device)
            learner = learner_class(cfg.agent.learner)(env, cfg, self.rsl_rl_cfg,
                                                       EpisodeStats(env.device, env.max_episode_length))
        self.learner = learner
        runs = ([(member.config(cfg), None if log_dir is None else Path(log_dir) / member.name) for member in members]
                or [(cfg, log_dir)])
        if learner.num_members != len(runs):
            raise ValueError(f"a learner of {learner.num_members} members cannot train {len(runs)} runs")
        self.evaluations = Evaluations(cfg, learner, [config.env.seed for config, _ in runs], eval_env, env.evaluation)
        self.records = [RunRecord(config, learner, k, env, run_dir,
                                  rsl_rl(config.agent) if members else self.rsl_rl_cfg,  # a member's own settings
                                  self.ranks, self.evaluations) for k, (config, run_dir) in enumerate(runs)]
        self.members = list(members)
        self.prefix = prefix
        for record in self.records:
            record.report.console = not members  # a population prints its own line
        if cfg.console == "rsl_rl":
            learner.on_step = self.records[0].logger.process_env_step
        self._stop_requested: str | None = None
        self._span = (0, 0)
        self.iteration_s: list[float] = []
        """Each iteration's wall seconds, its evaluations, books and lines included."""
        self.evaluation_s = 0.0  # the seconds in the evaluations' judge
        self.modes = list(modes)
        self.on_iteration: Callable[[int, EpisodeSummary], None] | None = None
        """Called after each iteration's console line (by the process that writes) with the iteration and the first
        member's episodes' summary (the browser viewer's and ``--video``'s hook)."""

    @property
    def stop_requested(self) -> str | None:
        """The reason of a pending ``request_stop`` (None: none)."""
        return self._stop_requested

    def request_stop(self, reason: str = "interrupted"):
        """End every run after the iteration in progress (which is saved); in a torchrun job every process stops after
        that same iteration."""
        self._stop_requested = reason

    def learn(self, num_learning_iterations: int, init_at_random_ep_len: bool = False) -> None:
        """``num_learning_iterations`` iterations of the runs still going (a run that has stopped stays stopped), each
        ending early on a stop request, non-finite networks or, with ``stop_when_solved``, once solved. Non-finite
        states never reach the learner (the env resets them), so there is no per-step NaN check; episode statistics
        stay on the device until the iteration ends."""
        if not (running := [k for k, record in enumerate(self.records) if record.stop_reason is None]):
            return
        self._span = (first := self.records[running[0]].next_iteration, first + num_learning_iterations)
        obs = self._start(running, init_at_random_ep_len)
        tick = time.perf_counter()
        for it in range(*self._span):
            obs, losses = self.learner.iteration(obs, it)
            running = self._after_iteration(it, self.learner.read(losses), running)
            self.iteration_s.append(time.perf_counter() - tick)
            tick = time.perf_counter()
            if not running:
                break
        for k in running:
            self.records[k].finish()

    def _start(self, running: list[int], init_at_random_ep_len: bool) -> TensorDict:
        """The ``running`` runs' start: each member's time-out counters at random steps where asked (block by block,
        as its own run would draw them); the env's observations out."""
        first, end = self._span
        if init_at_random_ep_len:
            high = int(self.env.max_episode_length)
            blocks = self.env.episode_length_buf.chunk(len(self.records))
            self.env.episode_length_buf = torch.cat([torch.randint_like(block, high=high) for block in blocks])
        self.learner.begin(first, end)
        for k in running:
            self.records[k].start(first, end, init_at_random_ep_len)
        self.evaluations.last_iteration = [first - 1] * len(self.records)
        self._start_s = self._tick = time.perf_counter()
        return self.env.get_observations().to(self.device)

    def _after_iteration(self, it: int, readout: Readout, running: list[int]) -> list[int]:
        """The books of iteration ``it`` (the learner's ``readout``) of the ``running`` members; those still
        running out."""
        now = time.perf_counter()
        steps = self.env.num_envs // len(self.records) * self.rsl_rl_cfg["num_steps_per_env"] * self.ranks.world_size
        pace = Pace(steps / (now - self._tick), *self.learner.clock.seconds())
        sound = [k for k in running if not readout.nonfinite[k]]
        env_steps = {k: self.records[k].count(it, steps) for k in sound}
        verdicts = self.evaluations.judge(it, readout.episodes, sound, [env_steps.get(k, 0) for k in
                                                                         range(len(self.records))])
        done = time.perf_counter()
        timing, self._tick = (done - self._tick, done - now, self._start_s), done
        self.evaluation_s += done - now
        for k in running:
            if readout.nonfinite[k]:
                self.records[k].stop_nonfinite(it)
                others = ", the others go on" if len(running) > 1 else ""
                print(f"{self.prefix}  {self.members[k].name if self.members else 'the run'}: its networks went "
                      f"non-finite in iteration {it + 1}; it ends here{others}", flush=True)
            else:
                self.records[k].after_iteration(it, readout.episodes[k], readout.losses[k], readout.learning_rates[k],
                                                readout.action_std[k], pace, verdicts.get(k), timing,
                                                self._stop_requested)
        still = running
        for mode in self.modes:
            still = mode.after_iteration(self, it, still)
        still = [k for k in still if self.records[k].stop_reason is None]
        if self.members:
            self._population_lines(it, verdicts, still)
        if self.on_iteration is not None and self.ranks.writes:
            self.on_iteration(it, readout.episodes[0])
        for k in running:
            if k not in still:  # after the hook: a clip of the last iteration reaches its writer
                self.learner.retire(k)
                self.records[k].finish()
        return still

    def _population_lines(self, it: int, verdicts: dict, running: list[int]):
        """A population's console (``progress.population_lines``)."""
        lines = population_lines(self.config.task_spec.play_metric, [member.name for member in self.members],
                                 [record.progress for record in self.records],
                                 {k: judged.iteration for k, judged in verdicts.items()}, running, (it, *self._span),
                                 time.perf_counter() - self._start_s,
                                 self.env.num_envs * self.rsl_rl_cfg["num_steps_per_env"])
        for line in lines:
            print(self.prefix + line, flush=True)

    def release_graphs(self):
        """Free the learner's captured graphs (before the process group is destroyed); ``learn`` captures again."""
        self.learner.release_graphs()


__getattr__ = renamed(__name__, {"TaskRunner": "TrainingLoop", "CartpoleRunner": "TrainingLoop"})
"""The loop's names while it was one run's (``TaskRunner``, before it ``CartpoleRunner``), until
``settings.deprecation.REMOVED_IN``."""
