"""Configuration: dataclasses with documented fields, YAML presets as partial overrides.

The dataclass defaults are the single source of truth. A preset (``configs/<name>.yaml``) overrides
some of them; ``set_field(cfg, "env.sim.physics_dt", "0.01")`` overrides one more from a command line.
This module imports neither warp nor newton.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path

import yaml

REPO_ROOT = Path(__file__).resolve().parent.parent
CONFIG_DIR = REPO_ROOT / "configs"
DEFAULT_STAGE = REPO_ROOT / "usd" / "cartpole.usda"
SOLVERS = ("featherstone", "mujoco")


class ConfigError(ValueError):
    """A configuration value or preset is invalid; the message names it."""


@dataclass
class SimConfig:
    """Physics timing and solver."""

    physics_dt: float = 1.0 / 120.0
    """Physics step (s)."""
    decimation: int = 2
    """Physics steps per env step; the env step is physics_dt * decimation seconds."""
    solver: str = "featherstone"
    """Newton solver: 'featherstone' (SolverFeatherstone) or 'mujoco' (SolverMuJoCo on mujoco-warp)."""
    mass_matrix_interval: int = 2
    """SolverFeatherstone recomputes the joint-space mass matrix every this many physics steps; must divide
    decimation (the captured step replays the choice). 2 with decimation 2 = once per env step, ~25% faster."""
    stage_path: str = str(DEFAULT_STAGE)
    """USD stage holding the cartpole articulation (joints 'cartJoint' and 'poleJoint')."""
    capture: str = "auto"
    """Graph capture of the env step: 'auto' (CUDA, and CPU where measured faster: always), 'on' or 'off'."""
    cpu_threads: int = 0
    """On the CPU with featherstone, step this many shards of the envs in parallel threads (Warp runs each CPU
    kernel launch on one thread); 0: one per available core. Shards hold at least 512 envs; ignored on CUDA."""

    @property
    def env_dt(self) -> float:
        """Duration of one env step (s)."""
        return self.physics_dt * self.decimation


@dataclass
class TaskConfig:
    """The tutorial's cartpole task: action scale, reward, termination, reset ranges, time limit."""

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
    reset_pole_angle_rad: float = 0.125 * math.pi
    """Reset samples pole_angle ~ U(-this, this) (rad)."""
    reset_cart_vel_m_s: float = 0.5
    """Reset samples cart_vel ~ U(-this, this) (m/s)."""
    reset_pole_vel_rad_s: float = 0.25 * math.pi
    """Reset samples pole_vel ~ U(-this, this) (rad/s)."""
    episode_length_s: float | None = 10.0
    """Time limit (s) after which an episode is truncated; null for none (the tutorial has none)."""


@dataclass
class EnvConfig:
    """Everything ``make_env`` needs."""

    num_envs: int = 4096
    """Number of cartpoles simulated in parallel."""
    device: str = "cpu"
    """Warp / torch device: 'cpu' or 'cuda:N'."""
    seed: int = 0
    """Seed of the per-env reset RNG; the same seed gives the same trajectory."""
    sim: SimConfig = field(default_factory=SimConfig)
    task: TaskConfig = field(default_factory=TaskConfig)

    @property
    def max_episode_length(self) -> int:
        """Time limit in env steps (2**31 - 1 when there is none)."""
        if self.task.episode_length_s is None:
            return 2**31 - 1
        return max(1, math.ceil(self.task.episode_length_s / self.sim.env_dt - 1e-9))

    def validate(self) -> EnvConfig:
        """Raise ConfigError naming the first invalid value; return self."""
        checks = [
            (isinstance(self.num_envs, int) and self.num_envs >= 1, f"num_envs must be an int >= 1, got {self.num_envs!r}"),
            (self.sim.physics_dt > 0 and math.isfinite(self.sim.physics_dt), f"sim.physics_dt must be > 0 s, got {self.sim.physics_dt!r}"),
            (isinstance(self.sim.decimation, int) and self.sim.decimation >= 1, f"sim.decimation must be an int >= 1, got {self.sim.decimation!r}"),
            (isinstance(self.sim.mass_matrix_interval, int) and self.sim.mass_matrix_interval >= 1
             and self.sim.decimation % self.sim.mass_matrix_interval == 0,
             f"sim.mass_matrix_interval must be >= 1 and divide sim.decimation ({self.sim.decimation}), "
             f"got {self.sim.mass_matrix_interval!r}"),
            (self.sim.solver in SOLVERS, f"unknown solver {self.sim.solver!r}; choose one of {', '.join(SOLVERS)}"),
            (isinstance(self.sim.cpu_threads, int) and self.sim.cpu_threads >= 0,
             f"sim.cpu_threads must be an int >= 0, got {self.sim.cpu_threads!r}"),
            (self.sim.capture in ("auto", "on", "off"), f"sim.capture must be 'auto', 'on' or 'off', got {self.sim.capture!r}"),
            (self.task.episode_length_s is None or self.task.episode_length_s > 0,
             f"task.episode_length_s must be > 0 or null, got {self.task.episode_length_s!r}"),
            (self.task.max_push_effort_n >= 0, f"task.max_push_effort_n must be >= 0, got {self.task.max_push_effort_n!r}"),
        ]
        for ok, message in checks:
            if not ok:
                raise ConfigError(message)
        return self


