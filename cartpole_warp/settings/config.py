"""The config engine (machinery): constrained field types, checks of dicts against dataclasses, merges of partial
overrides, ``ConfigError``; and the dataclasses every env shares (``SimConfig``, ``TaskConfig``, ``EnvConfig``).

The dataclass defaults are the single source of truth. A task's own settings are a ``TaskConfig`` subclass in its
task module; ``EnvConfig[BalanceConfig]`` is the env configuration of that task. A preset (``configs/<name>.yaml``,
loaded and checked by ``presets``) is a partial override; tyro turns the same dataclasses into command-line flags
(``--env.sim.solver mujoco``, docstrings become ``--help``), and pydantic checks dicts (presets, a run's saved
``config.yaml``, keyword overrides) against their types, once at each boundary (``from_dict``). No warp or newton
here.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import re
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Generic, Literal, TypeVar

import pydantic

from .files import data_path

Solver = Literal["featherstone", "mujoco"]
"""Newton solvers: ``SolverFeatherstone`` or ``SolverMuJoCo`` (on mujoco-warp)."""
Switch = Literal["auto", "on", "off"]
"""A choice that 'auto' makes by device."""
Capture = Switch
"""Graph capture of the env step."""
Image = Literal["none", "rgb", "depth"]
"""What the policy sees: the task's state observations, or camera frames (``CameraConfig``)."""
NO_TIME_LIMIT = 2**31 - 1
"""``max_episode_length`` of an env without a time limit (the largest int32 step counter)."""
MAX_EPISODE_LENGTH = NO_TIME_LIMIT - 1
"""The longest finite time limit in env steps that the kernels' int32 step counters hold."""
MAX_NUM_ENVS = 2**24
"""The most envs one process builds."""
BYTES_PER_ENV = 7_000
"""Peak memory per env while building the scene: a bound rounded up from the peak measured on the CPU at 262,144
envs (commit d3ad158)."""
MAX_ACTION_DELAY_STEPS = 1000
"""The longest action delay (env steps) a config may ask for: each env keeps that many past actions."""


def _numpy_scalar(value: Any) -> Any:
    """numpy's integer and floating scalars as Python ints and floats (bools and strings stay what they are, and the
    strict number types below refuse them)."""
    if isinstance(value, numbers.Integral) and not isinstance(value, (bool, int)):
        return int(value)
    if isinstance(value, numbers.Real) and not isinstance(value, (bool, int, float)):
        return float(value)
    return value


Number = pydantic.BeforeValidator(_numpy_scalar)
"""Lets numpy scalars of the right kind through the strict types."""
Count = Annotated[int, pydantic.Field(ge=1, strict=True), Number]
"""An integer >= 1 (not a bool, a float or a string)."""
NonNegativeInt = Annotated[int, pydantic.Field(ge=0, strict=True), Number]
Positive = Annotated[float, pydantic.Field(gt=0, allow_inf_nan=False, strict=True), Number]
"""A finite number > 0 (an int or a float; not a bool or a string)."""
NonNegative = Annotated[float, pydantic.Field(ge=0, allow_inf_nan=False, strict=True), Number]
"""A finite number >= 0."""
Finite = Annotated[float, pydantic.Field(allow_inf_nan=False, strict=True), Number]
"""A finite number."""
Fraction = Annotated[float, pydantic.Field(ge=0, le=1, strict=True), Number]
"""A number in [0, 1]."""
Flag = Annotated[bool, pydantic.Strict()]
"""True or False (not 1, 0 or 'yes')."""
Name = Annotated[str, pydantic.Field(min_length=1)]
MAX_SEED = 2**31 - 1 - 4096
"""The largest seed: an int32 once torchrun has added the rank."""
Seed = Annotated[int, pydantic.Field(ge=0, le=MAX_SEED, strict=True), Number]
"""A non-negative int32 (the kernels take it as one; torchrun adds the rank)."""


def check_seed(seed: Any) -> None:
    """ValueError unless ``seed`` is a whole number in [0, MAX_SEED] (a bool is not)."""
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or not 0 <= seed <= MAX_SEED:
        raise ValueError(f"seed: expected a whole number in [0, {MAX_SEED}] or None, got {seed!r}")

