"""Train a task on the batched Warp/Newton env with rsl-rl PPO, or by analytic policy gradients through the simulator.

    python train.py --num-envs 4096 --device cpu          # cartpole-balance, a run in logs/rsl_rl/cartpole-balance/
    python train.py --task cartpole-swingup               # another registered task (listed below)
    python train.py --resume                              # continue the newest run from its last checkpoint
    python train.py --config tutorial                     # a preset (configs/*.yaml) as the starting point
    python train.py --learner shac                        # backpropagation through the simulator (its own defaults)
    python train.py --agent.algorithm.entropy-coef 0.01   # any config field is a flag; --help-all lists them all
    torchrun --nproc_per_node=2 train.py --device cuda --num-envs 4096   # 2 GPUs, 4096 envs on each

Each run folder holds config.yaml, model_<iteration>.pt, TensorBoard events, exported/policy.{onnx,pt}, the curve and
summary.json. Ctrl-C stops after the current iteration and saves. Also installed as ``python -m cartpole_warp.train``.
"""

from __future__ import annotations

import functools
import gc
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Generic, Literal

import tyro

from . import tasks
from .cli import (
    ENV_ALIASES,
    ViserArgs,
    asks_help,
    clean_errors,
    expand_aliases,
    flags_named,
    parse,
    peek,
    process_age_s,
    quiet_libraries,
    renamed_flags,
    renamed_values,
    with_default_value,
)
from .engine.runtime import NO_CUDA, timed
from .engine.scene import StageError
from .rl.config import (
    TrainConfig,
    checked,
    chosen_settings,
    device_defaults,
    device_settings,
    learner_settings,
    on_gpu,
    train_config,
)
from .rl.distributed import Ranks
from .rl.learners import LEARNERS
from .rl.runs import (
    BEST_CHECKPOINT,
    MEMBERS_FILE,
    RunError,
    find_checkpoint,
    latest_checkpoint,
    latest_run,
    load_config,
    new_run_dir,
)
from .settings.agent import RENAMED_LEARNERS
from .settings.config import ConfigError, TaskT, require
from .settings.files import unwritable
from .settings.presets import presets


@dataclass
class PopulationArgs:
    seeds: list[int] = field(default_factory=list)
    """A population: one run per seed, at once (under torchrun spread over the processes; docs/training.md). Its
    members share one env of members x num_envs envs and one batched PPO; each writes an ordinary run folder under the
    population's."""
    vary: list[str] = field(default_factory=list)
    """--seeds: settings the members differ in, name=value1,value2: one member per combination and seed (PPO's
    learning-rate, entropy-coef, gamma, lam, clip-param, desired-kl, value-loss-coef, max-grad-norm), e.g.
    agent.algorithm.learning-rate=1e-3,3e-4."""
    until: Literal["each-solved", "first-solved"] = "each-solved"
    """--seeds: 'each-solved' trains every member to its own verdict (or --max-iterations); 'first-solved' ends the
    population in the iteration its first member is judged solved (the others stop, status 'outdone'), and its folder
    then holds that member's policy: config.yaml, model_best.pt and the exports, which play.py --run plays (one
    process: not under torchrun)."""
    exploit_interval: int | None = None
    """--seeds: population-based training every N iterations (none if left out; one process: not under torchrun).
    The members still training are ranked (by their latest evaluations' play metric where all have one that recent,
    else their training return); each of the bottom --population.exploit-fraction takes the whole state of one of the
    top (networks, optimiser, normalisers, settings) and perturbs its settings. Its lineage: members.md and its
    folder's lineage.json."""
    exploit_fraction: float | None = None
    """--population.exploit-interval: the share of members that take a top one's state, and of those they take from
    (at least one, at most half; None: 0.25)."""
    perturb: list[str] = field(default_factory=list)
    """--population.exploit-interval: the settings perturbed after an exploit (empty: every one --population.vary
    takes, but the learning rate under the adaptive schedule and desired-kl under the fixed one)."""
    perturb_factor: float | None = None
    """--population.exploit-interval: each perturbed setting is scaled by this or its inverse, at random (gamma and
    lam: their horizon, 1 - value; None: 1.2)."""

    def pbt_flags(self) -> list[str]:
        """The population-based training flags given (``--population.exploit-interval`` and those it takes)."""
        given = {"--population.exploit-interval": self.exploit_interval, "--population.exploit-fraction":
                 self.exploit_fraction, "--population.perturb": self.perturb or None,
                 "--population.perturb-factor": self.perturb_factor}
        return [flag for flag, value in given.items() if value is not None]

    def modes(self, seed: int) -> list:
        """The population's modes (``rl.modes``) these flags ask for, drawing from ``seed``; ConfigError in one line
        for a bad value or an exploit's flag without --population.exploit-interval."""
        from .rl.modes import Exploitation, UntilFirstSolved

        require(self.exploit_interval is not None or not self.pbt_flags(),
                f"{', '.join(self.pbt_flags())} set population-based training: give --population.exploit-interval N "
                "too")
        modes = [UntilFirstSolved()] if self.until == "first-solved" else []
        if self.exploit_interval is not None:
            given = {"fraction": self.exploit_fraction, "factor": self.perturb_factor}
            modes.append(Exploitation(self.exploit_interval, perturb=tuple(self.perturb), seed=seed,
                                      **{name: value for name, value in given.items() if value is not None}))
        return modes


