"""The env's configuration: dataclasses with a docstring under every field, and YAML presets.

The dataclass defaults are the single source of truth. A preset (``configs/<name>.yaml``) is a partial override of
them; tyro turns the same dataclasses into command-line flags (``--env.sim.solver mujoco``, the docstrings become
``--help``), and pydantic checks dicts (presets, a run's saved ``config.yaml``, ``make_env``'s keyword overrides)
against their types. The stage and the presets ship inside the wheel (``cartpole_warp/usd``,
``cartpole_warp/configs``) and sit at the top of a checkout (``usd/``, ``configs/``). No warp or newton here.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import math
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

import pydantic
import tyro
import yaml

Solver = Literal["featherstone", "mujoco"]
"""Newton solvers: ``SolverFeatherstone`` or ``SolverMuJoCo`` (on mujoco-warp)."""
Capture = Literal["auto", "on", "off"]
"""Graph capture of the env step."""
NO_TIME_LIMIT = 2**31 - 1
"""``max_episode_length`` of an env without a time limit (the largest int32 step counter)."""
MAX_EPISODE_LENGTH = NO_TIME_LIMIT - 1
"""The longest finite time limit in env steps that the kernels' int32 step counters hold."""
MAX_NUM_ENVS = 2**24
"""The most envs one process builds."""
BYTES_PER_ENV = 7_000
"""Peak memory per env while building the scene (measured on the CPU with 262,144 envs: ~6.9 kB)."""

Count = Annotated[int, pydantic.Strict(), pydantic.Field(ge=1)]
"""An integer >= 1 (not a bool, not a float)."""
NonNegativeInt = Annotated[int, pydantic.Strict(), pydantic.Field(ge=0)]
Positive = Annotated[float, pydantic.Field(gt=0, allow_inf_nan=False)]
"""A finite number > 0."""
NonNegative = Annotated[float, pydantic.Field(ge=0, allow_inf_nan=False)]
"""A finite number >= 0."""
Finite = Annotated[float, pydantic.Field(allow_inf_nan=False)]
Flag = Annotated[bool, pydantic.Strict()]
"""True or False (not 1, 0 or 'yes')."""
Name = Annotated[str, pydantic.Field(min_length=1)]
Seed = Annotated[int, pydantic.Strict(), pydantic.Field(ge=0, le=2**31 - 1 - 4096)]
"""A non-negative int32 (the kernels take it as one; torchrun adds the rank)."""

NO_UNKNOWN_KEYS = pydantic.ConfigDict(extra="forbid")
"""pydantic setting of every config dataclass: a dict (preset, saved config) with an unknown key is an error."""


class ConfigError(ValueError):
    """A configuration value or preset is invalid; the message names it."""


def data_path(folder: str, name: str = "") -> Path:
    """A file shipped with the package (``folder`` is 'usd' or 'configs'): inside the installed package, or at the
    top of the repository when running from a checkout."""
    packaged = Path(str(importlib.resources.files("cartpole_warp"))) / folder
    base = packaged if packaged.is_dir() else Path(__file__).resolve().parent.parent / folder
    return base / name if name else base


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
    decimation (the captured step replays the choice). 2 with decimation 2 = once per env step, ~25% faster."""
    stage_path: str | None = None
    """USD stage holding the cartpole articulation (metres, kilograms; any up axis and prim names); None: the cartpole
    stage shipped with the package (usd/cartpole.usda)."""
    cart_joint: Name = "cartJoint"
    """The stage's prismatic joint that moves the cart: its name, or its full prim path where the name repeats."""
    pole_joint: Name = "poleJoint"
    """The stage's revolute joint of the pole: its name, or its full prim path where the name repeats."""
    capture: Capture = "auto"
    """Graph capture of the env step: 'auto' (CUDA, and CPU where measured faster: always), 'on' or 'off'."""
    cpu_threads: NonNegativeInt = 0
    """On the CPU with featherstone, step this many shards of the envs in parallel threads (Warp runs each CPU
    kernel launch on one thread); 0: one per available core. Shards hold at least 512 envs; ignored on CUDA."""

    @property
    def env_dt(self) -> float:
        """Duration of one env step (s)."""
        return self.physics_dt * self.decimation

    @property
    def stage(self) -> Path:
        """The USD stage file to load."""
        return Path(self.stage_path) if self.stage_path else data_path("usd", "cartpole.usda")


