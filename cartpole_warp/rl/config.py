"""Training configuration: ``task`` names the registered task, ``agent`` is shaped like rsl-rl's own ``train_cfg``
(``RunnerConfig.to_rsl_rl``), ``env`` is the task's ``EnvConfig``; the rest says where runs go and what the console
shows.

The defaults are the dataclass defaults, then the task's own (``Task.defaults``). A preset (``configs/<name>.yaml``)
holds partial overrides of ``TrainConfig`` (sections ``env``, ``agent`` and the top-level fields); ``train.py`` and
``play.py`` take every field as a flag (``--agent.algorithm.entropy-coef 0.01``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Annotated, Generic, Literal

import pydantic
import tyro

from .. import tasks
from ..config import (
    NO_UNKNOWN_KEYS,
    ConfigError,
    Count,
    EnvConfig,
    Flag,
    Fraction,
    Name,
    NonNegative,
    NonNegativeInt,
    Positive,
    TaskT,
    checked,
    from_dict,
    load_preset,
    merge,
    overrides_dict,
    require,
)

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

    def to_rsl_rl(self) -> dict:
        """rsl-rl's ``train_cfg`` dict: class names added, our own fields left out."""
        cfg = dataclasses.asdict(self)
        for key in ("max_iterations", "init_at_random_ep_len", "experiment_name", "wandb_project", "cuda_graph"):
            del cfg[key]
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
class TrainConfig(Generic[TaskT]):
    """Everything ``train.py`` needs: the task, its env, rsl-rl's runner configuration and where the run goes."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    env: EnvConfig[TaskT]
    task: Name = tasks.DEFAULT_TASK
    """The registered task (``cartpole_warp.tasks.names()``); set it with --task, which picks its settings."""
    agent: RunnerConfig = field(default_factory=RunnerConfig)
    log_dir: Name = "logs"
    """Root folder of all runs; a run lives in <log_dir>/rsl_rl/<agent.experiment_name>/<timestamp>[_<run_name>]."""
    console: Console = "compact"
    """Console output per iteration: 'compact' (one line) or 'rsl_rl' (rsl-rl's block)."""
    stop_when_solved: Flag = False
    """End training at the first iteration that meets the 'solved' criterion."""
    torch_threads: NonNegativeInt = 1
    """CPU threads for torch (torch.set_num_threads); 0 keeps torch's default. 1 is fastest on small CPUs: the
    networks are tiny, and more threads fight the env and other processes for cores (10x slower when oversubscribed)."""

    @property
    def experiment(self) -> str:
        """The experiment folder's name: ``agent.experiment_name``, or the task's name."""
        return self.agent.experiment_name or self.task

    def validate(self) -> TrainConfig[TaskT]:
        """Raise ConfigError naming the first invalid value and what is allowed; return self (each field's type and
        range are checked by ``checked`` where flags become a config; the checks here relate fields)."""
        self.env.validate()
        require(isinstance(self.env.task, tasks.get(self.task).env_class.config_class),
                f"env.task holds {type(self.env.task).__name__}, not the settings of task {self.task!r}")
        rollout = self.env.num_envs * self.agent.num_steps_per_env
        mini_batches = self.agent.algorithm.num_mini_batches
        require(rollout % mini_batches == 0,
                f"agent.algorithm.num_mini_batches ({mini_batches}) must divide num_envs * agent.num_steps_per_env "
                f"({rollout})")
        return self


def train_config(task: str = tasks.DEFAULT_TASK, preset: str | None = None) -> TrainConfig:
    """TrainConfig of ``task`` from the dataclass defaults, the task's defaults and a preset (flags may still change
    it: ``validate`` after them)."""
    config_class = tasks.get(task).env_class.config_class
    cls = TrainConfig[config_class]
    data = merge(dataclasses.asdict(cls(env=EnvConfig(task=config_class()), task=task)), tasks.get(task).defaults)
    if preset is not None:
        preset_data = load_preset(preset)
        require(preset_data.get("task", task) == task,
                f"preset {preset!r} is for task {preset_data.get('task')!r}, not {task!r}")
        data = merge(data, overrides_dict(preset_data, f"preset {preset!r}:"))
    return from_dict(cls, data, f"task {task!r}" + (f", preset {preset!r}" if preset else ""))


def load_train_config(data: dict, where: str) -> TrainConfig:
    """A saved TrainConfig (a run's ``config.yaml``) from its dict: the task it names picks the settings' class."""
    task = overrides_dict(data, f"{where}:").get("task", tasks.DEFAULT_TASK)
    return from_dict(TrainConfig[tasks.get(task).env_class.config_class], data, where)


__all__ = ["ActorConfig", "ConfigError", "DistributionConfig", "ModelConfig", "PpoConfig", "RunnerConfig",
           "TrainConfig", "checked", "load_train_config", "train_config"]