@dataclass
class TrainArgs(Generic[TaskT]):
    cfg: Annotated[TrainConfig[TaskT], tyro.conf.arg(name="")]
    config: Annotated[str | None, tyro.conf.arg(help=(
        f"Preset in configs/ ({', '.join(presets())}) or a YAML file. "
        "Precedence: dataclass defaults < the task's defaults < preset (or a resumed run's config.yaml) < flags."
    ))] = None
    resume: str | None = None
    """Continue a run in place from its last checkpoint: a run folder, or 'latest' (a bare --resume) for the newest
    run under --log-dir. The run's config.yaml is the starting point; flags still override it."""
    checkpoint: Path | None = None
    """Continue from this checkpoint file, in its run folder (implies --resume)."""
    viewer: Literal["none", "viser"] = "none"
    """viser: watch the training envs in a browser (the viser extra), drawn between iterations in at most 1/21 of
    the wall time (nothing is imported or drawn without it)."""
    viewer_interval_s: float = 5.0
    """--viewer viser: seconds between the page's updates. Each update makes the browser redraw: a browser without a
    GPU, on the training's own cores, then slows training the more, the shorter this."""
    viser: Annotated[ViserArgs, tyro.conf.arg(name="")] = field(default_factory=ViserArgs)
    video: bool = False
    """A clip of the policy in <run>/videos/ every --video-interval iterations. The first iteration has one;
    MP4 with the video extra, else GIF, played on an env of its own; the logger shows where each one is."""
    video_length: int = 200
    """--video: env steps per clip."""
    video_interval: int = 50
    """--video: iterations between clips."""
    population: Annotated[PopulationArgs, tyro.conf.arg(name="population")] = field(default_factory=PopulationArgs)


class IterationHooks(list):
    """Several ``on_iteration`` callbacks (the browser view, the clips), called in order, closed together."""

    def __call__(self, it: int, summary) -> None:
        for hook in self:
            hook(it, summary)

    def close(self):
        for hook in self:
            hook.close()


ALIASES = ENV_ALIASES | {"--max-iterations": "--agent.max-iterations", "--run-name": "--agent.run-name",
                         "--logger": "--agent.logger", "--learner": "--agent.learner",
                         "--seeds": "--population.seeds"}
"""train.py's short flags."""
RENAMED_FLAGS = {"--algorithm": "--learner"} | {f"--agent.{old}.": f"--agent.{new}." for old, new in
                                                 RENAMED_LEARNERS.items()}
"""Old spellings still taken, with a warning, until ``settings.deprecation.REMOVED_IN`` (``--algorithm`` named the
learner while ``agent.algorithm`` is PPO's section; a renamed learner's section, ``--agent.apg.*``)."""
LEARNER_FLAGS = ("--learner", "--agent.learner")
"""The flags that name the learner, whose old names (``settings.agent.RENAMED_LEARNERS``) are taken as the new."""


def task_list() -> str:
    """The registered tasks, one line each, for --help."""
    width = max(map(len, tasks.names()))
    return "tasks (--task):\n" + "\n".join(f"    {name:<{width}}  {tasks.get(name).summary}" for name in tasks.names())


