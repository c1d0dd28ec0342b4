"""Preset files and the schema they are checked against, in one place below the tasks and the training code: the
``agent`` section of a training config (shaped like rsl-rl's ``train_cfg``), the run settings, and the one loader
that refuses an unknown section or key anywhere, whoever loads the preset (``train.py --config``, ``make_env``,
``gym.make``). A preset (``configs/<name>.yaml`` or a YAML path) holds partial overrides of ``rl.config.TrainConfig``;
its ``env`` section is checked against the task's own settings where the task is known (``tasks.env_config``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import pydantic
import tyro
import yaml

from .config import (
    NO_UNKNOWN_KEYS,
    ConfigError,
    Count,
    Flag,
    Fraction,
    Name,
    NonNegative,
    NonNegativeInt,
    Positive,
    from_dict,
    merge,
    overrides_dict,
    require,
)
from .files import data_path

Activation = Literal["elu", "selu", "relu", "crelu", "lrelu", "tanh", "sigmoid", "softplus", "gelu", "swish", "mish"]
"""rsl-rl's activation names (``rsl_rl.utils.resolve_nn_activation``)."""
Schedule = Literal["adaptive", "fixed"]
Algorithm = Literal["PPO", "SyncFreePPO"]
"""rsl-rl's ``PPO``, or ``SyncFreePPO`` (``cartpole_warp.rl.ppo``: the same update without host syncs)."""
MetricsLogger = Literal["tensorboard", "wandb", "none"]
Console = Literal["compact", "rsl_rl"]


@dataclass
class DistributionConfig:
    """The actor's Gaussian action noise (rsl-rl ``GaussianDistribution``)."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    init_std: Positive = 1.0
    """Initial standard deviation (actions are in [-1, 1])."""


@dataclass
class ModelConfig:
    """An rsl-rl ``MLPModel``."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    hidden_dims: Annotated[list[Count], pydantic.Field(min_length=1)] = field(default_factory=lambda: [32, 32])
    """Hidden layer widths."""
    activation: Activation = "elu"
    """Activation function of the hidden layers (docs/benchmarks.md compares them)."""
    obs_normalization: Flag = False
    """Normalise observations with running mean/std statistics inside the network."""


@dataclass
class ActorConfig(ModelConfig):
    """The policy network: an MLP whose output is the mean of a Gaussian."""

    distribution_cfg: DistributionConfig = field(default_factory=DistributionConfig)


