"""System identification: a task's physical parameters fitted to a recorded trajectory by gradient descent through
the simulator (``gradients.rollout``). Its programs: ``tools.sysid`` (whose ``--help`` ends with what follows) and
``tools.multiarm`` (a real rig's published recordings).

The recording (CSV with a header row, or NPZ; ``play.py --headless`` writes one of env 0 as ``trajectory.npz``):
``time_s``; ``action`` (the action applied from that row's time to the next row's, -1..1 as the task takes it); per
joint role its position, ``cart_pos_m`` for the cart and ``<role>_angle_rad`` for each pole (``pole_angle_rad``,
``pole2_angle_rad``: the hinge's angle relative to the body below it, 0 upright), and optionally its velocity
(``cart_vel_m_s``, ``<role>_vel_rad_s``); an optional ``episode`` column marks where the rig was reset. Rows come at
one rate that the physics step ``sim.physics_dt`` divides: the fit steps the env at the recording's rate. ``--config``
gives the rig's own env settings (its stage, the joints it holds still: ``sim.held_joints``, whose recorded positions
must not move).

Multiple shooting: the recording is cut into windows of ``--window-steps`` env steps (several: a fit with each length
in turn, each from the last one's result), each simulated from its own
initial state (fitted too, starting from the recorded positions and the recorded or differenced velocities), so that
errors do not compound through a chaotic trajectory. Every window of every starting guess is one env of one batched,
differentiable rollout: ``--guesses`` guesses, each parameter drawn log-uniformly within ``--spread`` of the stage's
value, fitted at once by Levenberg-Marquardt on the parameters (the log of those the stage sets; a damping or a
friction, 0 on the stage, in 1% of its joint's natural unit, kept >= 0) and every window's start (the gradient
through the simulator's adjoints, the Jacobian by forward differences of the batched rollout, the windows' starts
eliminated per window), until an undamped Gauss-Newton step would lower the loss by less than ``--tolerance`` of it
(or ``--iterations`` per window length, saying so); ``--from`` starts from an earlier fit. Before it fits, a chain of
arms on a held cart is told what the ``--fit`` list leaves to the stage (``identification.chain``). The guess that
fits best is printed against the stage's values with the residual, plotted (recorded against simulated positions,
PNG), tried on whole episodes (each episode of the recording and of the ``--validate`` recordings simulated from its
first row over its whole length: RMS error per joint, and for a chain of arms per arm from upright, a plot and a
``sysid_simulated_<n>.npz`` each) and written as a preset whose randomization ranges lie ``--randomize`` around the
fit (0: exactly the fit) for ``train.py --config FILE`` and ``play.py --config FILE``. A parameter whose standard
error exceeds 1% of its fit is reported as not identified by the recording, and one outside physical sense (a scale
near 0, a centre of mass beyond its body) is flagged. The recording must be of one physics: no domain randomization
or action delay while it was made (the fit has neither).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
import yaml

from .. import tasks
from ..engine.parameters import (
    ACTUATOR_SCALE,
    COM,
    DAMPING,
    FRICTION,
    GRAVITY,
    INERTIA_SCALE,
    MASS,
    Parameter,
    of_quantity,
)
from ..evaluation.trajectories import Recording, column_names, read_trajectory, write_trajectory
from ..gradients.rollout import DifferentiableRollout, Trajectory
from ..settings.config import merge, require
from ..settings.files import write_text
from . import chain

NOT_FITTED_BY_DEFAULT = (ACTUATOR_SCALE.key, GRAVITY.key)
"""Left at the stage's values unless ``--fit`` names them: scaling every mass, damping, friction and the actuator
together moves nothing (only their ratios are in the motion), and gravity is known."""
EQUALLY_GOOD = 1.1
"""Guesses whose loss is within this factor of the best one's count as fitting as well."""
INITIAL_LM_LAMBDA = 1e-2
"""Levenberg-Marquardt's first lambda, the damping of its steps (per guess: divided by 3 after an iteration whose
step lowers the loss, times 4 after each step tried that does not)."""
LM_LAMBDA_RANGE = (1e-9, 1e9)
"""The lambdas' bounds. An iteration that lowers no guess's loss with every lambda at the largest ends the fit as
stalled: its steps are then too short to change the loss (a minimum at the rollouts' float resolution, or a
Jacobian that misleads)."""
JACOBIAN_STEP = 1e-3
"""Forward-difference step of the Jacobian's columns (in units of each signal's spread, and of a log-parameter)."""
IDENTIFIED_WITHIN = 0.01
"""A parameter whose standard error is above this fraction of its fit (or of the stage's value, if larger) is
reported as not identified by the recording: its effect on the recorded positions is small against their noise."""
LIMIT_MARGIN = 0.02
"""Rows whose position lies within this fraction of a joint's range (1 m or rad where one side has no limit) of one
of its limits are in no window."""
NO_LIMIT = 1e6
"""A joint limit at or beyond this (m or rad) is none."""
HELD_STILL = 1e-6
"""A held joint's recorded position may vary by at most this (m or rad) within an episode."""
ROW_JITTER = 1e-3
"""Each row's interval may differ from the recording's (their median) by this fraction of it."""
RATE_TOLERANCE = 1e-3
"""The recording's row interval may differ from a whole number of physics steps by this fraction of it (timestamps
rounded to the microsecond at 60 Hz are 2e-5 off)."""
NATURAL_FRACTION = 0.01
"""A damping's or a friction's unit in the fit: this fraction of its joint's natural one (``natural_units``)."""
RESOLVED = 2e-6
"""Also converged: residuals whose RMS is below this fraction of each signal's spread, finer than a float32 rollout
resolves (a noise-free recording of the model itself)."""
LM_TRIALS = 4
"""Steps tried on one Jacobian in an iteration, the damping times 4 after each that does not lower the loss."""
PLAUSIBLE_FACTOR = 10.0
"""A mass or an inertia scale fitted beyond this factor of the stage's value (either way) is flagged in the report as
outside physical sense: a scale near 0 is an inertia that other parameters took over."""
COM_SPAN = 2.0
"""A centre of mass fitted below its joint or beyond this factor of the stage's distance is flagged likewise: the
stage's shapes are centred on their centres of mass, so this is past the shape's far end."""