def default_notes(cfg: TrainConfig) -> dict[str, str]:
    """For --help, by short flag: that ``cfg.task`` and ``cfg.env.device`` are whose defaults it shows, which short
    flags' defaults another task or learner sets (compared over every registered task and every learner), and which
    settings the task chooses by device (``device_defaults``)."""
    def value(c: TrainConfig, flag: str) -> str:
        return repr(functools.reduce(getattr, flag.removeprefix("--").replace("-", "_").split("."), c))

    shown = {short: flag for short, flag in ALIASES.items()
             if short not in ("--device", "--learner") and flag.startswith(("--env.", "--agent."))}
    by_task = [train_config(name, None, cfg.env.device) for name in tasks.names()]
    by_learner = [train_config(cfg.task, None, cfg.env.device, learner) for learner in LEARNERS]
    other_device = "cuda" if cfg.env.device == "cpu" else "cpu"
    by_device = sorted(device_settings(cfg).keys() | chosen_settings(cfg, device_defaults(cfg.task_spec,
                                                                                          other_device)).keys())
    notes = {"--task": "the defaults shown are its own",
             "--device": f"{other_device} changes {', '.join(by_device)}" if by_device else ""}
    for short, flag in shown.items():
        setters = [by for by, configs in (("--task", by_task), ("--learner", by_learner))
                   if len({value(c, flag) for c in configs}) > 1]
        notes[short] = f"set by {' and '.join(setters)}" if setters else ""
    return {short: note for short, note in notes.items() if note}


def resolve(argv: list[str]) -> tuple[TrainConfig, Path, Path | None]:
    """(config, run folder, checkpoint to resume from or None) from the command line."""
    cfg, run_dir, checkpoint, _ = resolve_args(argv)
    return cfg, run_dir, checkpoint


def resolve_args(argv: list[str]) -> tuple[TrainConfig, Path, Path | None, TrainArgs]:
    """``resolve``, and the parsed arguments."""
    argv = renamed_values(renamed_flags(argv, RENAMED_FLAGS), LEARNER_FLAGS, RENAMED_LEARNERS)
    argv = with_default_value(argv, "--resume", "latest")
    first = peek(expand_aliases(argv, ALIASES), task=None, config=None, resume=None, checkpoint=None,
                 log_dir="logs", **{"agent.experiment_name": None, "env.device": None, "agent.learner": None})
    checkpoint = run_dir = None
    if (first.resume or first.checkpoint) and not asks_help(argv):
        if first.config:
            raise ConfigError("--config cannot change a resumed run; override its fields with flags instead")

        def newest_run() -> Path:
            experiment = getattr(first, "agent.experiment_name") or tasks.get(first.task or tasks.DEFAULT_TASK).name
            return latest_run(first.log_dir, experiment)

        resume = None if first.resume in (None, "latest") else first.resume
        checkpoint = find_checkpoint(first.checkpoint, resume, newest_run, latest_checkpoint, "--resume")
        run_dir = checkpoint.parent
        base = load_config(run_dir)
        if first.task and first.task != base.task:
            raise ConfigError(f"--task {first.task} cannot change the task of {run_dir} ({base.task})")
    else:
        base = train_config(first.task or tasks.DEFAULT_TASK, first.config, getattr(first, "env.device"),
                            getattr(first, "agent.learner"))
    cls = TrainArgs[type(base.env.task)]
    notes = default_notes(base) if asks_help(argv) else None
    args = parse(cls, cls(cfg=base, config=first.config), argv, f"{__doc__}\n{task_list()}", ALIASES, notes)
    require(args.cfg.task == base.task, "--task must come as one flag (it picks the task's settings)")
    require(args.viser.problem() is None, args.viser.problem())
    require(math.isfinite(args.viewer_interval_s) and args.viewer_interval_s >= 0,
            f"--viewer-interval-s must be finite and >= 0, got {args.viewer_interval_s}")
    require(args.video_length >= 1, f"--video-length must be >= 1, got {args.video_length}")
    require(args.video_interval >= 1, f"--video-interval must be >= 1, got {args.video_interval}")
    with flags_named(argv, ALIASES):
        cfg = checked(args.cfg).validate()
    run_dir = run_dir or new_run_dir(cfg.log_dir, cfg.experiment, cfg.agent.run_name)
    problem = unwritable(run_dir)
    require(problem is None, f"the run folder {run_dir} cannot be written: {problem}")
    return cfg, run_dir, checkpoint, args


