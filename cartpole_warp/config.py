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

    physics_dt: float = 1.0 / 120.0
    """Physics step (s)."""
    decimation: int = 2
    """Physics steps per env step; the env step is physics_dt * decimation seconds."""
    solver: Solver = "featherstone"
    """Newton solver: 'featherstone' (SolverFeatherstone) or 'mujoco' (SolverMuJoCo on mujoco-warp)."""
    mass_matrix_interval: int = 2
    """SolverFeatherstone recomputes the joint-space mass matrix every this many physics steps; must divide
    decimation (the captured step replays the choice). 2 with decimation 2 = once per env step, ~25% faster."""
    stage_path: str | None = None
    """USD stage holding the cartpole articulation (metres, kilograms; any up axis and prim names); None: the cartpole
    stage shipped with the package (usd/cartpole.usda)."""
    cart_joint: str = "cartJoint"
    """The stage's prismatic joint that moves the cart: its name, or its full prim path where the name repeats."""
    pole_joint: str = "poleJoint"
    """The stage's revolute joint of the pole: its name, or its full prim path where the name repeats."""
    capture: Capture = "auto"
    """Graph capture of the env step: 'auto' (CUDA, and CPU where measured faster: always), 'on' or 'off'."""
    cpu_threads: int = 0
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

    max_push_effort_n: float = 400.0
    """Cart force (N) for action 1; actions are clipped to [-1, 1] first."""
    reset_dist_m: float = 3.0
    """Terminate when |cart_pos| exceeds this (m)."""
    max_pole_angle_rad: float = math.pi / 2
    """Terminate when |pole_angle| exceeds this (rad)."""
    failure_reward: float = -2.0
    """Reward that replaces the shaped reward on the step that terminates."""
    alive_reward: float = 1.0
    """Constant term of the shaped reward."""
    pole_angle_weight: float = 1.0
    """Weight of pole_angle^2 (per rad^2) subtracted from the reward."""
    cart_vel_weight: float = 0.01
    """Weight of |cart_vel| (per m/s) subtracted from the reward."""
    pole_vel_weight: float = 0.005
    """Weight of |pole_vel| (per rad/s) subtracted from the reward."""
    reset_cart_pos_m: float = 1.0
    """Reset samples cart_pos ~ U(-this, this) (m)."""
    reset_cart_vel_m_s: float = 0.5
    """Reset samples cart_vel ~ U(-this, this) (m/s)."""
    reset_pole_angle_rad: float = 0.125 * math.pi
    """Reset samples pole_angle ~ U(-this, this) (rad)."""
    reset_pole_vel_rad_s: float = 0.25 * math.pi
    """Reset samples pole_vel ~ U(-this, this) (rad/s)."""
    episode_length_s: float | None = 10.0
    """Time limit (s) after which an episode is truncated; None for none (the tutorial has none)."""


@dataclass
class EnvConfig:
    """Everything ``make_env`` needs."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    num_envs: Annotated[int, tyro.conf.arg(aliases=("--num-envs",))] = 4096
    """Number of cartpoles simulated in parallel (per GPU when torchrun starts several processes)."""
    device: Annotated[str, tyro.conf.arg(aliases=("--device",))] = "cpu"
    """Warp / torch device: 'cpu', 'cuda' or 'cuda:N' (under torchrun each process takes cuda:$LOCAL_RANK)."""
    seed: Annotated[int, tyro.conf.arg(aliases=("--seed",))] = 0
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
        """Raise ConfigError naming the first invalid value; return self."""
        sim, task = self.sim, self.task
        require(self.num_envs >= 1, f"num_envs must be >= 1, got {self.num_envs!r}")
        require(sim.physics_dt > 0 and math.isfinite(sim.physics_dt),
                f"sim.physics_dt must be > 0 s, got {sim.physics_dt!r}")
        require(sim.decimation >= 1, f"sim.decimation must be >= 1, got {sim.decimation!r}")
        require(sim.mass_matrix_interval >= 1 and sim.decimation % sim.mass_matrix_interval == 0,
                f"sim.mass_matrix_interval must be >= 1 and divide sim.decimation ({sim.decimation}), "
                f"got {sim.mass_matrix_interval!r}")
        require(sim.cpu_threads >= 0, f"sim.cpu_threads must be >= 0, got {sim.cpu_threads!r}")
        require(task.episode_length_s is None or task.episode_length_s > 0,
                f"task.episode_length_s must be > 0 or None, got {task.episode_length_s!r}")
        require(task.max_push_effort_n >= 0, f"task.max_push_effort_n must be >= 0, got {task.max_push_effort_n!r}")
        return self


def require(ok: bool, message: str):
    """Raise ConfigError(message) unless ``ok``."""
    if not ok:
        raise ConfigError(message)


Config = TypeVar("Config")


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