Range = tuple[Finite, Finite]
"""(low, high): a uniform draw from [low, high]; low == high fixes the value."""
Randomize = Literal["reset", "startup"]
"""When each env's physics is drawn: at each of its episode starts, or once (at construction and ``reset()``)."""

NO_UNKNOWN_KEYS = pydantic.ConfigDict(extra="forbid")
"""pydantic setting of every config dataclass: a dict (preset, saved config) with an unknown key is an error."""


class ConfigError(ValueError):
    """A configuration value or preset is invalid; the message names it."""


class StageError(ConfigError):
    """The USD stage is missing, unreadable or lacks the task's joints."""


@dataclass
class SimConfig:
    """Physics: stage, solver and timing."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    physics_dt: Positive = 1.0 / 120.0
    """Physics step (s)."""
    decimation: Count = 2
    """Physics steps per env step; the env step is physics_dt * decimation seconds."""
    solver: Solver = "featherstone"
    """Newton solver: 'featherstone' (SolverFeatherstone) or 'mujoco' (SolverMuJoCo on mujoco-warp)."""
    mass_matrix_interval: Count = 2
    """SolverFeatherstone recomputes the joint-space mass matrix every this many physics steps; must divide
    decimation (the captured step replays the choice)."""
    stage_path: Name | None = None
    """USD stage holding the robot's articulation (metres, kilograms; any up axis and prim names): a path, or the name
    of a stage in the package's usd/ folder (``multiarm_pendulum.usda``); None: the task's own stage (an empty path is
    refused)."""

    @property
    def stage_file(self) -> Path | None:
        """``stage_path`` as a file: the path where one is there, else the package's stage of that name."""
        if self.stage_path is None or Path(self.stage_path).exists():
            return None if self.stage_path is None else Path(self.stage_path)
        packaged = data_path("usd", self.stage_path)
        return packaged if packaged.is_file() else Path(self.stage_path)
    held_joints: list[Name] = field(default_factory=list)
    """Joint roles held still, as a clamp holds a rig's cart: the body the role's joint moves is kinematic (Newton's
    ``BodyFlags.KINEMATIC``: SolverFeatherstone gives its joint no acceleration and keeps its position, whatever the
    forces on it), and its velocity is zeroed before each env step's physics. SolverFeatherstone only."""
    capture: Capture = "auto"
    """Graph capture of the env step: 'auto' (captured on every device: replaying a graph beats launching each kernel,
    on the CPU too; docs/benchmarks.md), 'on' or 'off'."""
    cpu_threads: NonNegativeInt = 0
    """On the CPU with featherstone, step this many shards of the envs in parallel threads (Warp runs each CPU
    kernel launch on one thread); 0: one per available core. Shards hold at least 512 envs; ignored on CUDA."""
    divergence_limit: Positive = 1000.0
    """A joint position or velocity (m or rad, m/s or rad/s) beyond this ends that env's episode as 'diverged_state'
    with reward 0, like a non-finite one: far beyond what any task reaches, it keeps runaway physics (e.g. an extreme
    randomized mass) out of the observations, the rewards and the policy's normaliser."""
    tile_gemm: Switch = "auto"
    """SolverFeatherstone's joint-space mass matrix and its Cholesky factor through Warp's tile API (Newton's
    ``use_tile_gemm``: a block of threads per articulation, only the diagonal blocks of the body mass matrix) instead
    of its dense one-thread-per-articulation products. 'auto': on CUDA, off on the CPU; 'on' on the CPU steps one shard
    in one thread (Warp's CPU tile kernels share one memory arena between threads). The two paths round differently, so
    a seed's run differs between them. docs/benchmarks.md has the measurements behind 'auto'."""
    gradients: Flag = False
    """Compile the adjoint (gradient) code of Newton's modules that the env loads too, to differentiate through the
    physics with ``wp.Tape``; without it a first build compiles faster (the env never needs gradients)."""

    @property
    def env_dt(self) -> float:
        """Duration of one env step (s)."""
        return self.physics_dt * self.decimation

    def tiles(self, device: str) -> bool:
        """Whether SolverFeatherstone takes the tile path (``tile_gemm``) on ``device``."""
        return self.solver == "featherstone" and (self.tile_gemm == "on"
                                                  or self.tile_gemm == "auto" and device.startswith("cuda"))