def check_population_flags(args: TrainArgs, checkpoint: Path | None, ranks: Ranks) -> bool:
    """Whether the flags ask for a population (``--seeds``, ``--population.vary``); ConfigError where they ask for
    what one cannot do, or for a population's mode without one."""
    population = bool(args.population.seeds or args.population.vary)
    require(population or args.population.until != "first-solved",
            "--population.until first-solved ends a population: give --seeds")
    if not population and (pbt := args.population.pbt_flags()):
        raise ConfigError(f"{', '.join(pbt)}: population-based training trains a population: give --seeds")
    if population:
        require(checkpoint is None, "--seeds starts a population afresh; --resume one member's run folder instead")
        require(args.viewer == "none" and not args.video, "--seeds trains without --viewer or --video")
    return population


def check_browser_viewer(args: TrainArgs) -> None:
    """``--viewer viser``: ConfigError now, before the build, where the page could not be served."""
    from .viz.web import ViewerUnavailable, check_viser

    require(args.viser.host_problem() is None, args.viser.host_problem())
    try:
        check_viser()
    except ViewerUnavailable as err:
        raise ConfigError(str(err)) from None


def main(argv: list[str] | None = None) -> int:
    age = process_age_s() if argv is None else None
    timing_s = {"start": age} if age is not None else {}
    quiet_libraries()
    with clean_errors(ConfigError, RunError, StageError):
        with timed(timing_s, "config"):
            cfg, run_dir, checkpoint, args = resolve_args(sys.argv[1:] if argv is None else argv)
        code = train(cfg, run_dir, checkpoint, args, timing_s)
    if argv is None:
        gc.freeze()  # the interpreter's final collection of Newton's objects would delay the exit
    return code


def train(cfg: TrainConfig, run_dir: Path, checkpoint: Path | None, args: TrainArgs,
          timing_s: dict[str, float]) -> int:
    """The training in ``run_dir`` (over torchrun's processes, if any): one run, or with ``--seeds`` /
    ``--population.vary`` a population's (``rl.population``); 130 where interrupted."""
    ranks = Ranks.from_environment()
    population = check_population_flags(args, checkpoint, ranks)
    if args.viewer == "viser":
        check_browser_viewer(args)
    with timed(timing_s, "imports"):
        import torch

        from .rl.population import members_of
        from .rl.training import Training

    if not ranks.distributed and cfg.env.device != "cpu" and not torch.cuda.is_available():  # torchrun: per process
        raise ConfigError(NO_CUDA.format(cfg.env.device))
    members = members_of(args.population.seeds, args.population.vary) if population else []
    modes = args.population.modes(cfg.env.seed) if population else []

    def building():
        if ranks.writes:
            where = (f"{ranks.world_size} {'processes' if members else 'GPUs'}" if ranks.distributed
                     else cfg.env.device)
            print(f"building {f'{len(members)} members x ' if members else ''}{cfg.env.num_envs} envs on {where}...",
                  flush=True)

    training, result = None, None
    try:
        training = Training(cfg, run_dir, resume_from=checkpoint, ranks=ranks, timing_s=timing_s, members=members,
                            modes=modes, before_build=building)
        if ranks.writes:
            announce(training, args, training.run_dir, checkpoint)
        result = training.run()
    finally:
        if training is not None and training.loop.on_iteration is not None:
            training.loop.on_iteration.close()
        if torch.distributed.is_initialized():
            torch.distributed.destroy_process_group()
    if ranks.writes and members:  # the files are written: a Ctrl-C now only cuts these lines short
        report_population(result, training.run_dir)
    elif ranks.writes:
        report(result, training.run_dir, checkpoint, timing_s)
    return 130 if training.interrupted else 0