@dataclass
class PpoConfig:
    """rsl-rl ``PPO`` hyper-parameters. The defaults are tuned for wall-clock time to a solved balance task (one epoch
    of eight mini-batches, a looser KL target, the sync-free update); ``configs/isaac_lab.yaml`` holds Isaac Lab's."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    class_name: Algorithm = "SyncFreePPO"
    """'PPO' (rsl-rl's) or 'SyncFreePPO' (the same update, no host sync per mini-batch: faster on a GPU)."""

    num_learning_epochs: Count = 1
    """Passes over each rollout per iteration."""
    num_mini_batches: Count = 8
    """Mini-batches per epoch."""
    clip_param: Positive = 0.2
    """PPO ratio clip."""
    gamma: Annotated[Fraction, pydantic.Field(gt=0)] = 0.99
    """Discount factor per env step."""
    lam: Fraction = 0.95
    """GAE lambda."""
    value_loss_coef: NonNegative = 1.0
    """Weight of the value loss."""
    entropy_coef: NonNegative = 0.005
    """Weight of the entropy bonus."""
    learning_rate: Positive = 1.0e-3
    """Initial Adam learning rate (adapted when schedule is 'adaptive')."""
    max_grad_norm: Positive = 1.0
    """Gradient norm clip."""
    use_clipped_value_loss: Flag = True
    """Clip the value-function update like the policy update."""
    schedule: Schedule = "adaptive"
    """Learning-rate schedule: 'adaptive' (follow desired_kl) or 'fixed'."""
    desired_kl: Positive = 0.02
    """Target KL divergence per update for the adaptive schedule."""
    use_mixed_precision: Flag = False
    """rsl-rl's bfloat16 autocast of the losses' forward passes."""
    symmetry: Flag = True
    """rsl-rl's symmetry data augmentation: each mini-batch also holds its mirror images under the task's left-right
    symmetry (``BatchedEnv.obs_mirror``; ignored for a task without one), so the policy learns no left or right bias
    (without it the robust balance's policies can drift off the rail after solving; docs/benchmarks.md). Twice the
    samples per update."""


@dataclass
class RunnerConfig:
    """rsl-rl's ``OnPolicyRunner`` configuration (its ``train_cfg``), plus the run's length and name."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    num_steps_per_env: Count = 8
    """Env steps collected per env per iteration; a rollout holds num_envs * num_steps_per_env steps."""
    max_iterations: Annotated[Count, tyro.conf.arg(aliases=("--max-iterations",))] = 150
    """PPO iterations to run (on --resume: iterations to add)."""
    init_at_random_ep_len: Flag = True
    """Start training with each env's time-out counter at a random point of the time limit (rsl-rl's ``learn``
    argument, as Isaac Lab's train script sets it): time-outs, hence resets from random states, spread over every
    iteration instead of arriving all at once. Reported episode lengths stay the steps each episode really ran."""
    save_interval: Count = 50
    """Write a checkpoint every this many iterations (and always at the end)."""
    experiment_name: Name | None = None
    """Folder under <log_dir>/rsl_rl that groups the runs of one experiment; None: the task's name."""
    run_name: Annotated[str, tyro.conf.arg(aliases=("--run-name",))] = ""
    """Suffix of the run folder name (empty: the timestamp alone)."""
    logger: Annotated[MetricsLogger, tyro.conf.arg(aliases=("--logger",))] = "tensorboard"
    """Metrics writer: 'tensorboard', 'wandb' (needs the wandb package) or 'none' (checkpoints and summary only)."""
    wandb_project: Name = "cartpole_warp"
    """Weights & Biases project when logger is 'wandb'."""
    cuda_graph: Flag = True
    """With SyncFreePPO on a GPU: capture one iteration's rollout and its update (with its NCCL all-reduces under
    torchrun) as CUDA graphs after the first iterations and replay them, one launch each instead of thousands.
    Ignored on the CPU, with rsl-rl's PPO (whose sampling and update read the device) and with console 'rsl_rl'
    (whose per-step bookkeeping does)."""
    torch_compile_mode: Literal["default", "max-autotune-no-cudagraphs"] | None = None
    """rsl-rl's torch.compile of the actor and critic (None: not compiled)."""
    algorithm: PpoConfig = field(default_factory=PpoConfig)
    actor: ActorConfig = field(default_factory=ActorConfig)
    critic: ModelConfig = field(default_factory=ModelConfig)

    def to_rsl_rl(self, mirror: bool = False) -> dict:
        """rsl-rl's ``train_cfg`` dict: class names added, our own fields left out; ``mirror``: the task has a mirror
        (``symmetry`` applies)."""
        cfg = dataclasses.asdict(self)
        for key in ("max_iterations", "init_at_random_ep_len", "experiment_name", "wandb_project", "cuda_graph"):
            del cfg[key]
        del cfg["algorithm"]["symmetry"]
        if self.algorithm.symmetry and mirror:
            cfg["algorithm"]["symmetry_cfg"] = {"use_data_augmentation": True,
                                                "data_augmentation_func": "cartpole_warp.wrappers.rsl_rl:mirror"}
        cfg["actor"]["class_name"] = "MLPModel"
        cfg["actor"]["distribution_cfg"]["class_name"] = "GaussianDistribution"
        if self.algorithm.class_name == "SyncFreePPO":
            cfg["algorithm"]["class_name"] = "cartpole_warp.rl.ppo:SyncFreePPO"
            cfg["algorithm"]["cuda_graph"] = self.cuda_graph
            cfg["actor"]["distribution_cfg"]["class_name"] = "cartpole_warp.rl.ppo:SyncFreeGaussian"
        cfg["critic"]["class_name"] = "MLPModel"
        cfg["obs_groups"] = {"actor": ["policy"], "critic": ["policy"]}
        if self.logger == "wandb":
            cfg["logger"] = {"class_name": "WandbLogWriter", "project_name": self.wandb_project}
        elif self.logger == "none":
            cfg["logger"] = {"class_name": "cartpole_warp.rl.runner:NullLogWriter"}
        return cfg


@dataclass
class EvalConfig:
    """The deterministic evaluation that decides 'solved' and picks the best checkpoint: the policy's mean action,
    each env's first episode from the run's seed to the time limit, on a separate batch of envs. With ``num_envs``
    equal to play.py's --num-envs (256 by default) these are the episodes ``play.py --headless`` plays."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    num_envs: Count = 256
    """Envs (one episode each) of an evaluation."""
    min_interval: Count = 5
    """Evaluate when an iteration's training episodes meet the task's solved rule, at most once in this many
    iterations ..."""
    max_interval: Count = 25
    """... and after this many iterations without an evaluation (a policy that fails only through its exploration
    noise)."""


@dataclass
class RunSettings:
    """Where runs go and what the console shows (the top-level fields of a training config besides its task, env
    and agent)."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    log_dir: Name = "logs"
    """Root folder of all runs; a run lives in <log_dir>/rsl_rl/<agent.experiment_name>/<timestamp>[_<run_name>]."""
    console: Console = "compact"
    """Console output per iteration: 'compact' (one line) or 'rsl_rl' (rsl-rl's block)."""
    stop_when_solved: Flag = False
    """End training at the first evaluation that meets the task's solved rule (``eval``)."""
    eval: EvalConfig = field(default_factory=EvalConfig)
    torch_threads: NonNegativeInt = 1
    """CPU threads for torch (torch.set_num_threads); 0 keeps torch's default. 1 is fastest on small CPUs: the
    networks are tiny, and more threads fight the env and other processes for cores (10x slower when oversubscribed)."""


@dataclass
class PresetFile(RunSettings):
    """The schema of a preset file: a training config's sections and fields, every one optional. ``env`` is checked
    against the task's settings where the task is known."""

    task: Name | None = None
    env: dict[str, Any] = field(default_factory=dict)
    agent: RunnerConfig = field(default_factory=RunnerConfig)


def presets() -> list[str]:
    """Names of the presets shipped with the package."""
    return sorted(p.stem for p in data_path("configs").glob("*.yaml"))


def load_preset(preset: str, task: str | None = None) -> dict:
    """The overrides a preset holds, as a nested dict: a name under ``configs/`` or a path to a YAML file. ConfigError
    for an unknown section or key anywhere but ``env`` (whose keys depend on the task), a bad value, or a preset that
    names another task than ``task`` (a preset without ``task:`` applies to any)."""
    path = Path(preset)
    if path.suffix not in (".yaml", ".yml"):
        path = data_path("configs", f"{preset}.yaml")
        require(path.is_file(), f"unknown preset {preset!r}; known presets: {', '.join(presets())}")
    require(path.is_file(), f"config file {path} does not exist")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise ConfigError(f"cannot parse {path}: {err}") from None
    data = overrides_dict(data, f"{path}: expected a mapping at the top level;")
    from_dict(PresetFile, merge(dataclasses.asdict(PresetFile()), data), f"preset {preset!r}")
    require(task is None or data.get("task", task) == task,
            f"preset {preset!r} is for task {data.get('task')!r}, not {task!r}")
    return data
