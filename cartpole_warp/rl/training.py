"""A training end to end, of one run or of a population's (``--seeds``: K runs of one task in one process, on one
batched env, ``rl.population``): the env, learner and ``TrainingLoop`` built from a ``TrainConfig``, Ctrl-C handling,
and each run folder's artefacts (config, checkpoints, exports, learning curve, ``summary.json``), and a population's
own files (``members.md``, ``population.json``).

    training = Training(cfg, run_dir)            # builds the env (compiles Warp kernels on first use)
    summary = training.run()                     # Ctrl-C ends after the current iteration, saved
    result = Training(cfg, run_dir, members=members_of([0, 1, 2])).run()    # members in run_dir/seed0, ...
"""

from __future__ import annotations

import dataclasses
import importlib.util
import signal
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import torch

from ..engine import camera
from ..engine.runtime import free_memory_bytes, resolve_device, timed
from ..evaluation.in_step import InStepEvaluation
from ..settings.config import ConfigError, EnvConfig
from ..wrappers.rsl_rl import RslRlVecEnv
from .config import TrainConfig
from .distributed import SINGLE_PROCESS, Ranks, from_rank_zero, join_process_group
from .learners import learner_class
from .learners.batched_ppo.learner import BatchedPpoLearner, Member
from .loop import PopulationMode, TrainingLoop
from .modes import check_modes
from .policies import to_rsl_rl
from .population import check_population, write_population
from .record import solved_definition
from .runs import RunSummary, save_config

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


def check_memory(cfg: TrainConfig, device: str, members: int = 0):
    """ConfigError in one line, with the estimate (``bytes_per_env``), where ``cfg.env.num_envs`` envs of one run (and
    the evaluation's inside the step, ``eval.in_step``, counted as training envs), or of each of a population's
    ``members`` (with its evaluation's envs), would not fit in the free memory of the host or of ``device``, before
    anything is allocated."""
    n, evaluation_envs = cfg.env.num_envs, cfg.eval.num_envs if cfg.eval.in_step or members else 0
    for where, need_per_env in bytes_per_env_by_place(cfg, device).items():
        per_run = (n + evaluation_envs) * need_per_env
        need, free = max(members, 1) * per_run, free_memory_bytes(where)
        if need > free and members:
            raise ConfigError(f"a population of {members} members x {n:,} envs of {cfg.task} needs about "
                              f"{need / 1e9:,.1f} GB on {where} (with {evaluation_envs} evaluation envs each); it has "
                              f"{free / 1e9:,.1f} GB free: at most ~{free // per_run} members of {n:,} envs (fewer "
                              "--seeds or --num-envs)")
        if need > free:
            frames = ", the camera's frames" if cfg.env.camera.enabled else ""
            raise ConfigError(
                f"training {n:,} envs of {cfg.task} needs about {need / 1e9:,.1f} GB on {where} "
                f"({need_per_env / 1e3:,.1f} kB per env: the scene{frames} and rsl-rl's storage of "
                f"{cfg.agent.num_steps_per_env} steps per env); {where} has {free / 1e9:,.1f} GB free: use at most "
                f"~{free // need_per_env - evaluation_envs:,} envs (--num-envs) or fewer --agent.num-steps-per-env")


class Interrupts:
    """SIGINT and SIGTERM (which torchrun sends its processes) while a training runs, as a context: the first calls
    ``stop`` (training ends after the iteration in progress, which is saved) and ``say``s so; a second
    aborts (KeyboardInterrupt, nothing saved); once ``finishing`` (training has ended, the run's files are being
    written) a signal waits for them, saying so. Only the main thread receives signals: a training in another thread
    (a Ray Tune trial's, ``tools.tune``) is stopped by its caller (``TrainingLoop.request_stop``)."""

    def __init__(self, stop: Callable[[], None], say: Callable[[str], None], stopping: str):
        self.stop, self.say, self.stopping = stop, say, stopping
        self.count, self.finishing = 0, False
        self._previous: dict = {}

    def __enter__(self) -> Interrupts:
        if threading.current_thread() is threading.main_thread():  # Python's rule; elsewhere the caller stops it
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