@dataclass
class SysidArgs:
    """Fit a task's physical parameters to a recorded trajectory (module docstring)."""

    trajectory: Path | None = None
    """The recording: a CSV with a header row or an NPZ (columns in the module docstring)."""
    task: str = tasks.DEFAULT_TASK
    """The registered state task whose stage and joints the recording is of."""
    config: str | None = None
    """A preset (a name under configs/ or a YAML path) whose env settings the fit's envs take: a rig's own stage
    (``sim.stage_path``), joints held still (``sim.held_joints``), its physics step. The preset written keeps them."""
    validate: list[Path] = field(default_factory=list)
    """Recordings of the same rig held out of the fit: each of their episodes, like each of the fitted recording's,
    is simulated from its first row over its whole length with the fitted physics (the report's prediction table)."""
    fit: list[str] = field(default_factory=list)
    """Parameters to fit (names as printed); default: every mass, centre of mass, joint damping and friction."""
    window_steps: list[int] = field(default_factory=lambda: [20])
    """Env steps of each shooting window; several: a fit with each in turn, each from the last one's result (short
    windows find the motion's frequencies from a poor start, longer ones then see what accumulates, such as
    dissipation)."""
    window_stride: int = 1
    """Fit every this-many-th window (1: every one): a long recording's windows thinned."""
    guesses: int = 8
    """Starting guesses fitted at once (one batch of envs each)."""
    spread: float = 0.5
    """Each guess draws a parameter's starting value log-uniformly within a factor 1 + this of the stage's."""
    iterations: int = 30
    """At most this many Levenberg-Marquardt iterations with each window length (each: the gradient by one backward
    pass through the simulator, the Jacobian by forward differences, a step on the parameters and every window's
    start); a fit ends earlier once converged (``--tolerance``) or stalled (no step lowers the loss), and says which."""
    tolerance: float = 1e-4
    """Converged: an undamped Gauss-Newton step from the best guess would lower its loss by less than this fraction
    of it (the local model sees no further fall), or its residuals are below float32's resolution."""
    start_from: Path | None = None
    """An earlier fit's result (``sysid_result.yaml`` or ``tools.multiarm``'s ``multiarm_result.yaml``; ``--from``):
    its fitted values start this fit (the first guess; the others drawn ``--spread`` around them), and without
    ``--fit`` its parameter list is this fit's."""
    randomize: float = 0.0
    """The preset's randomization ranges: the fit times (1 -/+ this) (0: the fit exactly)."""
    device: str = "cpu"
    """Where the rollouts run: 'cpu' or 'cuda:N'."""
    batched_jacobian: bool | None = None
    """Roll the Jacobian's columns out in the fit's own rollout, as copies of its envs (one rollout of many envs
    instead of one per column); default: on a GPU, which runs a small batch in as many launches as a large one, and
    not on a CPU, whose time grows with the envs."""
    output: Path | None = None
    """Folder for sysid_preset.yaml, sysid_fit.png and sysid_result.yaml (default: <trajectory>_sysid beside the
    recording)."""
    seed: int = 0
    """Seed of the starting guesses."""


def windows(recording: Recording, steps: int, usable: np.ndarray) -> list[int]:
    """The first rows of the shooting windows: ``steps`` + 1 rows each, inside one episode, back to back, every row
    ``usable`` (bool per row)."""
    same = recording.episode
    starts, t = [], 0
    while t + steps < len(same):
        if (same[t:t + steps + 1] == same[t]).all() and usable[t:t + steps + 1].all():
            starts.append(t)
            t += steps
        else:
            t += 1
    return starts


def clear_of_limits(recording: Recording, env) -> np.ndarray:
    """(rows,) bool: every joint's recorded position further than ``LIMIT_MARGIN`` of its range from the stage's
    limits (a joint without limits is always clear)."""
    model, dofs = env.scene.model, env.scene.role_dofs
    lower, upper = model.joint_limit_lower.numpy()[dofs], model.joint_limit_upper.numpy()[dofs]
    has_lower, has_upper = np.abs(lower) < NO_LIMIT, np.abs(upper) < NO_LIMIT  # Newton's "none" is +-1e10
    margin = LIMIT_MARGIN * np.where(has_lower & has_upper, upper - lower, 1.0)
    clear = (~has_lower | (recording.q > lower + margin)) & (~has_upper | (recording.q < upper - margin))
    return clear.all(axis=1)


def velocities(recording: Recording, dt: float, sliders: list[bool]) -> np.ndarray:
    """Recorded velocities where given, else central differences of the positions within each episode."""
    qd = recording.qd.copy()
    for episode in np.unique(recording.episode):
        rows = recording.episode == episode
        if rows.sum() > 1:
            q = recording.q[rows]
            q = np.where(sliders, q, np.unwrap(q, axis=0))  # a hinge recorded wrapped to (-pi, pi]
            differenced = np.gradient(q, dt, axis=0)
            qd[rows] = np.where(np.isfinite(qd[rows]), qd[rows], differenced)
    return np.nan_to_num(qd)


def angle_error(a: torch.Tensor, b: torch.Tensor, hinge: torch.Tensor) -> torch.Tensor:
    """a - b, wrapped to (-pi, pi] on the hinges (``hinge`` (joints,) bool)."""
    difference = a - b
    return torch.where(hinge, torch.atan2(torch.sin(difference), torch.cos(difference)), difference)


@dataclass
class Problem:
    """What a fit reads before it builds its envs: the recording, its windows and the parameters to fit."""

    recording: Recording
    usable: np.ndarray
    """(rows,) bool: the rows a window may hold (clear of the joints' limits)."""
    names: list[str]
    """The parameters fitted."""
    stage: dict[str, float]
    """Every settable parameter's value on the stage (SI units)."""
    units: dict[str, float]
    """Each fitted parameter's unit in the fit: its stage value, or where that is 0 (a damping, a friction)
    ``NATURAL_FRACTION`` of its joint's natural one."""
    roles: tuple[str, ...]
    sliders: list[bool]
    table: tuple[Parameter, ...]
    """The task's physical parameters (``engine.parameters``)."""
    dt: float
    """The recording's row interval (s): the fit's env step."""
    sim: dict
    """The fit's ``sim`` settings beyond the task's and the preset's: as many physics steps per env step as fit in
    ``dt``."""
    held: list[bool]
    """Per role: whether the rig holds its joint still (``sim.held_joints``)."""
    start: dict[str, float] = field(default_factory=dict)
    """The earlier fit's values that start this one (``--from``), by parameter."""