Point = tuple[Finite, Finite, Finite]


@dataclass
class CameraConfig:
    """One camera per env (Newton's ray-traced ``SensorCamera``, rendered on the env's device after each step): with
    ``image`` 'rgb' or 'depth' the policy observes its last ``frame_stack`` frames instead of the task's state, which
    stays available to the critic (``BatchedEnv.state_obs_buf``). The camera looks from ``eye_m`` at ``target_m`` (Z
    up), in each env's own frame."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    image: Image = "none"
    """'none' (the policy sees the task's state), 'rgb' (uint8 colour, 3 channels a frame) or 'depth' (float32
    distance along each pixel's ray in metres, 1 channel a frame; 0 where the ray hits nothing)."""
    width_px: Count = 64
    """Image width (pixels)."""
    height_px: Count = 64
    """Image height (pixels)."""
    fov_rad: Annotated[float, pydantic.Field(gt=0, lt=math.pi, allow_inf_nan=False, strict=True), Number] = 1.0
    """Vertical field of view (rad), in (0, pi)."""
    eye_m: Point = (5.0, 0.0, 0.5)
    """Camera position (m) in the env's frame."""
    target_m: Point = (0.0, 0.0, 0.5)
    """The point the camera looks at (m); the image's up is the world's +Z."""
    frame_stack: Count = 3
    """Frames per observation, oldest first (a reset fills them with its first frame)."""
    min_width_px: NonNegative = 1.5
    """Box and capsule shapes thinner than this many pixels (at the target's distance) are drawn that thick, so that a
    thin pole stays visible at low resolution; render only (a cart task has no contacts, and masses and inertias are
    the stage's). 0: the stage's sizes."""

    @property
    def enabled(self) -> bool:
        """Whether the policy sees camera frames (``image`` not 'none'): the one test of it."""
        return self.image != "none"

    @property
    def channels(self) -> int:
        """Channels of one frame."""
        return 3 if self.image == "rgb" else 1

    def validate(self) -> None:
        forward = [t - e for t, e in zip(self.target_m, self.eye_m)]
        require(math.hypot(*forward) > 1e-6, f"camera.target_m={self.target_m} must differ from camera.eye_m")
        require(math.hypot(forward[0], forward[1]) > 1e-6 * math.hypot(*forward),
                f"camera.eye_m={self.eye_m} -> target_m={self.target_m} looks straight up or down; the image's up "
                "is the world's +Z, so the camera must look sideways")


@dataclass
class RandomizationConfig:
    """Domain randomization: each env draws its own physics from these ranges with its own RNG (seeded by ``seed``).
    Empty by default: every env simulates the stage as authored. A per-role entry is keyed by the task's joint role
    ('cart', 'pole', ...) and changes the body that role's joint moves (or the joint itself)."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    at: Randomize = "reset"
    """'reset': each env draws new physics at every episode start; 'startup': once, when the env is built and on
    every ``reset()``."""
    mass_scale: dict[str, Range] = field(default_factory=dict)
    """Per role: factor on the mass of the role's body, and on its inertia (same shape, other density)."""
    inertia_scale: dict[str, Range] = field(default_factory=dict)
    """Per role: a further factor on the body's inertia about its centre of mass (another shape at the same mass;
    ``mass_scale``'s factor applies too)."""
    com_offset_m: dict[str, Range] = field(default_factory=dict)
    """Per role: shift (m) of the body's centre of mass along the line from its joint to it (the inertia about the
    centre of mass stays; the inertia about the joint follows)."""
    joint_damping: dict[str, Range] = field(default_factory=dict)
    """Per role: viscous damping of the joint (N s/m for a slider, N m s/rad for a hinge), applied by the solver."""
    joint_friction: dict[str, Range] = field(default_factory=dict)
    """Per role: Coulomb friction of the joint (N or N m), -friction * tanh(velocity / 0.01) applied before each
    physics step."""
    actuator_scale: Range | None = None
    """Factor on the task's joint forces (the actuator strength; 1 is the task's own)."""
    gravity_m_s2: Range | None = None
    """Gravity's magnitude (m/s^2), along the stage's gravity direction."""
    action_delay_steps: Annotated[NonNegativeInt, pydantic.Field(le=MAX_ACTION_DELAY_STEPS)] = 0
    """Each env applies the action of d env steps ago, d drawn from {0, ..., this}; no force before the first (each
    env keeps this many past actions)."""
    obs_noise_std: NonNegative = 0.0
    """Standard deviation of the Gaussian noise added to every observation element (in its units)."""

    @property
    def on(self) -> bool:
        """Whether anything is randomized."""
        return self != RandomizationConfig(at=self.at)

    def validate(self, roles: tuple[str, ...]) -> None:
        """ConfigError for a range with low > high, out of its bounds, or keyed by a role the task does not have."""
        per_role = {"mass_scale": 0.0, "inertia_scale": 0.0, "com_offset_m": None, "joint_damping": 0.0,
                    "joint_friction": 0.0}
        for name, low_bound in per_role.items():
            for role, bounds in getattr(self, name).items():
                require(role in roles, f"randomization.{name}: unknown joint role {role!r}; this task's roles: "
                                       f"{', '.join(roles)}")
                check_range(f"randomization.{name}.{role}", bounds, low_bound,
                            strict=name in ("mass_scale", "inertia_scale"))
        for name in ("actuator_scale", "gravity_m_s2"):
            if getattr(self, name) is not None:
                check_range(f"randomization.{name}", getattr(self, name), 0.0, strict=False)


def check_range(key: str, bounds: tuple[float, float], low_bound: float | None, strict: bool):
    """ConfigError unless ``low <= high`` and ``low`` is above ``low_bound`` (``strict``) or at least it."""
    low, high = bounds
    require(low <= high, f"{key}: low {low:g} is above high {high:g}")
    if low_bound is not None:
        ok = low > low_bound if strict else low >= low_bound
        require(ok, f"{key}: low {low:g} must be {'>' if strict else '>='} {low_bound:g}")


@dataclass
class TaskConfig:
    """What every task's settings hold; a task module subclasses it with its own fields (every float field reaches
    the task's Warp functions under its own name, see ``kernels.kernel_constants``)."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    episode_length_s: Positive | None = 10.0
    """Time limit (s) after which an episode is truncated; None for none."""

    @property
    def has_time_limit(self) -> bool:
        """Whether episodes are truncated at ``episode_length_s``."""
        return self.episode_length_s is not None

    def validate(self, env: EnvConfig) -> None:
        """ConfigError for values of this task that do not fit together (its fields' own ranges are checked by their
        types); nothing to check by default."""


TaskT = TypeVar("TaskT", bound=TaskConfig)


@dataclass
class EnvConfig(Generic[TaskT]):
    """Everything an env needs; ``task`` is the task's own ``TaskConfig`` subclass."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    num_envs: Count = 4096
    """Number of robots simulated in parallel (per GPU when torchrun starts several processes)."""
    device: str = "cpu"
    """Warp / torch device: 'cpu', 'cuda' or 'cuda:N' (torchrun: cuda:$LOCAL_RANK in each process)."""
    seed: Seed = 0
    """Seed of the per-env reset RNG (and of torch in train.py; seed + rank under torchrun); the same seed gives the
    same trajectory."""
    sim: SimConfig = field(default_factory=SimConfig)
    randomization: RandomizationConfig = field(default_factory=RandomizationConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    verbose: Flag = False
    """Let Warp print while the env is built: its greeting and a line per module loaded or compiled (by default the
    library prints nothing)."""
    task: TaskT = None  # type: ignore[assignment]  # the task's settings: always given (tasks.env_config builds it)

    @property
    def max_episode_length(self) -> int:
        """Time limit in env steps (``NO_TIME_LIMIT`` when there is none)."""
        if not self.task.has_time_limit:
            return NO_TIME_LIMIT
        return max(1, math.ceil(self.task.episode_length_s / self.sim.env_dt - 1e-9))

    def validate(self) -> EnvConfig[TaskT]:
        """Raise ConfigError naming the first invalid value and what is allowed; return self. Each field's type and
        range are checked where dicts become configs (``from_dict``); the checks here relate fields."""
        sim, limit_s = self.sim, self.task.episode_length_s
        check_device_name(self.device)
        if sim.stage_file is not None and not sim.stage_file.is_file():
            raise StageError(f"USD stage {'is a folder' if sim.stage_file.is_dir() else 'not found'}: "
                             f"{sim.stage_path}")
        require(self.num_envs <= MAX_NUM_ENVS,
                f"num_envs={self.num_envs:,} would need about {self.num_envs * BYTES_PER_ENV / 1e9:,.0f} GB "
                f"(~{BYTES_PER_ENV / 1e3:.0f} kB per env); at most {MAX_NUM_ENVS:,} per process")
        history = self.num_envs * (self.randomization.action_delay_steps + 1)
        require(history < 2**31, f"randomization.action_delay_steps={self.randomization.action_delay_steps} with "
                                 f"num_envs={self.num_envs:,} is an action history of {history:,} entries "
                                 f"(~{history * 4 / 1e9:,.1f} GB per action); Warp's arrays hold at most 2**31 - 1")
        require(sim.tile_gemm != "on" or sim.solver == "featherstone",
                "sim.tile_gemm='on' is SolverFeatherstone's tile path; sim.solver='mujoco' has none")
        require(not sim.held_joints or sim.solver == "featherstone",
                f"sim.held_joints={sim.held_joints} needs sim.solver='featherstone' (its kinematic bodies)")
        require(sim.decimation % sim.mass_matrix_interval == 0,
                f"sim.mass_matrix_interval={sim.mass_matrix_interval} must divide sim.decimation={sim.decimation}")
        if limit_s is not None:
            steps = limit_s / sim.env_dt
            require(steps <= MAX_EPISODE_LENGTH,
                    f"task.episode_length_s={limit_s:g} is {steps:,.0f} env steps; the step counters hold at most "
                    f"{MAX_EPISODE_LENGTH:,} ({MAX_EPISODE_LENGTH * sim.env_dt:,.0f} s): use None for no limit")
        self.camera.validate()
        self.task.validate(self)
        return self


def require(ok: bool, message: str):
    """Raise ConfigError(message) unless ``ok``."""
    if not ok:
        raise ConfigError(message)


def check_device_name(device: str):
    """ConfigError naming the valid devices unless ``device`` is 'cpu', 'cuda' or 'cuda:N' (whether it exists here is
    ``runtime.resolve_device``'s to say)."""
    require(str(device) in ("cpu", "cuda") or re.fullmatch(r"cuda:\d+", str(device)) is not None,
            f"unknown device {device!r}; use 'cpu', 'cuda' (the first GPU) or 'cuda:N'")


Config = TypeVar("Config")


def _field_type(owner: Any, name: str) -> Any:
    """The type of field ``name`` of the dataclass ``owner`` (a generic alias such as ``EnvConfig[X]`` resolved)."""
    origin = typing.get_origin(owner) or owner
    hint = typing.get_type_hints(origin)[name]
    bindings = dict(zip(getattr(origin, "__parameters__", ()), typing.get_args(owner)))
    if isinstance(hint, TypeVar):
        hint = bindings.get(hint, hint)
    elif dataclasses.is_dataclass(typing.get_origin(hint)):  # e.g. EnvConfig[TaskT] inside TrainConfig[X]
        hint = typing.get_origin(hint)[tuple(bindings.get(arg, arg) for arg in typing.get_args(hint))]
    return typing.get_origin(hint) if typing.get_origin(hint) is Annotated else hint


def checked(cfg: Config) -> Config:
    """``cfg`` (built in code or by tyro, which checks no ranges) checked against its field types and ranges; returns
    it (ConfigError naming the first bad field)."""
    from_dict(config_type(cfg), dataclasses.asdict(cfg), "invalid config")
    return cfg


def config_type(cfg: Any) -> Any:
    """The dataclass of ``cfg``, parametrized by the types its generic fields hold (``EnvConfig[BalanceConfig]``)."""
    cls = type(cfg)
    if not getattr(cls, "__parameters__", ()):
        return cls
    hints, bound = typing.get_type_hints(cls), {}
    for f in dataclasses.fields(cls):
        hint, value = hints[f.name], getattr(cfg, f.name)
        if isinstance(hint, TypeVar):
            bound[hint] = type(value)
        elif dataclasses.is_dataclass(value) and typing.get_args(hint):
            bound.update(zip(typing.get_args(hint), typing.get_args(config_type(value))))
    return cls[tuple(bound[p] for p in cls.__parameters__)]


def config_errors(cls: type[Config], data: Any, key_prefix: str = "") -> list[str]:
    """Every type error and unknown key of ``data`` as a ``cls`` dataclass tree, each naming its key (after
    ``key_prefix``, where ``data`` sits in a larger file), e.g. ``env.sim.solver: Input should be 'featherstone' or
    'mujoco'``; empty when ``data`` is valid."""
    return _validated(cls, data, key_prefix)[1]


@functools.cache
def _adapter(cls: type[Config]) -> pydantic.TypeAdapter:
    """pydantic's validator of ``cls``, built once per class (building it is the slow part)."""
    return pydantic.TypeAdapter(cls)


def _validated(cls: type[Config], data: Any, key_prefix: str) -> tuple[Config | None, list[str]]:
    try:
        return _adapter(cls).validate_python(data), []
    except pydantic.ValidationError as err:
        return None, [_error_line(cls, error, key_prefix) for error in err.errors()]


def _error_line(cls: type[Config], error: Any, key_prefix: str) -> str:
    key = key_prefix + ".".join(str(part) for part in error["loc"])
    if error["type"] != "unexpected_keyword_argument":
        return f"{key}: {error['msg']} (got {error['input']!r})"
    owner = cls
    for part in error["loc"][:-1]:
        owner = _field_type(owner, part)
    known = ", ".join(f.name for f in dataclasses.fields(typing.get_origin(owner) or owner))
    return f"unknown config key {key!r}; valid keys here: {known}"


def refuse_present(cannot: str, problems: dict[str, bool]) -> None:
    """ConfigError '<cannot> with A; B' naming every problem present (``problems``: each in words, with whether it
    is), if any: ``refuse_present("--learner shac cannot train cartpole-balance", {...})``."""
    named = [what for what, present in problems.items() if present]
    require(not named, f"{cannot} with {'; '.join(named)}")


def raise_config_errors(where: str, errors: list[str]) -> None:
    """ConfigError naming every one of ``errors`` (``config_errors``) in one line, if there are any."""
    require(not errors, f"{where}: {' | '.join(errors)}")


def from_dict(cls: type[Config], data: Any, where: str = "config", key_prefix: str = "") -> Config:
    """A ``cls`` dataclass tree from nested dicts, checked against the field types; unknown keys are errors.
    ConfigError names every bad key (``config_errors``)."""
    cfg, errors = _validated(cls, data, key_prefix)
    raise_config_errors(where, errors)
    return cfg


def merge(base: dict, overrides: dict) -> dict:
    """``base`` with ``overrides`` applied, nested dicts merged key by key."""
    out = dict(base)
    for key, value in overrides.items():
        out[key] = merge(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def apply_overrides(config: object, overrides: dict) -> None:
    """Set ``overrides`` (nested dicts, as a preset's sections) on the dataclass tree ``config`` in place: a dict
    into a field holding a dataclass recurses, any other value replaces the field's."""
    for key, value in overrides.items():
        current = getattr(config, key)
        if isinstance(value, dict) and dataclasses.is_dataclass(current):
            apply_overrides(current, value)
        else:
            setattr(config, key, value)


def stray_fields(config: object, prefix: str = "") -> list[str]:
    """The dotted names of the attributes set on the dataclass tree ``config`` that none of its dataclasses has as a
    field (a misspelt setting written by attribute)."""
    names = {f.name for f in dataclasses.fields(config)}
    stray = [f"{prefix}{name}" for name in vars(config) if name not in names and not name.startswith("__")]
    for name in sorted(names):
        value = getattr(config, name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            stray += stray_fields(value, f"{prefix}{name}.")
    return stray


def changes(before: dict, after: dict) -> dict:
    """The nested leaves of ``after`` (``dataclasses.asdict`` of a config) whose values differ from ``before``'s."""
    out = {}
    for key, value in after.items():
        if isinstance(value, dict) and isinstance(before.get(key), dict):
            if inner := changes(before[key], value):
                out[key] = inner
        elif before.get(key) != value:
            out[key] = value
    return out


def overrides_dict(overrides: Any, where: str) -> dict:
    """``overrides`` checked to be a mapping (ConfigError naming ``where`` otherwise)."""
    require(isinstance(overrides, dict), f"{where} expected a mapping, got {overrides!r}")
    return overrides
