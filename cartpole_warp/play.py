"""Watch a policy on its task: statistics and a GIF (--headless; a USD recording too with --record-usd) or Newton's
viewer.

    python play.py --headless                    # newest cartpole-balance run's best checkpoint -> <run>/play/
    python play.py --headless --task cartpole-swingup     # newest run of that task
    python play.py --headless --run DIR          # or --checkpoint FILE
    python play.py --agent zero --headless       # no checkpoint needed (also: random, multisine)
    python play.py --headless --eval             # success rate over a grid of pole mass x actuator strength
    python play.py                               # Newton's interactive viewer (needs a display and the viz extra)
    python play.py --viewer viser                # in a browser: http://127.0.0.1:8080 (needs the viser extra)

The task and its env are rebuilt from the run's saved config.yaml (flags override it); the policy acts
deterministically (the Gaussian's mean). Also installed as ``python -m cartpole_warp.play``.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Generic, Literal

import tyro

from . import tasks
from .cli import (
    ENV_ALIASES,
    ViserArgs,
    asks_help,
    clean_errors,
    flags_named,
    parse,
    peek,
    quiet_libraries,
    renamed_flags,
)
from .engine.scene import StageError
from .rl.config import TrainConfig, checked, train_config, with_env_preset
from .rl.runs import (
    CONFIG_FILE,
    EXPORT_DIR,
    PLAY_DIR,
    RunError,
    best_member,
    find_checkpoint,
    latest_run,
    load_config,
    newer_populations,
    play_checkpoint,
    population_members,
)
from .settings.config import ConfigError, EnvConfig, RandomizationConfig, TaskT, require
from .settings.files import unwritable, write_text

if TYPE_CHECKING:
    from .evaluation.rollouts import Policy  # torch: imported when a run needs it

Agent = Literal["trained", "zero", "random", "multisine"]
Viewer = Literal["window", "viser", "none"]


@dataclass
class GridArgs:
    """--eval's grid of physical parameters: up to three axes, each a name of ``env.physical_params()`` and factors that
    multiply the stage's value (or are the values themselves where the stage's is 0: damping, friction, action
    delay)."""

    x: str | None = None
    """The parameter along the heatmap's x axis (default: the mass of the task's last joint role, pole_mass_kg for the
    cart-pole tasks)."""
    x_factors: list[float] = field(default_factory=lambda: [0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0])
    y: str = "actuator_scale"
    """The parameter along the y axis."""
    y_factors: list[float] = field(default_factory=lambda: [0.5, 0.6, 0.7, 0.85, 1.0, 1.15, 1.3, 1.5])
    z: str | None = None
    """A third parameter: the table and heatmap show the worst over it (the CSV every cell)."""
    z_factors: list[float] = field(default_factory=lambda: [0.5, 1.0, 2.0])
    episodes: int = 64
    """Episodes per cell (one env each)."""

    def axes(self, joint_roles: tuple[str, ...]) -> list:
        """The axes for a task with these joint roles."""
        from .evaluation.robustness import Axis

        named = [(self.x or f"{joint_roles[-1]}_mass_kg", self.x_factors), (self.y, self.y_factors),
                 (self.z, self.z_factors)]
        return [Axis(name, tuple(factors)) for name, factors in named if name is not None]


GRID_ALIASES = {f"--grid-{name}": f"--grid.{name}" for name in
                ("x", "x-factors", "y", "y-factors", "z", "z-factors", "episodes")}
"""The grid's flags as they were spelt before they were grouped (``--grid-x`` for ``--grid.x``): still taken, with a
warning, until ``settings.deprecation.REMOVED_IN``."""


@dataclass
class PlayArgs(Generic[TaskT]):
    env: EnvConfig[TaskT]
    task: str = tasks.DEFAULT_TASK
    """The task whose newest run plays (a run's own task when --run or --checkpoint names it), or which --agent
    zero|random|multisine plays."""
    agent: Agent = "trained"
    """trained: a checkpoint's policy; zero: no push; random: uniform in [-1, 1]; multisine: cosines of 0.75, 1.4 and
    2.7 Hz, the same in every env (an excitation for tools.sysid's recordings of the swing-up)."""
    run: Path | None = None
    """Run folder (default: the newest run under --log-dir)."""
    checkpoint: Path | None = None
    """Checkpoint file (default: the run's best by its evaluations, model_best.pt, else its latest); it plays with its
    own folder's config.yaml, so --run, if given too, must be that folder."""
    log_dir: str = "logs"
    """Root folder of all runs (train.py's --log-dir)."""
    experiment_name: str | None = None
    """The experiment whose newest run plays (train.py's --agent.experiment-name); None: the task's name."""
    config: str | None = None
    """Preset of the env for --agent zero|random|multisine or a checkpoint outside a run folder; with a run, its env
    settings replace the run's (a policy played on other physics, e.g. a rig's)."""
    headless: bool = False
    """No window: print statistics, write <output>/cartpole.gif, cartpole.mp4 (with the video extra) and result.json
    (the same as --viewer none)."""
    viewer: Viewer = "window"
    """window: Newton's OpenGL viewer (a display and the viz extra); viser: a web page served by this process (the
    viser extra); none: --headless."""
    viser: Annotated[ViserArgs, tyro.conf.arg(name="")] = field(default_factory=ViserArgs)
    record_usd: bool = False
    """--headless: also write <output>/cartpole.usda, Newton's ViewerUSD recording of the envs (usdview plays it;
    tens of MB for a 10 s episode of 256 envs)."""
    record_viser: bool = False
    """--headless: also write <output>/cartpole.viser, a replay for viser's static player (the viser extra; Newton's
    viser viewer records only while it serves, so a server runs on a free local port meanwhile)."""
    export: bool = False
    """Write <run>/exported/policy.onnx, policy.pt2 and policy.pt."""
    steps: int | None = None
    """Env steps to run (default: the time limit, or 1000 without one; in the viewer: until its window closes); fewer
    than a whole episode's are not judged 'solved' or not."""
    video_length: int | None = None
    """Env steps of env 0 in the MP4 (default: all the steps run); its frame rate is one frame per env step."""
    output: Path | None = None
    """Folder for the GIF, USD and result (default <run>/play, or <log-dir>/play/<agent>)."""
    eval: bool = False
    """With --headless, instead of the rollout: play --grid.episodes episodes in each cell of a grid of physical
    parameters (factors on the stage's values, without the run's randomization) and write <output>/robustness.csv
    and robustness.png (success: the time limit reached, and the task's reward per step where its rule asks)."""
    grid: GridArgs = field(default_factory=GridArgs)


def newest_run(log_dir: str, experiment: str) -> Path:
    """``latest_run``, saying so where a population newer than that run is there too."""
    run = latest_run(log_dir, experiment, "--experiment-name")
    if newer := newer_populations(run):
        print(f"note: playing {run}, the newest single run; the population {newer[-1]} is newer (play its "
              f"best-evaluated member: --run {best_member(population_members(newer[-1]))})", flush=True)
    return run


def resolve(argv: list[str]) -> tuple[PlayArgs, TrainConfig, Path | None]:
    """(arguments, the run's config with the env flags applied, checkpoint or None)."""
    first = peek(argv, task=None, agent="trained", run=None, checkpoint=None, log_dir="logs", experiment_name=None,
                 config=None)
    task = tasks.get(first.task or tasks.DEFAULT_TASK).name
    checkpoint, physics_preset = None, False
    if first.agent != "trained" or asks_help(argv):
        cfg = train_config(task, first.config)
    else:
        checkpoint = find_checkpoint(first.checkpoint, first.run, lambda: newest_run(
            first.log_dir, first.experiment_name or task), play_checkpoint, "--run")
        saved = checkpoint.parent / CONFIG_FILE
        cfg = load_config(checkpoint.parent) if saved.is_file() else train_config(task, first.config)
        physics_preset = saved.is_file() and first.config is not None
        if physics_preset:
            cfg = with_env_preset(cfg, first.config)
        require(not first.task or first.task == cfg.task, f"--task {first.task}: the run was trained on {cfg.task}")
    cfg.env.num_envs = cfg.eval.num_envs
    cls = PlayArgs[type(cfg.env.task)]
    args = parse(cls, cls(env=cfg.env, task=cfg.task, config=first.config), renamed_flags(argv, GRID_ALIASES),
                 __doc__, ENV_ALIASES)
    require(args.agent == "trained" or not (args.run or args.checkpoint or args.export),
            f"--agent {args.agent} takes no --run, --checkpoint or --export")
    require(args.steps is None or args.steps >= 1, f"--steps must be >= 1, got {args.steps}")
    require(args.video_length is None or args.video_length >= 1,
            f"--video-length must be >= 1, got {args.video_length}")
    cfg.env = args.env
    if args.viewer == "none":
        args.headless = True
    require(args.viser.problem() is None, args.viser.problem())
    if args.eval:
        require(not physics_preset, "--eval plays its own grid of physics around the stage's: drop --config")
        grid_envs(args, cfg, argv)
    with flags_named(argv, ENV_ALIASES):
        return args, checked(cfg).validate(), checkpoint


def grid_envs(args: PlayArgs, cfg: TrainConfig, argv: list[str]):
    """--eval: the grid's checks, and the envs it plays in ``cfg.env`` (episodes of every cell, the largest action
    delay it asks for)."""
    require(args.headless, "--eval runs headless: add --headless")
    grid = args.grid
    require(grid.episodes >= 1, f"--grid.episodes must be >= 1, got {grid.episodes}")
    require(args.steps is None, "--eval plays each episode to the time limit: drop --steps")
    require(cfg.env.task.has_time_limit, "--eval needs a time limit (task.episode_length_s)")
    envs = peek(argv, num_envs=None, **{"env.num_envs": None})
    require(envs.num_envs is None and getattr(envs, "env.num_envs") is None,
            "--eval sets the envs itself (grid cells x --grid.episodes): drop --num-envs")
    axes = grid.axes(cfg.task_spec.env_class.joint_roles)
    names = [axis.name for axis in axes]
    require(len(set(names)) == len(names), f"each grid axis needs its own parameter, got {', '.join(names)}")
    for axis, flag in zip(axes, (f"--grid.{letter}-factors" for letter in "xyz")):
        require(axis.factors and min(axis.factors) >= 0 and math.isfinite(max(axis.factors)),
                f"{flag} needs finite factors >= 0, got {' '.join(f'{f:g}' for f in axis.factors) or 'none'}")
    cfg.env.num_envs = math.prod(len(axis.factors) for axis in axes) * grid.episodes
    delays = [max(axis.factors) for axis in axes if axis.name == "action_delay_steps"]
    require(all(d == int(d) for d in delays), "action_delay_steps factors are whole env steps")
    cfg.env.randomization = RandomizationConfig(at="startup", action_delay_steps=int(max(delays, default=0)))


def main(argv: list[str] | None = None) -> int:
    quiet_libraries()
    from .viz import ViewerUnavailable

    try:
        return play(sys.argv[1:] if argv is None else argv)
    except ViewerUnavailable as err:  # a usage error, as every other: exit 2
        print(f"error: {err}", file=sys.stderr)
        return 2


def play(argv: list[str]) -> int:
    """play.py's work; ViewerUnavailable when the viewer is asked for and cannot open."""
    with clean_errors(ConfigError, RunError, StageError):
        args, cfg, checkpoint = resolve(argv)
        if args.headless:
            output = output_dir(args, checkpoint)
            problem = unwritable(output)
            require(problem is None, f"the output folder {output} cannot be written: {problem}")
        if not args.headless and args.viewer == "viser":
            from .viz.web import check_viser

            require(args.viser.host_problem() is None, args.viser.host_problem())
            check_viser()
        elif not args.headless:
            from .viz.viewer import check_viewer

            check_viewer()
        cfg.apply_torch_threads()
        env = cfg.task_spec.env_class(cfg.env)
        policy = load_policy(args, cfg, env, checkpoint)
        if args.eval:
            return evaluate_robustness(args, cfg, env, policy, checkpoint)
        if args.headless:
            return play_headless(args, cfg, env, policy, checkpoint)
        return view(args, env, policy, cfg.task_spec.play_metric)


def load_policy(args: PlayArgs, cfg: TrainConfig, env, checkpoint: Path | None) -> Policy:
    """The checkpoint's deterministic policy (exported first with --export), or the zero, random or multisine one."""
    from .evaluation.rollouts import MultisinePolicy, RandomPolicy, zero_policy

    if checkpoint is None:
        print(f"policy: {args.agent}")
        return {"zero": lambda: functools.partial(zero_policy, num_actions=env.num_actions),
                "random": lambda: RandomPolicy(env.num_actions, cfg.env.seed),
                "multisine": lambda: MultisinePolicy(env.num_actions, env.env_dt)}[args.agent]()
    from .rl.policies import deterministic, export_policy, load_actor
    from .wrappers.rsl_rl import RslRlVecEnv

    print(f"policy: {checkpoint}")
    actor = load_actor(RslRlVecEnv(env), cfg.agent, checkpoint)
    if args.export:
        for path in export_policy(actor, checkpoint.parent / EXPORT_DIR):
            print(f"exported {path}")
    return deterministic(actor)


def view(args: PlayArgs, env, policy: Policy, play_metric: str) -> int:
    """The policy in Newton's window or, with --viewer viser, in a browser, until the viewer closes."""
    if args.viewer == "viser":
        from .viz.web import view_in_browser

        viser = args.viser
        steps = view_in_browser(env, policy, viser.host, viser.port, viser.viewer_envs, max_steps=args.steps,
                                on_ready=lambda url: print(f"watch it at {url} (Ctrl-C ends)", flush=True),
                                title=args.task, play_metric=play_metric)
    else:
        from .viz.viewer import view_interactively

        steps = view_interactively(env, policy, max_steps=args.steps)
    print(f"viewer closed after {steps} env steps")
    return 0


def play_headless(args: PlayArgs, cfg: TrainConfig, env, policy: Policy, checkpoint: Path | None) -> int:
    """Each env's first episode, recorded (GIF, MP4 with the video extra, USD with --record-usd; for a policy that
    sees camera frames, also ``policy_view.gif``: those frames beside the side view; env 0's joint states and actions
    as ``trajectory.npz``, the input of ``tools.sysid``); the statistics printed and written to result.json."""
    from .evaluation.rollouts import rollout, whole_episode_steps
    from .evaluation.trajectories import TRAJECTORY_FILE, TrajectoryRecorder
    from .viz.record import VIDEO_EXTRA, Recorder, video_available

    task = cfg.task_spec
    steps = args.steps or whole_episode_steps(env)
    output = output_dir(args, checkpoint)
    recorder = Recorder.of_env(env, output, video_length=args.video_length, viser=args.record_viser,
                               usd=args.record_usd)
    trajectory = TrajectoryRecorder(env)

    def on_step(k: int):
        recorder(k)
        trajectory(k)

    print(f"playing {env.num_envs} envs for {steps} env steps ...", flush=True)
    stats = rollout(env, policy, steps, on_step=with_progress(on_step, steps), seed=cfg.env.seed)
    pictures = [*recorder.close(), trajectory.write(output / TRAJECTORY_FILE)]
    at_limit = cfg.env.task.has_time_limit and steps >= env.max_episode_length
    limit = f"the {cfg.env.task.episode_length_s:g} s time limit" if at_limit else f"the {steps}-step cap"
    whole = steps >= whole_episode_steps(env)
    solved = task.solved(stats) if whole else None  # episodes cut by --steps say nothing of the task's rule
    verdict = ("solved" if solved else "not solved") if whole else (
        f"not judged: --steps {steps} ends the episodes before their {whole_episode_steps(env)} steps")
    metric = getattr(stats, task.play_metric)
    print(f"{cfg.task}: {stats.episodes} episodes ({env.num_envs} envs, first episode each, {steps} steps): "
          f"mean return {stats.mean_return:.2f}, mean length {stats.mean_episode_length:.1f} steps "
          f"({stats.mean_episode_length * env.env_dt:.2f} s), reward/step {stats.mean_reward_per_step:.3f}, "
          f"reached {limit}: {stats.time_limit_fraction:.1%}; {task.play_metric} "
          f"{'-' if metric is None else f'{metric:.3f}'}: {verdict}")
    record = {"task": cfg.task, "agent": args.agent, "checkpoint": str(checkpoint) if checkpoint else None,
              "num_envs": env.num_envs, "steps": steps, **dataclasses.asdict(stats), "play_metric": task.play_metric,
              "play_value": metric, "solved": solved}
    result_file = write_text(output / "result.json", json.dumps(record, indent=2) + "\n")
    usd = " (usdview plays the .usda)" if args.record_usd else ""
    print(f"wrote {', '.join(map(str, pictures))}{usd} and {result_file}")
    if not video_available():
        print(f"no MP4: {VIDEO_EXTRA} adds it")
    return 0


PROGRESS_EVERY_S = 10.0
"""A rollout that runs longer prints how far it is this often (a camera task on the CPU plays for a minute)."""


def with_progress(on_step: Callable[[int], None], steps: int,
                  every_s: float = PROGRESS_EVERY_S) -> Callable[[int], None]:
    """``on_step`` that also prints, every ``every_s`` seconds, the steps done and an estimate of the time left at
    the pace of the steps after the first (which loads kernels and, on CUDA, captures the step's graph)."""
    start = time.perf_counter()
    next_s = start + every_s
    first_done_s = start

    def step(k: int):
        nonlocal next_s, first_done_s
        on_step(k)
        now = time.perf_counter()
        if k == 1:
            first_done_s = now
        if 0 < k < steps and now >= next_s:
            left = (f", about {(now - first_done_s) / (k - 1) * (steps - k):.0f} s left" if k > 1
                    else " (the first step warms up)")
            print(f"  {k}/{steps} env steps in {now - start:.0f} s{left}", flush=True)
            next_s = now + every_s

    return step


def output_dir(args: PlayArgs, checkpoint: Path | None) -> Path:
    """--output, or <run>/play, or <log-dir>/play/<agent>."""
    if args.output:
        return args.output
    return checkpoint.parent / PLAY_DIR if checkpoint else Path(args.log_dir) / PLAY_DIR / args.agent


def evaluate_robustness(args: PlayArgs, cfg: TrainConfig, env, policy: Policy, checkpoint: Path | None) -> int:
    """--eval: the grid's success rates, printed and written as CSV and PNG."""
    from .evaluation.robustness import evaluate_grid, format_table, plot_heatmap, write_table

    axes = args.grid.axes(cfg.task_spec.env_class.joint_roles)
    print(f"{cfg.task}: {args.grid.episodes} episodes in each of {env.num_envs // args.grid.episodes} cells "
          f"({env.num_envs} envs) ...", flush=True)
    result = evaluate_grid(env, policy, axes, args.grid.episodes, cfg.task_spec.solved)
    print(format_table(result))
    output = output_dir(args, checkpoint)
    who = f"{checkpoint.parent.name}/{checkpoint.name}" if checkpoint else f"{args.agent} policy"
    table = write_table(output / "robustness.csv", result)
    heatmap = plot_heatmap(output / "robustness.png", result,
                           f"{cfg.task}: {who}\n{args.grid.episodes} episodes per cell")
    print(f"wrote {table} and {heatmap}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