@dataclass
class TaskConfig:
    """The tutorial's cartpole task: action scale, reward, termination, reset ranges, time limit.

    Every float field reaches the Warp kernels as a field of the same name (``kernels.TaskParams``)."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    max_push_effort_n: NonNegative = 400.0
    """Cart force (N) for action 1; actions are clipped to [-1, 1] first."""
    reset_dist_m: Positive = 3.0
    """Terminate when |cart_pos| exceeds this (m)."""
    max_pole_angle_rad: Positive = math.pi / 2
    """Terminate when |pole_angle| exceeds this (rad)."""
    failure_reward: Finite = -2.0
    """Reward that replaces the shaped reward on the step that terminates."""
    alive_reward: Finite = 1.0
    """Constant term of the shaped reward."""
    pole_angle_weight: NonNegative = 1.0
    """Weight of pole_angle^2 (per rad^2) subtracted from the reward."""
    cart_vel_weight: NonNegative = 0.01
    """Weight of |cart_vel| (per m/s) subtracted from the reward."""
    pole_vel_weight: NonNegative = 0.005
    """Weight of |pole_vel| (per rad/s) subtracted from the reward."""
    reset_cart_pos_m: NonNegative = 1.0
    """Reset samples cart_pos ~ U(-this, this) (m)."""
    reset_cart_vel_m_s: NonNegative = 0.5
    """Reset samples cart_vel ~ U(-this, this) (m/s)."""
    reset_pole_angle_rad: NonNegative = 0.125 * math.pi
    """Reset samples pole_angle ~ U(-this, this) (rad)."""
    reset_pole_vel_rad_s: NonNegative = 0.25 * math.pi
    """Reset samples pole_vel ~ U(-this, this) (rad/s)."""
    episode_length_s: Positive | None = 10.0
    """Time limit (s) after which an episode is truncated; None for none (the tutorial has none)."""


@dataclass
class EnvConfig:
    """Everything ``make_env`` needs."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    num_envs: Annotated[Count, tyro.conf.arg(aliases=("--num-envs",))] = 4096
    """Number of cartpoles simulated in parallel (per GPU when torchrun starts several processes)."""
    device: Annotated[str, tyro.conf.arg(aliases=("--device",))] = "cpu"
    """Warp / torch device: 'cpu', 'cuda' or 'cuda:N' (under torchrun each process takes cuda:$LOCAL_RANK)."""
    seed: Annotated[Seed, tyro.conf.arg(aliases=("--seed",))] = 0
    """Seed of the per-env reset RNG (and of torch in train.py; seed + rank under torchrun); the same seed gives the
    same trajectory."""
    sim: SimConfig = field(default_factory=SimConfig)
    task: TaskConfig = field(default_factory=TaskConfig)

    @property
    def max_episode_length(self) -> int:
        """Time limit in env steps (``NO_TIME_LIMIT`` when there is none)."""
        if self.task.episode_length_s is None:
            return NO_TIME_LIMIT
        return max(1, math.ceil(self.task.episode_length_s / self.sim.env_dt - 1e-9))

    def validate(self) -> EnvConfig:
        """Raise ConfigError naming the first invalid value and what is allowed; return self. Each field's type and
        range are written where it is defined; the checks here relate fields."""
        if isinstance(self.num_envs, int) and self.num_envs > MAX_NUM_ENVS:
            need_gb = self.num_envs * BYTES_PER_ENV / 1e9
            raise ConfigError(f"num_envs={self.num_envs:,} would need about {need_gb:,.0f} GB "
                              f"(~{BYTES_PER_ENV / 1e3:.0f} kB per env); at most {MAX_NUM_ENVS:,} per process")
        checked(self)
        sim, task = self.sim, self.task
        require(sim.decimation % sim.mass_matrix_interval == 0,
                f"sim.mass_matrix_interval={sim.mass_matrix_interval} must divide sim.decimation={sim.decimation}")
        require(task.reset_cart_pos_m < task.reset_dist_m,
                f"task.reset_cart_pos_m={task.reset_cart_pos_m:g} must be below "
                f"task.reset_dist_m={task.reset_dist_m:g} (else episodes end as they start)")
        require(task.reset_pole_angle_rad < task.max_pole_angle_rad,
                f"task.reset_pole_angle_rad={task.reset_pole_angle_rad:g} must be below task.max_pole_angle_rad="
                f"{task.max_pole_angle_rad:g} (else episodes end as they start)")
        if task.episode_length_s is not None:
            steps = task.episode_length_s / sim.env_dt
            require(steps <= MAX_EPISODE_LENGTH,
                    f"task.episode_length_s={task.episode_length_s:g} is {steps:,.0f} env steps; the step counters "
                    f"hold at most {MAX_EPISODE_LENGTH:,} ({MAX_EPISODE_LENGTH * sim.env_dt:,.0f} s): use None for "
                    "no limit")
        return self