def read_problem(args: SysidArgs) -> Problem:
    """The recording of ``args.trajectory`` checked against the task (ConfigError in one line), cut into windows, and
    the parameters to fit."""
    probe = tasks.get(args.task).env_class(tasks.env_config(args.task, args.config, num_envs=1, device=args.device))
    require(not probe.sees_images, f"--task {args.task} observes camera frames; identify its state twin's physics")
    roles, sliders = probe.joint_roles, probe.physics.sliders
    held = [role in probe.cfg.sim.held_joints for role in roles]
    recording = read_trajectory(args.trajectory, roles, sliders, probe.num_actions)
    dt, sim = step_settings(args.trajectory, recording, probe.cfg.sim)
    check_held(args.trajectory, recording, roles, held)
    clear = clear_of_limits(recording, probe)
    if not clear.all():
        print(f"{int((~clear).sum())} rows lie within {LIMIT_MARGIN:.0%} of a joint's range of its limit (the stage's "
              "stop, a stiff spring whose onset a window's start cannot be fitted through): no window holds them")
    table, bodies = probe.physics.table, probe.physics.bodies
    settable = [p.name for p in table if p.quantity.differentiable]
    stage = {n: float(v[0]) for n, v in probe.physics.stage_values().items() if n in settable}
    on_joint = [p.name for p in of_quantity(table, COM) if bodies[p.role_index].com_distance == 0.0]
    start = earlier_fit(args)
    names = fitted_names(args.fit or list(start), settable, on_joint)
    dropped = sorted(set(start) - set(names))
    require(not dropped, f"--from {args.start_from} fitted {', '.join(dropped)}, which --fit leaves out (this fit "
                         "would put them back to the stage's values): add them to --fit")
    natural = natural_units(table, bodies, sliders, probe.physics.gravity_m_s2)
    units = {name: stage[name] if stage[name] > 0 else NATURAL_FRACTION * natural.get(name, 1.0) for name in names}
    probe.close()
    return Problem(recording, clear, names, stage, units, roles, sliders, table, dt, sim, held, start)


def earlier_fit(args: SysidArgs) -> dict[str, float]:
    """The fitted values of ``--from``'s result file (none without it); ConfigError in one line where it is not a fit
    of this task."""
    if args.start_from is None:
        return {}
    require(args.start_from.is_file(), f"--from: no file {args.start_from}")
    earlier = yaml.safe_load(args.start_from.read_text()) or {}
    fitted = earlier.get("fitted") if isinstance(earlier, dict) else None
    require(isinstance(fitted, dict) and fitted,
            f"--from {args.start_from}: no 'fitted' values (a sysid_result.yaml or multiarm_result.yaml holds them)")
    task = earlier.get("task", args.task)
    require(task == args.task, f"--from {args.start_from} is a fit of --task {task}, not of {args.task}")
    return {name: float(value) for name, value in fitted.items()}


def natural_units(table: tuple[Parameter, ...], bodies: list, sliders: list[bool], gravity_m_s2: float
                  ) -> dict[str, float]:
    """Each joint's damping and friction in its body's own terms: for a hinge the torque of gravity on the body held
    level, m g d (d: its centre of mass from the hinge, at least 1 cm), and the damping sqrt(J m g d) that takes as
    much (J: the inertia about the hinge), at the body's own rate sqrt(m g d / J); for a slider the body's weight and
    that weight per m/s."""
    units = {}
    for p in of_quantity(table, DAMPING) + of_quantity(table, FRICTION):
        body = bodies[p.role_index]
        weight = body.mass * gravity_m_s2
        if sliders[p.role_index]:
            units[p.name] = weight
            continue
        torque = weight * max(body.com_distance, 0.01)
        inertia = float(body.axis @ body.inertia @ body.axis) + body.mass * body.com_distance**2
        units[p.name] = torque if p.quantity is FRICTION else math.sqrt(inertia * torque)
    return units


def row_interval(path: Path, recording: Recording) -> float:
    """The recording's row interval (s), the median of its rows' within episodes (ConfigError in one line where they
    differ by more than ``ROW_JITTER``)."""
    same_episode = np.diff(recording.episode) == 0
    require(same_episode.any(), f"{path}: no episode of two rows or more")
    intervals = np.diff(recording.time_s)[same_episode]
    dt = float(np.median(intervals))
    require(np.allclose(intervals, dt, rtol=ROW_JITTER, atol=0.0),
            f"{path}: rows must come at one rate; their intervals range over {intervals.min():g}-{intervals.max():g} s")
    return dt


def step_settings(path: Path, recording: Recording, sim) -> tuple[float, dict]:
    """The recording's row interval (s) and the ``sim`` settings whose env step it is: ``decimation`` physics steps
    of ``sim.physics_dt`` (ConfigError in one line where rows are uneven or the physics step does not divide them)."""
    dt = row_interval(path, recording)
    decimation = round(dt / sim.physics_dt)
    require(decimation >= 1 and abs(decimation * sim.physics_dt - dt) <= RATE_TOLERANCE * dt,
            f"{path}: rows every {dt:g} s, which the physics step sim.physics_dt={sim.physics_dt:g} s does not divide; "
            f"set a physics step that does (e.g. --config with sim.physics_dt: {dt / max(decimation, 1):g})")
    interval = sim.mass_matrix_interval if decimation % sim.mass_matrix_interval == 0 else 1
    return dt, {"decimation": decimation, "mass_matrix_interval": interval}


def check_held(path: Path, recording: Recording, roles: tuple[str, ...], held: list[bool]):
    """ConfigError where a joint the rig holds still (``sim.held_joints``) moves in the recording."""
    for j, role in enumerate(roles):
        if not held[j]:
            continue
        for episode in np.unique(recording.episode):
            rows = recording.episode == episode
            moved = float(np.ptp(recording.q[rows, j]))
            speed = float(np.nanmax(np.abs(recording.qd[rows, j]), initial=0.0))
            require(moved <= HELD_STILL and speed <= HELD_STILL,
                    f"{path}: the {role} joint moves in the recording (by {moved:g}, at up to {speed:g} per s) but "
                    f"sim.held_joints holds it still: fit a recording made with it held, or a preset that frees it")


def fitted_names(chosen: list[str], settable: list[str], on_joint: list[str]) -> list[str]:
    """``--fit``'s parameters (ConfigError in one line where one is unknown, named twice or a centre of mass on its
    joint), or by default every ``settable`` one but ``NOT_FITTED_BY_DEFAULT`` and those centres of mass."""
    names = chosen or [n for n in settable if n not in NOT_FITTED_BY_DEFAULT and n not in on_joint]
    require(len(set(names)) == len(names), f"--fit names a parameter twice: {' '.join(names)}")
    unknown = sorted(set(names) - set(settable))
    require(not unknown, f"--fit: unknown parameters {unknown}; this task's: {', '.join(settable)}")
    require(not set(names) & set(on_joint), f"--fit: {', '.join(set(names) & set(on_joint))}: those bodies' centre "
                                            "of mass lies on their joint, with no line to move along")
    return names