def announce(training, args: TrainArgs, run_dir: Path, checkpoint: Path | None):
    """The lines of a built training (its folder, its set-up time, the solved rule), and the browser view where
    asked."""
    what = "population" if training.members else "run"
    print(f"{what} folder: {run_dir}" + (f" (resumed from {checkpoint.name})" if checkpoint else ""))
    print(f"ready in {training.setup_time_s:.1f} s; task {training.cfg.task}, solved = {training.solved_definition}",
          flush=True)
    if checkpoint is None and (chosen := device_settings(training.cfg)):  # a resumed run keeps its saved settings
        here, other = ("GPU", "CPU") if on_gpu(training.cfg.env.device) else ("CPU", "GPU")
        print(f"on a {here} the task's settings: {', '.join(f'{name} {value}' for name, value in chosen.items())} "
              f"(its {other} settings differ; a flag changes either)", flush=True)
    if checkpoint is None and (chosen := learner_settings(training.cfg)):
        settings = ", ".join(f"{name} {value}" for name, value in chosen.items())
        print(f"with --learner {training.cfg.agent.learner} its settings and the task's: {settings} (a flag changes "
              "any)",
              flush=True)
    for mode in training.loop.modes:
        print(f"population mode: {mode.describe()}", flush=True)
    hooks = IterationHooks()
    if args.viewer == "viser":
        from .viz.web import TrainingView

        view = TrainingView(training.env.env, args.viser.host, args.viser.port, args.viser.viewer_envs,
                            args.viewer_interval_s, stopping=lambda: training.loop.stop_requested is not None,
                            title=training.cfg.task, play_metric=training.task.play_metric)
        hooks.append(view)
        print(f"watch it at {view.url}", flush=True)
    if args.video:
        from .rl.video import VIDEO_DIR, TrainingVideo

        hooks.append(TrainingVideo(training, args.video_length, args.video_interval))
        print(f"clips of {args.video_length} env steps every {args.video_interval} iterations: "
              f"{run_dir / VIDEO_DIR}", flush=True)
    if hooks:
        training.loop.on_iteration = hooks


def report(summary, run_dir: Path, checkpoint: Path | None, timing_s: dict[str, float]):
    """The end of a run: what it did, when it was solved, where its artefacts are, where its seconds went."""
    resumed = (f" of training over all its processes, {summary.timing_s['training']:.1f} s in this one"
               if checkpoint is not None else "")
    done = (f"{summary.iterations} iterations, {summary.env_steps:,} env steps in {summary.train_time_s:.1f} s"
            f"{resumed} ({summary.env_steps_per_s:,} steps/s)")
    solved = summary.solved_at
    if solved and summary.status == "solved":
        print(f"solved at iteration {solved['iterations']} after {summary.train_time_s:.1f} s{resumed} "
              f"({summary.env_steps:,} env steps, {summary.env_steps_per_s:,} steps/s)")
    else:
        print(f"{summary.status}: {done}")
        print(f"solved at iteration {solved['iterations']} after {solved['train_time_s']:.1f} s "
              f"({solved['env_steps']:,} env steps)" if solved else
              "not solved yet: train longer (--max-iterations, or --resume)")
    best = [BEST_CHECKPOINT + " (play.py's)"] if (run_dir / BEST_CHECKPOINT).is_file() else []
    print(f"artefacts in {run_dir}: {', '.join([summary.checkpoint, *best])}, summary.json, learning_curve.png, "
          f"{', '.join(summary.exports)}\nwatch it: python play.py --headless --run {run_dir}")
    total = process_age_s() if "start" in timing_s else None
    phases = ", ".join(f"{phase} {seconds:.1f}" for phase, seconds in summary.timing_s.items())
    print(f"seconds: {phases}" + (f"; {total:.1f} since the process started" if total is not None else ""))


def report_population(result: dict, run_dir: Path):
    """The end of a population: its members' table, how many solved, its pace, and how to watch one."""
    members, first = result["members"], result.get("first_solved")
    watch = (f"the population's policy, {first}'s: python play.py --headless --run {run_dir}" if first
             else f"watch one: python play.py --headless --run {run_dir / members[0]['member']}")
    print(f"\n{(run_dir / MEMBERS_FILE).read_text()}{result['solved']} of {len(members)} solved; the population "
          f"trained {result['env_steps']:,} env steps in {result['train_time_s']:.1f} s "
          f"({result['env_steps_per_s']:,} steps/s)\n{watch}")


if __name__ == "__main__":
    sys.exit(main())