class Training:
    """A training in ``run_dir`` (created, with its ``config.yaml``, only once the env is built and a checkpoint to
    resume from is loaded): one run, or with ``members`` a population's, member k training on envs [k N, (k+1) N) of
    one env of K x N envs (N = ``env.num_envs``) and writing an ordinary run folder, ``run_dir / member.name``. In a
    torchrun job (``ranks``) a run's processes each train its own envs on their own GPU with seed + rank, and rank 0
    alone writes the run folder; a population's each train their share of the members, in rank 0's ``run_dir``.
    ``modes``: a population's (``rl.modes``): until its first solved member (whose policy its folder then holds:
    ``runs.copy_policy``), population-based training. ``before_build`` is called once the training is checked
    (ConfigError where it cannot run or would not fit), before its envs are built; ``setup_time_s`` counts from
    there."""

    def __init__(self, cfg: TrainConfig, run_dir: Path, resume_from: Path | None = None,
                 ranks: Ranks = SINGLE_PROCESS, timing_s: dict[str, float] | None = None,
                 members: Sequence[Member] = (), modes: Sequence[PopulationMode] = (),
                 before_build: Callable[[], None] | None = None):
        self.cfg, self.ranks = cfg.validate(), ranks
        if cfg.agent.logger == "wandb" and importlib.util.find_spec("wandb") is None:
            raise ConfigError("--logger wandb needs the wandb package: pip install wandb (and wandb login)")
        self.prefix = f"rank {ranks.rank}: " if members and ranks.distributed else ""
        """Before each console line of a population's process."""
        if members and resume_from is not None:
            raise ConfigError("a population starts afresh; resume one member's run folder instead")
        check_modes(modes, len(members), ranks.distributed)
        self.all_members, self.members = list(members), ranks.share(list(members)) if members else []
        env_cfg = self._process_env_config()
        self.run_dir = Path(from_rank_zero(Path(run_dir), ranks) if members else run_dir)
        if before_build is not None:
            before_build()
        start = time.perf_counter()
        torch.manual_seed(env_cfg.seed)
        cfg.apply_torch_threads()
        self.task = cfg.task_spec
        self.env = self._build_env(env_cfg)
        self.timing_s = (timing_s if timing_s is not None else {}) | self.env.env.build_time_s
        """Where the training's seconds went, by phase (after those of ``timing_s``, e.g. train.py's); each
        summary.json keeps them."""
        self.loop = self._build_loop(env_cfg, modes)
        with timed(self.timing_s, "eval_env"):
            self.loop.evaluations.prepare()
            if resume_from is not None:
                self.loop.records[0].load(resume_from)
            for record, config in zip(self.loop.records, [m.config(self.cfg) for m in self.members] or [cfg]):
                if record.run_dir is not None:
                    save_config(record.run_dir, config)
        self.setup_time_s = time.perf_counter() - start

    def _process_env_config(self) -> EnvConfig:
        """This process's env config, once the training is checked (ConfigError where it cannot run or would not fit
        in memory): the learner's (``Learner.env_config``) of a run; a population's on this process's device (its
        process group joined), judged on envs of its own where the task evaluates inside the step (``eval.in_step``:
        a task's GPU default for long runs, made for one run's envs: ``cfg`` says so)."""
        cfg, ranks = self.cfg, self.ranks
        if not self.members:
            env_cfg = learner_class(cfg.agent.learner).env_config(cfg, ranks.env_config(cfg.env,
                                                                                         torch.cuda.device_count()),
                                                                  ranks)
            check_memory(dataclasses.replace(cfg, env=env_cfg), resolve_device(env_cfg.device))
            return env_cfg
        if cfg.eval.in_step:
            print(f"{self.prefix}note: a population judges its members on envs of their own, not inside the "
                  "training's step (eval.in_step)", flush=True)
            cfg = dataclasses.replace(cfg, eval=dataclasses.replace(cfg.eval, in_step=False))
        check_population(cfg)
        device = resolve_device(ranks.device(cfg.env.device, torch.cuda.device_count()))
        self.cfg = cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, device=device))
        check_memory(cfg, device, len(self.members))
        join_process_group(ranks, device, backend="gloo")
        return cfg.env

    def _build_env(self, env_cfg: EnvConfig) -> RslRlVecEnv:
        """The training's env: a run's envs (and the evaluation's, where it runs inside the step, on the process that
        writes), or the members' blocks, each restarted as a solo run of its seed starts them."""
        members = self.members
        in_step = self.cfg.eval.in_step and self.ranks.writes  # the process that writes the run evaluates
        extra = self.cfg.eval.num_envs if in_step else 0
        n = env_cfg.num_envs
        batched = self.task.env_class(dataclasses.replace(env_cfg, num_envs=max(1, len(members)) * n + extra))
        for k, member in enumerate(members):
            batched.restart(k * n, (k + 1) * n, member.seed)
        return RslRlVecEnv(batched, InStepEvaluation(batched, extra, self.cfg.env.seed) if in_step else None)

    def _build_loop(self, env_cfg: EnvConfig, modes: Sequence[PopulationMode]) -> TrainingLoop:
        """The learner (a population's built here, before its evaluation envs), the evaluation's envs (where they are
        envs of their own, in a process that judges), the loop."""
        cfg, env, members = self.cfg, self.env, self.members
        learner = None
        if members:
            with timed(self.timing_s, "networks"):
                rsl_rl_cfg = to_rsl_rl(cfg.agent, mirror=env.obs_mirror is not None, images=env.images)
                learner = BatchedPpoLearner(env, [member.config(cfg) for member in members], rsl_rl_cfg,
                                            cfg.env.seed)
        eval_env = None
        if (members or self.ranks.writes) and env.evaluation is None:
            with timed(self.timing_s, "eval_env"):
                eval_env = self.task.env_class(dataclasses.replace(
                    env_cfg, num_envs=max(1, len(members)) * cfg.eval.num_envs, seed=cfg.env.seed))
        with timed(self.timing_s, "networks"):
            return TrainingLoop(env, dataclasses.replace(cfg, env=env_cfg),
                                self.run_dir if members or self.ranks.writes else None, eval_env, learner,
                                SINGLE_PROCESS if members else self.ranks, members, self.prefix, modes)

    @property
    def solved_definition(self) -> str:
        """The task's solved rule and what it judges, in words."""
        return solved_definition(self.cfg)

    @property
    def max_episode_length(self) -> int:
        """The env's time limit in env steps."""
        return self.env.max_episode_length

    @property
    def interrupted(self) -> bool:
        """Whether a signal stopped the training (``run``): this process's, for a population; a run's, in any of its
        processes (its stop decision)."""
        if self.members:
            return self.loop.stop_requested == "interrupted"
        return self.loop.records[0].stop_reason == "interrupted"

    def run(self) -> RunSummary | dict | None:
        """Train ``agent.max_iterations`` iterations (each run fewer on Ctrl-C or SIGTERM, which torchrun sends its
        processes, non-finite networks or, with stop_when_solved, once solved); then each run folder's end
        (``RunRecord.summarize``: the exports of the policy play.py plays, the learning curve, ``summary.json``). A
        run's summary out (None in the processes that do not write), or a population's table (``population.json``'s,
        which every process returns). A signal once training has ended waits until the files are written."""
        def say(line: str):  # on a line of its own, after the terminal's ^C
            if self.ranks.writes or self.members:
                print(f"\n{self.prefix}{line}", flush=True)

        records = self.loop.records
        stopping = "stopping every member" if self.members else "stopping"
        with Interrupts(lambda: self.loop.request_stop("interrupted"), say, stopping) as interrupts:
            trained_before_s, start = records[0].progress.train_time_s, time.perf_counter()  # a resumed run's
            try:
                self.loop.learn(self.cfg.agent.max_iterations, self.cfg.agent.init_at_random_ep_len)
            finally:
                interrupts.finishing = True
                self.loop.release_graphs()
            train_time_s = time.perf_counter() - start
            if not self.members:
                return (records[0].summarize(self.timing_s, self.setup_time_s, trained_before_s,
                                             self.ranks.world_size) if self.ranks.writes else None)
            summaries = [record.summarize(dict(self.timing_s), self.setup_time_s) for record in records]
            return write_population(self.loop, summaries, self.run_dir, self.ranks, train_time_s, self.setup_time_s)