class WindowFit:
    """The batched fit of a ``Problem``: ``guesses`` x windows envs of one differentiable rollout, each window of each
    guess one env. Per guess the parameters ``theta`` (G, P): a parameter the stage sets (a mass, a centre of mass) as
    its log over the stage's value, one the stage leaves at 0 (damping, friction) in its unit (``Problem.units``),
    kept >= 0; per env its window's start ``starts`` (N, 2 free joints: those not held), in units of the signals'
    spread around the recorded one."""

    def __init__(self, problem: Problem, args: SysidArgs, steps: int):
        self.problem, self.guesses, self.horizon = problem, args.guesses, steps
        recording, stage = problem.recording, problem.stage
        self.starts = windows(recording, steps, problem.usable)[::args.window_stride]
        """The windows' first rows."""
        require(self.starts, f"{args.trajectory}: no stretch of {steps + 1} rows inside one episode and clear of the "
                             "joints' limits")
        self.num_windows = len(self.starts)
        self.num_envs = n = self.guesses * self.num_windows
        free = [not h for h in problem.held]
        variants = 1 + 2 * sum(free) + len(problem.names)
        batched = args.device != "cpu" if args.batched_jacobian is None else args.batched_jacobian
        self.copies = variants if batched else 1
        """Copies of the N envs in one rollout: the fit's own and, with ``batched_jacobian``, the Jacobian's columns'
        (each window's start or a parameter moved by ``JACOBIAN_STEP``)."""
        sim = {"gradients": True, **problem.sim}
        env = tasks.get(args.task).env_class(tasks.env_config(args.task, args.config, num_envs=n * self.copies,
                                                              device=args.device, sim=sim))
        self.rollout = DifferentiableRollout(env, self.horizon)
        self.device = device = self.rollout.device
        rows = np.array(self.starts)[:, None] + np.arange(self.horizon + 1)[None, :]  # (windows, H + 1)
        tensor = lambda x: torch.as_tensor(x, dtype=torch.float32, device=device)  # noqa: E731
        self.recorded = tensor(recording.q[rows]).repeat(self.guesses, 1, 1)  # (N, H + 1, joints)
        self.actions = tensor(recording.action[rows[:, :-1]]).repeat(self.guesses, 1, 1).transpose(0, 1)  # (H, N, A)
        self.scale = tensor(np.maximum(recording.q.std(axis=0), 1e-3))
        self.hinge = torch.tensor([not s for s in problem.sliders], device=device)
        self.linear = torch.tensor([stage[name] == 0.0 for name in problem.names], device=device)
        self.base = tensor([problem.units[name] for name in problem.names])
        estimated = velocities(recording, problem.dt, problem.sliders)
        self.velocity_scale = tensor(np.maximum(estimated.std(axis=0), 1e-3))
        self.qd_start = tensor(estimated[rows[:, 0]]).repeat(self.guesses, 1)
        self.joints = len(problem.roles)
        self.free_columns = torch.tensor(free + free, device=device).nonzero().squeeze(1)
        """The columns of (positions, velocities) that a window's start moves: those of the joints not held."""
        self.guess_of = torch.arange(n, device=device) // self.num_windows

    def first_guesses(self, seed: int, spread: float) -> tuple[torch.Tensor, torch.Tensor]:
        """The starting ``theta``, each parameter log-uniform within a factor 1 + ``spread`` of its start (guess 0:
        the start itself): the earlier fit's value (``Problem.start``) or the stage's (near 0 where that is 0); and
        the windows' ``starts`` as recorded."""
        generator = torch.Generator().manual_seed(seed)
        noise = ((torch.rand((self.guesses, len(self.problem.names)), generator=generator) * 2 - 1)
                 * math.log1p(spread)).to(self.device)
        noise[0] = 0.0
        start = torch.tensor([self.problem.start.get(name, self.problem.stage[name]) for name in self.problem.names],
                             device=self.device) / self.base
        log_start = torch.log(torch.where(self.linear, 1.0, start.clamp(min=1e-30)))
        theta = torch.where(self.linear, torch.where(start > 0, start * torch.exp(noise), noise.abs()),
                            log_start + noise)
        return theta, torch.zeros((self.num_envs, len(self.free_columns)), device=self.device)

    def physical(self, theta: torch.Tensor) -> torch.Tensor:
        """(G, P) parameters (SI) of the fitted variables."""
        return torch.where(self.linear, self.base * theta,
                           self.base * torch.exp(torch.where(self.linear, 0.0, theta)))

    def variants(self, theta: torch.Tensor, starts: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """The parameters and windows' starts of the fit itself, then of each forward difference of the Jacobian:
        each window's start's columns, then each parameter, moved by ``JACOBIAN_STEP``."""
        step_theta = JACOBIAN_STEP * torch.eye(theta.shape[1], device=self.device)
        step_starts = JACOBIAN_STEP * torch.eye(starts.shape[1], device=self.device)
        return ([(theta, starts)] + [(theta, starts + moved) for moved in step_starts]
                + [(theta + moved, starts) for moved in step_theta])

    def residuals(self, variants: list[tuple[torch.Tensor, torch.Tensor]]) -> tuple[torch.Tensor, Trajectory]:
        """One batched rollout of ``variants`` (at most ``copies``; padded with the first): each one's (N, (H + 1) x
        joints) normalized position errors of every window, stacked, and the rollout of the first."""
        variants = variants + variants[:1] * (self.copies - len(variants))
        n, joints = self.num_envs, self.joints
        values = self.physical(torch.cat([theta for theta, _ in variants]))
        params = {name: values[:, k].repeat_interleave(self.num_windows) for k, name in enumerate(self.problem.names)}
        starts = torch.cat([starts for _, starts in variants])
        moved = torch.zeros((n * self.copies, 2 * joints), device=self.device).index_copy(1, self.free_columns, starts)
        recorded = self.recorded.repeat(self.copies, 1, 1)
        q0 = recorded[:, 0] + moved[:, :joints] * self.scale
        qd0 = self.qd_start.repeat(self.copies, 1) + moved[:, joints:] * self.velocity_scale
        out = self.rollout(q0, qd0, actions=self.actions.repeat(1, self.copies, 1), params=params)
        r = (angle_error(out.q.transpose(0, 1), recorded, self.hinge) / self.scale).flatten(1).unflatten(0, (-1, n))
        first = Trajectory(*(x[:, :n] for x in (out.q, out.qd, out.obs, out.actions, out.rewards, out.end_reason)))
        return r, first

    def jacobians(self, variants: list[tuple[torch.Tensor, torch.Tensor]], first: torch.Tensor):
        """The residuals of every variant, ``first`` (the first ``copies``' already rolled out) and the others' (no
        gradient), and from them the residuals of the fit (N, K) and their Jacobians by forward differences, (N, K,
        S) in each window's start (S: its columns) and (N, K, P) in the parameters."""
        with torch.no_grad():
            later = [self.residuals(variants[i:i + self.copies])[0] for i in range(self.copies, len(variants),
                                                                                   self.copies)]
        r = torch.cat([first.detach(), *later])[:len(variants)]
        moved = ((r[1:] - r[:1]) / JACOBIAN_STEP).permute(1, 2, 0)
        columns = variants[0][1].shape[1]
        return r[0], moved[:, :, :columns], moved[:, :, columns:]

    def per_guess(self, r: torch.Tensor) -> torch.Tensor:
        """(G,) each guess's loss: half its windows' squared residuals."""
        return torch.zeros(self.guesses, device=self.device).index_add_(0, self.guess_of, 0.5 * r.pow(2).sum(dim=1))

    def schur(self, a: torch.Tensor, b: torch.Tensor, lam: torch.Tensor, extra: torch.Tensor | None = None):
        """Per window: A'A + lam, A'B, the parameters' normal matrix with the window's start eliminated, and
        (A'A + lam)^-1 [A'B, extra]."""
        ata = a.transpose(1, 2) @ a + lam[:, None, None] * torch.eye(a.shape[2], device=self.device)
        atb = a.transpose(1, 2) @ b
        solved = torch.linalg.solve(ata, atb if extra is None else torch.cat([atb, extra], dim=2))
        return ata, atb, b.transpose(1, 2) @ b - atb.transpose(1, 2) @ solved[:, :, :atb.shape[2]], solved

    def step(self, theta: torch.Tensor, starts: torch.Tensor, lm_lambda: torch.Tensor):
        """One Levenberg-Marquardt iteration of every guess (``lm_lambda`` (G,): each one's damping): the exact gradient
        through the simulator (one backward pass), the Jacobian's columns by forward differences (in the same batched
        rollout), then up to ``LM_TRIALS`` steps on ``theta`` and every window's start on that Jacobian, the damping
        times 4 after each that does not lower a guess's loss, kept where one does. The new theta, starts and lambdas,
        the best guess's loss, and the fall of the best guess's loss that Gauss-Newton predicts, over that loss
        (``predicted_fall``; 0 where its residuals are ``RESOLVED``)."""
        theta_leaf, starts_leaf = theta.clone().requires_grad_(), starts.clone().requires_grad_()
        variants = self.variants(theta_leaf, starts_leaf)
        first = self.residuals(variants[:self.copies])[0]
        loss = self.per_guess(first[0].detach())
        self.per_guess(first[0]).sum().backward()
        grad_theta, grad_starts = theta_leaf.grad, starts_leaf.grad
        _, a, b = self.jacobians(variants, first)
        with torch.no_grad():
            best = int(loss.nan_to_num(nan=math.inf).argmin())
            improved = torch.zeros(self.guesses, dtype=torch.bool, device=self.device)
            new_theta, new_starts, new_loss = theta, starts, loss
            for trial in range(LM_TRIALS):
                step_theta, step_starts, at_bound = self.solve(a, b, grad_theta, grad_starts, theta, lm_lambda)
                if trial == 0:
                    fall = self.predicted_fall(a, b, grad_theta, grad_starts, ~(at_bound & (theta <= 0.0)))
                trial_theta = theta + step_theta
                trial_theta = torch.where(self.linear, trial_theta.clamp(min=0.0), trial_theta)
                trial_starts = starts + step_starts
                trial_loss = self.per_guess(self.residuals([(trial_theta, trial_starts)])[0][0])
                better = ~improved & (trial_loss < loss)
                new_theta = torch.where(better[:, None], trial_theta, new_theta)
                new_starts = torch.where(better[self.guess_of][:, None], trial_starts, new_starts)
                new_loss = torch.where(better, trial_loss, new_loss)
                improved |= better
                lm_lambda = torch.where(improved, lm_lambda, lm_lambda * 4).clamp(*LM_LAMBDA_RANGE)
                if improved.all():
                    break
            lm_lambda = torch.where(improved, lm_lambda / 3, lm_lambda).clamp(*LM_LAMBDA_RANGE)
        resolved = float(loss[best]) <= 0.5 * RESOLVED**2 * first[0].shape[1] * self.num_windows
        return (new_theta, new_starts, lm_lambda, new_loss.min().item(),
                0.0 if resolved else float(fall[best] / loss[best].clamp(min=1e-30)))

    def solve(self, a: torch.Tensor, b: torch.Tensor, grad_theta: torch.Tensor, grad_starts: torch.Tensor,
              theta: torch.Tensor, lm_lambda: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Levenberg-Marquardt's step at damping ``lm_lambda`` on ``theta`` (G, P) and every window's start (N, S),
        each window's start eliminated (``schur``); a damping or a friction that the step would take below 0 goes to
        0 and the others' step is solved with it held there (returned: which, (G, P) bool)."""
        guess_of, size = self.guess_of, theta.shape[1]
        ata, atb, reduced, solve_ata = self.schur(a, b, lm_lambda[guess_of], grad_starts[:, :, None])
        eye = torch.eye(size, device=self.device)
        normal = torch.zeros((self.guesses, size, size), device=self.device).index_add_(0, guess_of, reduced)
        normal += lm_lambda[:, None, None] * eye
        rhs = grad_theta - torch.zeros_like(grad_theta).index_add_(
            0, guess_of, (atb.transpose(1, 2) @ solve_ata[:, :, -1:]).squeeze(2))
        step_theta = -torch.linalg.solve(normal, rhs)
        at_bound = self.linear & (theta + step_theta < 0.0)
        if at_bound.any():
            free, to_bound = ~at_bound, torch.where(at_bound, -theta, 0.0)
            coupled = rhs + (normal @ to_bound[:, :, None]).squeeze(2)
            normal = torch.where(free[:, :, None] & free[:, None, :], normal, eye)
            step_theta = torch.where(free, -torch.linalg.solve(normal, torch.where(free, coupled, 0.0)), to_bound)
        step_starts = -torch.linalg.solve(ata, grad_starts[:, :, None] + atb @ step_theta[guess_of][:, :, None])
        return step_theta, step_starts.squeeze(2), at_bound

    def predicted_fall(self, a: torch.Tensor, b: torch.Tensor, grad_theta: torch.Tensor, grad_starts: torch.Tensor,
                       free: torch.Tensor) -> torch.Tensor:
        """(G,) the fall of each guess's loss that an undamped Gauss-Newton step predicts, g' (J'J)^-1 g / 2 (each
        window's start eliminated, the parameters held at their bound of 0 (``free`` False) left out): near 0 at a
        minimum, whatever Levenberg-Marquardt's damping."""
        size, guess_of = grad_theta.shape[1], self.guess_of
        _, atb, reduced, solved = self.schur(a, b, torch.full((self.num_envs,), 1e-9, device=self.device),
                                             grad_starts[:, :, None])
        starts_part = 0.5 * (grad_starts[:, None, :] @ solved[:, :, -1:]).reshape(-1)
        normal = torch.zeros((self.guesses, size, size), device=self.device).index_add_(0, guess_of, reduced)
        rhs = grad_theta - torch.zeros_like(grad_theta).index_add_(
            0, guess_of, (atb.transpose(1, 2) @ solved[:, :, -1:]).squeeze(2))
        eye = torch.eye(size, device=self.device)
        normal = torch.where(free[:, :, None] & free[:, None, :], normal, eye)
        normal = normal + 1e-9 * normal.diagonal(dim1=1, dim2=2).amax(dim=1)[:, None, None] * eye
        rhs = torch.where(free, rhs, 0.0)
        theta_part = 0.5 * (rhs[:, None, :] @ torch.linalg.solve(normal, rhs[:, :, None])).reshape(-1)
        return torch.zeros(self.guesses, device=self.device).index_add_(0, guess_of, starts_part) + theta_part

    @torch.no_grad()
    def standard_errors(self, theta: torch.Tensor, starts: torch.Tensor):
        """Each guess's loss (G,), the best guess (a guess that diverged is never it), the standard errors of its
        ``theta`` (P,) and the rollout: the noise's variance (the residual per degree of freedom) times the inverse of
        the parameters' normal matrix (Gauss-Newton's, each window's start eliminated)."""
        variants = self.variants(theta, starts)
        first, out = self.residuals(variants[:self.copies])
        r, a, b = self.jacobians(variants, first)
        losses = self.per_guess(r)
        best = int(losses.nan_to_num(nan=math.inf).argmin())
        best_guess_rows = self.guess_of == best
        normal = self.schur(a[best_guess_rows], b[best_guess_rows],
                            torch.zeros(self.num_windows, device=self.device))[2].sum(dim=0)
        first_rows, free_joints = self.starts, len(self.free_columns) // 2  # a held joint's residuals are all 0
        shared = sum(later - earlier == self.horizon for earlier, later in zip(first_rows, first_rows[1:]))
        freedom = max((self.num_windows * (self.horizon + 1) - shared) * free_joints - theta.shape[1]
                      - self.num_windows * len(self.free_columns), 1)
        variance = 2 * float(losses[best]) / freedom
        # a direction the data do not see (an eigenvalue ~0) gives the parameters along it a huge error, not none
        eigenvalues, vectors = torch.linalg.eigh(normal.double())
        eigenvalues = eigenvalues.clamp(min=1e-12 * max(float(eigenvalues.max()), 1e-30))
        return losses, best, torch.sqrt(variance * (vectors.pow(2) / eigenvalues).sum(dim=1)).float(), out

    def result(self, args: SysidArgs, theta: torch.Tensor, starts: torch.Tensor, start_s: float):
        """The fit's result file (a dict), how many guesses fit within ``EQUALLY_GOOD`` of the best, and the best
        guess's simulated positions (H + 1, windows, joints); ``start_s``: when fitting began (``perf_counter``)."""
        problem, names, stage = self.problem, self.problem.names, self.problem.stage
        losses, best, theta_error, out = self.standard_errors(theta, starts)
        values = self.physical(theta)
        # a log-parameter's standard error is relative; a linear one's is in SI units
        error = torch.where(self.linear, self.base * theta_error, values[best] * theta_error)
        fitted = {name: float(values[best, k]) for k, name in enumerate(names)}
        standard_error = {name: float(error[k]) for k, name in enumerate(names)}
        best_windows = slice(best * self.num_windows, (best + 1) * self.num_windows)
        window_error = angle_error(out.q.transpose(0, 1), self.recorded, self.hinge)
        residual = window_error[best_windows].pow(2).mean(dim=(0, 1)).sqrt().cpu().numpy()
        seconds = round(time.perf_counter() - start_s, 2)
        result = {"task": args.task, "trajectory": str(args.trajectory), "seconds": seconds,
                  "windows": self.num_windows, "window_steps": self.horizon, "guesses": self.guesses,
                  "loss": float(losses[best]), "stage": {name: stage[name] for name in names}, "fitted": fitted,
                  "standard_error": standard_error,
                  "not_identified": [name for name in names if (fitted[name] > 0 or stage[name] > 0)
                                     and standard_error[name] > IDENTIFIED_WITHIN * max(fitted[name], stage[name])],
                  "residual_rms": {pos: float(r) for pos, r in
                                   zip(column_names(problem.roles, problem.sliders)[0], residual)},
                  "implausible": implausible(fitted, stage, problem.table)}
        equally_good = int((losses <= losses[best] * EQUALLY_GOOD).sum())
        return result, equally_good, out.q.detach()[:, best_windows].cpu().numpy()


def implausible(fitted: dict[str, float], stage: dict[str, float], table: tuple[Parameter, ...]) -> dict[str, str]:
    """The fitted values outside physical sense (``PLAUSIBLE_FACTOR``, ``COM_SPAN``), each with why."""
    flags = {}
    for p in (p for p in table if p.name in fitted and stage[p.name] > 0):
        value, base = fitted[p.name], stage[p.name]
        if p.quantity in (MASS, INERTIA_SCALE) and not 1 / PLAUSIBLE_FACTOR <= value / base <= PLAUSIBLE_FACTOR:
            flags[p.name] = f"{value / base:.3g}x the stage's, beyond {PLAUSIBLE_FACTOR:g}x either way"
        elif p.quantity is COM and not 0 <= value <= COM_SPAN * base:
            flags[p.name] = (f"{value:.3g} m from its joint, outside the stage's shape (0-{COM_SPAN * base:.3g} m)")
    return flags


def fit(args: SysidArgs) -> dict:
    """The fit (``SysidArgs``): prints its progress and result, writes the plot, the preset and the result file, and
    returns the result."""
    return fit_and_predict(args)[0]


def fit_and_predict(args: SysidArgs) -> tuple[dict, dict[str, np.ndarray]]:
    """``fit``, and the positions each predicted recording's episodes were simulated through (``predict``'s), by the
    recording's path."""
    check_args(args)
    problem = read_problem(args)
    told = chain.of(args.task, args.config, problem.names)
    for line in told.lines() if told else []:
        print(line)
    start = time.perf_counter()
    fitter, theta, starts, stages = fit_windows(problem, args, start)
    result, equally_good, simulated = fitter.result(args, theta, starts, start)
    result["iterations"], result["identifiability"] = stages, told.lines() if told else []
    report(result, equally_good)
    output = args.output or args.trajectory.with_name(args.trajectory.stem + "_sysid")
    labels = column_names(problem.roles, problem.sliders)[0]
    plot(output / "sysid_fit.png", problem.recording, fitter.starts, simulated, problem.dt, labels)
    result["prediction"], positions = predict_recordings(args, problem, result["fitted"], output)
    report_prediction(result["prediction"], labels)
    write_text(output / "sysid_result.yaml", yaml.safe_dump(result, sort_keys=False))
    preset = write_preset(output / "sysid_preset.yaml", args, problem.stage, result["fitted"], problem.table)
    print(f"wrote {output / 'sysid_fit.png'}, {output / 'sysid_result.yaml'}, the simulated recordings "
          f"{output / 'sysid_simulated_<n>.npz'} and {preset} (python train.py --task {args.task} --config {preset})")
    return result, positions


def predict_recordings(args: SysidArgs, problem: Problem, fitted: dict, output: Path) -> tuple[dict, dict]:
    """The fitted recording and each ``--validate`` one, every episode simulated from its first row (``predict``):
    their errors and simulated positions by path; each one's simulation written as ``sysid_simulated_<n>.npz`` (the
    recording's columns; NaN past an env's end) and plotted against it as ``sysid_prediction_<n>.png``."""
    labels = column_names(problem.roles, problem.sliders)[0]
    prediction, positions = {}, {}
    for number, path in enumerate([args.trajectory, *args.validate]):
        recording = problem.recording if number == 0 else read_trajectory(path, problem.roles, problem.sliders,
                                                                          problem.recording.action.shape[1])
        if number > 0:
            check_held(path, recording, problem.roles, problem.held)
            interval = row_interval(path, recording)
            require(abs(interval - problem.dt) <= RATE_TOLERANCE * problem.dt,
                    f"{path}: rows every {interval:g} s; they must come every {problem.dt:g} s, as the fitted "
                    "recording's")
        simulated, rms = predict(args, problem, fitted, recording)
        prediction[str(path)], positions[str(path)] = rms, simulated
        rows = np.full_like(recording.q, np.nan)
        for e, first in enumerate(first_rows(recording)):
            length = int((recording.episode == recording.episode[first]).sum())
            rows[first:first + length] = simulated[:length, e]
        write_trajectory(output / f"sysid_simulated_{number}.npz", replace(recording, q=rows, qd=np.full_like(rows,
                         np.nan)), problem.roles, problem.sliders)
        in_sequence = replace(recording, time_s=np.arange(len(recording.time_s)) * problem.dt)  # episodes side by side
        plot(output / f"sysid_prediction_{number}.png", in_sequence, first_rows(recording), simulated, problem.dt,
             labels)
    return prediction, positions


def check_args(args: SysidArgs):
    """ConfigError in one line for a setting no fit can run with."""
    require(args.trajectory is not None, "--trajectory FILE is required (a CSV or NPZ recording)")
    require(bool(args.window_steps) and min(*args.window_steps, args.window_stride, args.guesses, args.iterations) >= 1,
            "--window-steps (one length or more), --window-stride, --guesses and --iterations must be >= 1")
    require(args.spread >= 0 and 0 <= args.randomize < 1, "--spread must be >= 0 and --randomize in [0, 1)")
    require(0 <= args.tolerance < 1, "--tolerance must be in [0, 1): the loss's relative fall that counts as converged")


def fit_windows(problem: Problem, args: SysidArgs, start: float
                ) -> tuple[WindowFit, torch.Tensor, torch.Tensor, list[dict]]:
    """Levenberg-Marquardt on windows of each of ``args.window_steps`` in turn, each from the last one's parameters
    (the first from the starting guesses), until converged, stalled or ``args.iterations``, printing its progress;
    the last fit, its parameters and windows' starts, and per window length its iterations and how it ended."""
    theta, stages = None, []
    for steps in args.window_steps:
        fitter = WindowFit(problem, args, steps)
        first_theta, starts = fitter.first_guesses(args.seed, args.spread)
        theta = first_theta if theta is None else theta
        print(f"{args.task}: {len(problem.recording.time_s)} rows, {fitter.num_windows} windows of {steps} steps x "
              f"{args.guesses} guesses = {fitter.num_envs} envs on {fitter.device}; fitting "
              f"{', '.join(problem.names)}", flush=True)
        lm_lambda = torch.full((args.guesses,), INITIAL_LM_LAMBDA, device=fitter.device)
        losses, fall, stalled = [], math.inf, False
        for it in range(args.iterations):
            theta, starts, lm_lambda, best_loss, fall = fitter.step(theta, starts, lm_lambda)
            stalled = bool(losses) and best_loss >= losses[-1] and float(lm_lambda.min()) >= LM_LAMBDA_RANGE[1]
            losses.append(best_loss)
            print(f"  iteration {it + 1}/{args.iterations}: best loss {best_loss:.3e}, Gauss-Newton's predicted fall "
                  f"{fall:.1e} of it ({time.perf_counter() - start:.1f} s)", flush=True)
            if fall <= args.tolerance or stalled:
                break
        converged = fall <= args.tolerance
        stages.append({"window_steps": steps, "iterations": len(losses), "converged": converged,
                       "stalled": stalled and not converged, "predicted_fall": fall})
        if converged:
            print(f"  converged after {len(losses)} iterations", flush=True)
        elif stalled:
            print(f"  stalled after {len(losses)} iterations: no step lowers the loss, Levenberg-Marquardt's damping "
                  f"at its largest ({LM_LAMBDA_RANGE[1]:g}), though Gauss-Newton predicts a fall of {fall:.1e} of it: "
                  "the loss is at the rollouts' float resolution, or the Jacobian misleads", flush=True)
        else:
            print(f"  not converged in --iterations {args.iterations} (a step would lower the loss by {fall:.1e} of "
                  f"it, above --tolerance {args.tolerance:g}): raise --iterations, or go on with --from", flush=True)
    return fitter, theta, starts, stages


def arm_chain(problem: Problem) -> bool:
    """Whether the recording is of a chain of two arms or more on a held cart (a multi-arm rig's free swing): then the
    report gives each arm's error in its angle from upright too, as the rig's encoders measure it."""
    sliders = problem.sliders
    return len(sliders) > 2 and sliders[0] and problem.held[0] and not any(sliders[1:])


def arm_angles(q: np.ndarray) -> np.ndarray:
    """Each arm's angle from upright from a cart task's joint positions (..., 1 + arms): the sums of the joints'."""
    return np.cumsum(q[..., 1:], axis=-1)


def first_rows(recording: Recording) -> list[int]:
    """The first row of each episode."""
    return [int(np.flatnonzero(recording.episode == episode)[0]) for episode in np.unique(recording.episode)]


@torch.no_grad()
def predict(args: SysidArgs, problem: Problem, fitted: dict, recording: Recording) -> tuple[np.ndarray, list[dict]]:
    """Each episode of ``recording`` simulated with the ``fitted`` physics from its first row (recorded positions,
    recorded or differenced velocities) over its whole length under its recorded actions, one env per episode with
    no time limit: the positions (rows of the longest, episodes, joints; NaN past an episode's end or its env's end)
    and per episode its rows and RMS position error per joint (hinges' wrapped to (-pi, pi])."""
    firsts = first_rows(recording)
    lengths = [int((recording.episode == recording.episode[first]).sum()) for first in firsts]
    n, rows = len(firsts), max(lengths)
    env = tasks.get(args.task).env_class(tasks.env_config(args.task, args.config, num_envs=n, device=args.device,
                                                          sim=problem.sim, task={"episode_length_s": None}))
    env.set_physical_params(**{name: torch.full((n,), value, device=env.device) for name, value in fitted.items()})
    qd = velocities(recording, problem.dt, problem.sliders)
    state = np.stack([recording.q[firsts], qd[firsts]], axis=2).reshape(n, -1)  # per role: position, velocity
    env.set_state(torch.as_tensor(state, dtype=torch.float32, device=env.device))
    index = np.minimum(np.array(firsts)[None, :] + np.arange(rows)[:, None], len(recording.time_s) - 1)
    actions = torch.as_tensor(recording.action[index], dtype=torch.float32, device=env.device)
    lengths_on_device, ended = torch.tensor(lengths, device=env.device), torch.zeros(n, dtype=torch.bool,
                                                                                       device=env.device)
    positions, alive = [env.joint_state()[0].clone()], [~ended]
    for t in range(1, rows):  # on the env's device: one copy to the host at the end
        _, _, terminated, truncated, _ = env.step(actions[t - 1])
        ended |= terminated | truncated
        positions.append(env.joint_state()[0].clone())
        alive.append(~ended & (t < lengths_on_device))
    env.close()
    simulated = torch.stack(positions).cpu().numpy().astype(np.float64)
    simulated[~torch.stack(alive).cpu().numpy()] = np.nan
    simulated[0] = recording.q[firsts]
    hinge = torch.tensor([not s for s in problem.sliders])
    chain_of_arms = arm_chain(problem)
    rms = []
    for e, (first, length) in enumerate(zip(firsts, lengths)):
        mine, recorded = simulated[:length, e], recording.q[first:first + length]
        error = angle_error(torch.as_tensor(mine), torch.as_tensor(recorded), hinge).numpy()
        predicted = np.isfinite(error).all(axis=1)
        rms.append({"episode": int(recording.episode[first]), "rows": length, "predicted_rows": int(predicted.sum()),
                    "rms": [float(np.sqrt(np.mean(error[predicted, j] ** 2))) for j in range(error.shape[1])]})
        if chain_of_arms:  # each arm's angle from upright, as a rig's encoders on a chain measure it
            arms = angle_error(torch.as_tensor(arm_angles(mine)), torch.as_tensor(arm_angles(recorded)),
                               hinge[1:]).numpy()
            rms[-1]["arm_rms"] = [float(np.sqrt(np.mean(arms[predicted, j] ** 2))) for j in range(arms.shape[1])]
    return simulated, rms


def report_prediction(prediction: dict, labels: list[str]):
    """Each recording's episodes, simulated from their first rows: RMS position error per joint."""
    print("each episode simulated from its first row over its whole length (RMS error):")
    for path, episodes in prediction.items():
        print(f"  {path}")
        for e in episodes:
            cut = "" if e["predicted_rows"] == e["rows"] else f" (the env ended after {e['predicted_rows']} rows)"
            arms = "".join(f"; arm {k} from upright {value:.4g}" for k, value in enumerate(e.get("arm_rms", []), 1))
            print(f"    episode {e['episode']:g}, {e['rows']} rows: "
                  + ", ".join(f"{label} {value:.4g}" for label, value in zip(labels, e["rms"])) + arms + cut)


def report(result: dict, equally_good: int):
    """The fitted values against the stage's, the residual and what the recording does not pin down."""
    print(f"fit in {result['seconds']:.1f} s; {equally_good} of {result['guesses']} guesses fit within "
          f"{EQUALLY_GOOD:g}x of the best loss ({result['loss']:.3e})")
    print(f"{'parameter':<26} {'stage':>10} {'fitted':>10} {'standard error':>15} {'fitted/stage':>13}")
    for name, value in result["fitted"].items():
        stage, error = result["stage"][name], result["standard_error"][name]
        ratio = f"{value / stage:13.3f}" if stage else f"{'-':>13}"
        flags = (["not identified by the recording (its standard error)"] if name in result["not_identified"] else []
                 ) + ([f"outside physical sense: {result['implausible'][name]}"] if name in result["implausible"]
                      else [])
        print(f"{name:<26} {stage:10.4g} {value:10.4g} {error:15.2g} {ratio}" + "".join(f"  {f}" for f in flags))
    print("residual (RMS over the windows): " + ", ".join(f"{k} {v:.4g}" for k, v in result["residual_rms"].items()))


def plot(path: Path, recording: Recording, starts: list[int], simulated: np.ndarray, dt: float, labels: list[str]):
    """Recorded positions (lines) against each window's simulation (dots) for the best guess."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    joints = recording.q.shape[1]
    figure, axes = plt.subplots(joints, 1, figsize=(10, 2.2 * joints), sharex=True, squeeze=False)
    for j in range(joints):
        ax = axes[j, 0]
        for number, episode in enumerate(np.unique(recording.episode)):  # no line across a reset
            rows = recording.episode == episode
            ax.plot(recording.time_s[rows], recording.q[rows, j], color="0.4", lw=1,
                    label="recorded" if number == 0 else None)
        for w, first in enumerate(starts):
            times = recording.time_s[first] + dt * np.arange(simulated.shape[0])
            ax.plot(times, simulated[:, w, j], ".", ms=2, color="tab:red", label="simulated" if w == 0 else None)
        ax.set_ylabel(labels[j])
    axes[0, 0].legend(loc="upper right")
    axes[-1, 0].set_xlabel("time (s)")
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=100)
    plt.close(figure)


def write_preset(path: Path, args: SysidArgs, stage: dict, fitted: dict, table: tuple[Parameter, ...]) -> Path:
    """A preset whose randomization draws the fitted physics (times 1 -/+ ``args.randomize``) at every reset, on
    ``args.config``'s env settings where it names a preset, but for its held joints: a policy trains with them free."""
    low, high = 1.0 - args.randomize, 1.0 + args.randomize
    sections: dict = {}
    for p in (p for p in table if p.name in fitted):
        value, base = fitted[p.name], stage[p.name]
        draw = p.quantity.draw
        bounds = ([value / base * low, value / base * high] if draw == "scale"
                  else [value * low - base, value * high - base] if draw == "offset" else [value * low, value * high])
        if p.role is None:
            sections[p.quantity.section] = bounds
        else:
            sections.setdefault(p.quantity.section, {})[p.role] = bounds
    base = tasks.preset_overrides(args.task, args.config).get("env", {})
    held = base.get("sim", {}).pop("held_joints", [])
    preset = {"task": args.task, "env": merge(base, {"randomization": {"at": "reset", **sections}})}
    freed = f"; the joints the recording held ({', '.join(held)}) move here" if held else ""
    header = (f"# The physics tools.sysid fitted to {args.trajectory} (task {args.task}); randomization ranges "
              f"{args.randomize:g} around the fit{freed}.\n# python train.py --task {args.task} --config {path}\n")
    return write_text(path, header + yaml.safe_dump(preset, sort_keys=False))