def field_docs(cls) -> dict[str, str]:
    """Docstrings written under each field of a dataclass, by field name."""
    import ast
    import inspect

    tree = ast.parse(inspect.getsource(cls))
    body = tree.body[0].body
    docs = {}
    for node, after in zip(body, body[1:]):
        if isinstance(node, ast.AnnAssign) and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant):
            docs[node.target.id] = after.value.value
    return docs


def _field_type(cls, name):
    hints = typing.get_type_hints(cls)
    return hints[name]


def _coerce(value, kind, where):
    """Convert ``value`` (from YAML or a CLI string) to the annotated ``kind``."""
    origin = typing.get_origin(kind)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(kind) if a is not type(None)]
        if value is None or (isinstance(value, str) and value.lower() in ("none", "null")):
            return None
        return _coerce(value, args[0], where)
    if origin in (list, tuple):
        (item,) = typing.get_args(kind)[:1]
        if isinstance(value, str):
            value = yaml.safe_load(value)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        return [_coerce(v, item, where) for v in value]
    if isinstance(value, str) and kind is not str:
        value = yaml.safe_load(value)
    try:
        if kind is bool:
            if not isinstance(value, bool):
                raise TypeError
            return value
        if kind is int and isinstance(value, float) and not value.is_integer():
            raise TypeError
        return kind(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: expected {kind.__name__}, got {value!r}") from None


def apply_overrides(cfg, overrides: dict, where: str = ""):
    """Apply a nested dict of overrides to a dataclass tree in place; unknown keys raise ConfigError."""
    if not isinstance(overrides, dict):
        raise ConfigError(f"{where or 'config'}: expected a mapping, got {overrides!r}")
    names = {f.name for f in dataclasses.fields(cfg)}
    for key, value in overrides.items():
        path = f"{where}.{key}" if where else key
        if key not in names:
            raise ConfigError(f"unknown config key {path!r}; valid keys here: {', '.join(sorted(names))}")
        current = getattr(cfg, key)
        if dataclasses.is_dataclass(current):
            apply_overrides(current, value, path)
        else:
            setattr(cfg, key, _coerce(value, _field_type(type(cfg), key), path))
    return cfg


def set_field(cfg, dotted: str, text: str):
    """Set one field from a ``key.sub=value`` style pair, the value parsed as YAML."""
    *parents, leaf = dotted.split(".")
    nested = {leaf: text}
    for name in reversed(parents):
        nested = {name: nested}
    return apply_overrides(cfg, nested)


def preset_path(preset: str) -> Path:
    """Path of a preset: a name under ``configs/`` or a path to a YAML file."""
    path = Path(preset)
    if path.suffix in (".yaml", ".yml"):
        if not path.is_file():
            raise ConfigError(f"config file {path} does not exist")
        return path
    path = CONFIG_DIR / f"{preset}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in CONFIG_DIR.glob("*.yaml"))
        raise ConfigError(f"unknown preset {preset!r}; known presets: {', '.join(known)}")
    return path


def load_preset(preset: str) -> dict:
    """The overrides a preset holds, as a nested dict (sections such as 'env' and 'train')."""
    path = preset_path(preset)
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise ConfigError(f"cannot parse {path}: {err}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level")
    return data


def env_config(preset: str = "default", **overrides) -> EnvConfig:
    """EnvConfig from the dataclass defaults, the preset's 'env' section, then keyword overrides."""
    cfg = EnvConfig()
    apply_overrides(cfg, load_preset(preset).get("env", {}), "env")
    apply_overrides(cfg, {k: v for k, v in overrides.items() if v is not None})
    return cfg.validate()


def to_dict(cfg) -> dict:
    """A dataclass tree as plain nested dicts (for YAML)."""
    return dataclasses.asdict(cfg)


ALGOS = ("rsl_rl", "sb3")
LOGGERS = ("tensorboard", "wandb", "none")
CONSOLE_STYLES = ("compact", "rsl_rl")


@dataclass
class PolicyConfig:
    """Actor and critic networks (rsl-rl ``MLPModel``) and the Gaussian action noise."""

    hidden_dims: list[int] = field(default_factory=lambda: [32, 32])
    """Hidden layer widths of the actor and of the critic MLP."""
    activation: str = "elu"
    """Activation function of the hidden layers (an rsl-rl name: elu, relu, tanh, ...)."""
    init_noise_std: float = 1.0
    """Initial standard deviation of the Gaussian action noise (actions are in units of max_push_effort_n)."""
    obs_normalization: bool = False
    """Normalise observations with running mean/std statistics inside the networks."""


@dataclass
class PPOConfig:
    """rsl-rl PPO hyper-parameters (Isaac Lab's cartpole settings)."""

    num_learning_epochs: int = 5
    """Passes over each rollout per iteration."""
    num_mini_batches: int = 4
    """Mini-batches per epoch."""
    clip_param: float = 0.2
    """PPO ratio clip."""
    gamma: float = 0.99
    """Discount factor per env step."""
    lam: float = 0.95
    """GAE lambda."""
    value_loss_coef: float = 1.0
    """Weight of the value loss."""
    entropy_coef: float = 0.005
    """Weight of the entropy bonus."""
    learning_rate: float = 1.0e-3
    """Initial Adam learning rate (adapted when schedule is 'adaptive')."""
    max_grad_norm: float = 1.0
    """Gradient norm clip."""
    use_clipped_value_loss: bool = True
    """Clip the value-function update like the policy update."""
    schedule: str = "adaptive"
    """Learning-rate schedule: 'adaptive' (follow desired_kl) or 'fixed'."""
    desired_kl: float = 0.01
    """Target KL divergence per update for the adaptive schedule."""


@dataclass
class RunnerConfig:
    """Training loop, logging and checkpoints."""

    max_iterations: int = 150
    """PPO iterations to run (on --resume: iterations to add)."""
    num_steps_per_env: int = 16
    """Env steps collected per env per iteration; a rollout holds num_envs * num_steps_per_env steps."""
    save_interval: int = 50
    """Write a checkpoint every this many iterations (and always at the end)."""
    torch_threads: int = 1
    """CPU threads for torch (torch.set_num_threads); 0 keeps torch's default. 1 is fastest on small CPUs: the
    networks are tiny, and more threads fight the env and other processes for cores (10x slower when oversubscribed)."""
    stop_when_solved: bool = False
    """End training at the first iteration that meets the 'solved' criterion."""
    logger: str = "tensorboard"
    """Metrics writer: 'tensorboard', 'wandb' (needs the wandb package) or 'none' (checkpoints and summary only)."""
    wandb_project: str = "cartpole_warp"
    """Weights & Biases project name when logger is 'wandb'."""
    console: str = "compact"
    """Console output per iteration: 'compact' (one line) or 'rsl_rl' (rsl-rl's block)."""
    log_dir: str = "logs"
    """Root folder of all runs; a run lives in <log_dir>/<algo>/<experiment_name>/<timestamp>[_<run_name>]."""
    experiment_name: str = "cartpole"
    """Folder under <log_dir>/<algo> that groups the runs of one experiment."""
    run_name: str = ""
    """Suffix of the run folder name (empty: the timestamp alone)."""


@dataclass
class Sb3PpoConfig:
    """Stable-Baselines3 ``PPO("MlpPolicy", ...)`` (``--algo sb3``); the defaults are the Isaac Sim tutorial's."""

    total_timesteps: int = 100_000
    """Env steps to train for (summed over all envs): the tutorial's ``model.learn(total_timesteps=100000)``."""
    n_steps: int = 1000
    """Env steps per env in each rollout."""
    batch_size: int = 1000
    """Minibatch size (samples)."""
    n_epochs: int = 20
    """Passes over each rollout."""
    learning_rate: float = 0.001
    """Adam learning rate."""
    gamma: float = 0.99
    """Discount factor."""
    ent_coef: float = 0.0
    """Entropy bonus weight."""
    vf_coef: float = 0.5
    """Value loss weight."""
    max_grad_norm: float = 1.0
    """Gradient clipping norm."""


@dataclass
class TrainConfig:
    """Everything ``train.py`` needs: the env, the networks, PPO and the training loop."""

    algo: str = "rsl_rl"
    """Trainer: 'rsl_rl' (rsl-rl PPO on the batched env) or 'sb3' (the tutorial's Stable-Baselines3 PPO)."""
    env: EnvConfig = field(default_factory=EnvConfig)
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    train: RunnerConfig = field(default_factory=RunnerConfig)
    sb3: Sb3PpoConfig = field(default_factory=Sb3PpoConfig)

    def validate(self) -> TrainConfig:
        """Raise ConfigError naming the first invalid value; return self."""
        self.env.validate()
        t, p = self.train, self.ppo
        checks = [
            (self.algo in ALGOS, f"algo must be one of {', '.join(ALGOS)}, got {self.algo!r}"),
            (self.sb3.total_timesteps >= 1, f"sb3.total_timesteps must be >= 1, got {self.sb3.total_timesteps!r}"),
            (t.max_iterations >= 1, f"train.max_iterations must be >= 1, got {t.max_iterations!r}"),
            (t.num_steps_per_env >= 1, f"train.num_steps_per_env must be >= 1, got {t.num_steps_per_env!r}"),
            (t.torch_threads >= 0, f"train.torch_threads must be >= 0, got {t.torch_threads!r}"),
            (t.save_interval >= 1, f"train.save_interval must be >= 1, got {t.save_interval!r}"),
            (t.logger in LOGGERS, f"train.logger must be one of {', '.join(LOGGERS)}, got {t.logger!r}"),
            (t.console in CONSOLE_STYLES, f"train.console must be one of {', '.join(CONSOLE_STYLES)}, got {t.console!r}"),
            (p.schedule in ("adaptive", "fixed"), f"ppo.schedule must be 'adaptive' or 'fixed', got {p.schedule!r}"),
            (p.num_mini_batches >= 1 and (self.env.num_envs * t.num_steps_per_env) % p.num_mini_batches == 0,
             f"ppo.num_mini_batches ({p.num_mini_batches}) must divide num_envs * train.num_steps_per_env "
             f"({self.env.num_envs * t.num_steps_per_env})"),
            (all(d >= 1 for d in self.policy.hidden_dims), f"policy.hidden_dims must be positive, got {self.policy.hidden_dims!r}"),
        ]
        for ok, message in checks:
            if not ok:
                raise ConfigError(message)
        return self


def train_config(preset: str = "default", overrides: dict | None = None) -> TrainConfig:
    """TrainConfig from the dataclass defaults, a preset's sections, then a nested dict of overrides (not validated)."""
    cfg = TrainConfig()
    apply_overrides(cfg, load_preset(preset))
    apply_overrides(cfg, overrides or {})
    return cfg