def require(ok: bool, message: str):
    """Raise ConfigError(message) unless ``ok``."""
    if not ok:
        raise ConfigError(message)


Config = TypeVar("Config")


def checked(cfg: Config) -> Config:
    """``cfg`` checked against its field types and ranges (ConfigError naming the first bad field); returns it."""
    from_dict(type(cfg), dataclasses.asdict(cfg), "invalid config")
    return cfg


def from_dict(cls: type[Config], data: Any, where: str = "config") -> Config:
    """A ``cls`` dataclass tree from nested dicts, checked against the field types; unknown keys are errors.
    ConfigError names the first bad key, e.g. ``env.sim.solver: Input should be 'featherstone' or 'mujoco'``."""
    try:
        return pydantic.TypeAdapter(cls).validate_python(data)
    except pydantic.ValidationError as err:
        first = err.errors()[0]
        key = ".".join(str(part) for part in first["loc"])
        if first["type"] == "unexpected_keyword_argument":
            owner = cls
            for part in first["loc"][:-1]:
                owner = typing.get_type_hints(owner)[part]
            known = ", ".join(f.name for f in dataclasses.fields(owner))
            raise ConfigError(f"{where}: unknown config key {key!r}; valid keys here: {known}") from None
        raise ConfigError(f"{where}: {key}: {first['msg']} (got {first['input']!r})") from None


def merge(base: dict, overrides: dict) -> dict:
    """``base`` with ``overrides`` applied, nested dicts merged key by key."""
    out = dict(base)
    for key, value in overrides.items():
        out[key] = merge(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def override(cfg: Config, overrides: dict, where: str = "overrides") -> Config:
    """A copy of the dataclass ``cfg`` with a nested dict of ``overrides`` applied and checked."""
    if not isinstance(overrides, dict):
        raise ConfigError(f"{where}: expected a mapping, got {overrides!r}")
    return from_dict(type(cfg), merge(dataclasses.asdict(cfg), overrides), where)


def presets() -> list[str]:
    """Names of the presets shipped with the package."""
    return sorted(p.stem for p in data_path("configs").glob("*.yaml"))


def load_preset(preset: str) -> dict:
    """The overrides a preset holds, as a nested dict: a name under ``configs/`` or a path to a YAML file."""
    path = Path(preset)
    if path.suffix not in (".yaml", ".yml"):
        path = data_path("configs", f"{preset}.yaml")
        require(path.is_file(), f"unknown preset {preset!r}; known presets: {', '.join(presets())}")
    require(path.is_file(), f"config file {path} does not exist")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise ConfigError(f"cannot parse {path}: {err}") from None
    require(isinstance(data, dict), f"{path}: expected a mapping at the top level")
    return data


def env_config(preset: str = "default", **overrides) -> EnvConfig:
    """EnvConfig from the dataclass defaults, the preset's ``env`` section, then nested keyword overrides
    (``num_envs=64, sim={"solver": "mujoco"}``; None values are ignored)."""
    cfg = override(EnvConfig(), load_preset(preset).get("env", {}), f"preset {preset!r}")
    return override(cfg, {k: v for k, v in overrides.items() if v is not None}).validate()
