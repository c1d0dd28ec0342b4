"""Training configuration: ``agent`` is shaped like rsl-rl's own ``train_cfg`` (``RunnerConfig.to_rsl_rl``), ``env``
is the env's ``EnvConfig``; the rest says where runs go and what the console shows.

A preset (``configs/<name>.yaml``) holds partial overrides of ``TrainConfig`` (sections ``env``, ``agent`` and the
top-level fields); ``train.py`` and ``play.py`` take every field as a flag (``--agent.algorithm.entropy-coef 0.01``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Annotated, Literal

import pydantic
import tyro

from ..config import (
    NO_UNKNOWN_KEYS,
    ConfigError,
    Count,
    EnvConfig,
    Flag,
    Name,
    NonNegative,
    NonNegativeInt,
    Positive,
    checked,
    from_dict,
    load_preset,
    merge,
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
    """Initial standard deviation (actions are in units of max_push_effort_n)."""


@dataclass
class ModelConfig:
    """An rsl-rl ``MLPModel``."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    hidden_dims: Annotated[list[Count], pydantic.Field(min_length=1)] = field(default_factory=lambda: [32, 32])
    """Hidden layer widths."""
    activation: Activation = "elu"
    """Activation function of the hidden layers. 'relu' and 'lrelu' solve as fast at 4096 envs and cost slightly less
    CPU time (torch's CPU ELU is slow), but with 16384 envs 2 of 5 of their final policies failed play.py, against
    none with 'elu'."""
    obs_normalization: Flag = False
    """Normalise observations with running mean/std statistics inside the network."""


@dataclass
class ActorConfig(ModelConfig):
    """The policy network: an MLP whose output is the mean of a Gaussian."""

    distribution_cfg: DistributionConfig = field(default_factory=DistributionConfig)


@dataclass
class PpoConfig:
    """rsl-rl ``PPO`` hyper-parameters. The defaults are tuned for wall-clock time to a solved cartpole (one epoch of
    eight mini-batches, a looser KL target, the sync-free update); ``configs/isaac_lab.yaml`` holds Isaac Lab's."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    class_name: Algorithm = "SyncFreePPO"
    """'PPO' (rsl-rl's) or 'SyncFreePPO' (the same update, no host sync per mini-batch: faster on a GPU)."""

    num_learning_epochs: Count = 1
    """Passes over each rollout per iteration."""
    num_mini_batches: Count = 8
    """Mini-batches per epoch."""
    clip_param: Positive = 0.2
    """PPO ratio clip."""
    gamma: Annotated[float, pydantic.Field(gt=0, le=1)] = 0.99
    """Discount factor per env step."""
    lam: Annotated[float, pydantic.Field(ge=0, le=1)] = 0.95
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
    iteration instead of arriving all at once, and the final policy recovers from the whole reset range (5 of 5
    seeds reached the time limit in 100% of play's episodes, against 86-100% without). Reported episode lengths
    stay the steps each episode really ran."""
    save_interval: Count = 50
    """Write a checkpoint every this many iterations (and always at the end)."""
    experiment_name: Name = "cartpole"
    """Folder under <log_dir> that groups the runs of one experiment."""
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
class TrainConfig:
    """Everything ``train.py`` needs: the env, rsl-rl's runner configuration and where the run goes."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    env: EnvConfig = field(default_factory=EnvConfig)
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

    def validate(self) -> TrainConfig:
        """Raise ConfigError naming the first invalid value and what is allowed; return self (each field's type and
        range are written where it is defined; the checks here relate fields)."""
        self.env.validate()
        checked(self)
        rollout = self.env.num_envs * self.agent.num_steps_per_env
        mini_batches = self.agent.algorithm.num_mini_batches
        require(rollout % mini_batches == 0,
                f"agent.algorithm.num_mini_batches ({mini_batches}) must divide num_envs * agent.num_steps_per_env "
                f"({rollout})")
        return self


def train_config(preset: str = "default") -> TrainConfig:
    """TrainConfig from the dataclass defaults and a preset (not validated: flags may still change it)."""
    return from_dict(TrainConfig, merge(dataclasses.asdict(TrainConfig()), load_preset(preset)), f"preset {preset!r}")


__all__ = ["ActorConfig", "ConfigError", "DistributionConfig", "ModelConfig", "PpoConfig", "RunnerConfig",
           "TrainConfig", "train_config"]
