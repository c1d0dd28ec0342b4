"""Training configuration: ``agent`` is shaped like rsl-rl's own ``train_cfg`` (``RunnerConfig.to_rsl_rl``), ``env``
is the env's ``EnvConfig``; the rest says where runs go and what the console shows.

A preset (``configs/<name>.yaml``) holds partial overrides of ``TrainConfig`` (sections ``env``, ``agent`` and the
top-level fields); ``train.py`` and ``play.py`` take every field as a flag (``--agent.algorithm.entropy-coef 0.01``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Annotated, Literal

import tyro

from ..config import NO_UNKNOWN_KEYS, ConfigError, EnvConfig, from_dict, load_preset, merge, require

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

    init_std: float = 1.0
    """Initial standard deviation (actions are in units of max_push_effort_n)."""


@dataclass
class ModelConfig:
    """An rsl-rl ``MLPModel``."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    hidden_dims: list[int] = field(default_factory=lambda: [32, 32])
    """Hidden layer widths."""
    activation: Activation = "elu"
    """Activation function of the hidden layers."""
    obs_normalization: bool = False
    """Normalise observations with running mean/std statistics inside the network."""


@dataclass
class ActorConfig(ModelConfig):
    """The policy network: an MLP whose output is the mean of a Gaussian."""

    distribution_cfg: DistributionConfig = field(default_factory=DistributionConfig)


@dataclass
class PpoConfig:
    """rsl-rl ``PPO`` hyper-parameters. The defaults are tuned for wall-clock time to a solved cartpole (one epoch of
    six mini-batches, a looser KL target, the sync-free update); ``configs/isaac_lab.yaml`` holds Isaac Lab's."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    class_name: Algorithm = "SyncFreePPO"
    """'PPO' (rsl-rl's) or 'SyncFreePPO' (the same update, no host sync per mini-batch: faster on a GPU)."""

    num_learning_epochs: int = 1
    """Passes over each rollout per iteration."""
    num_mini_batches: int = 6
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
    schedule: Schedule = "adaptive"
    """Learning-rate schedule: 'adaptive' (follow desired_kl) or 'fixed'."""
    desired_kl: float = 0.02
    """Target KL divergence per update for the adaptive schedule."""


@dataclass
class RunnerConfig:
    """rsl-rl's ``OnPolicyRunner`` configuration (its ``train_cfg``), plus the run's length and name."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    num_steps_per_env: int = 12
    """Env steps collected per env per iteration; a rollout holds num_envs * num_steps_per_env steps."""
    max_iterations: Annotated[int, tyro.conf.arg(aliases=("--max-iterations",))] = 150
    """PPO iterations to run (on --resume: iterations to add)."""
    save_interval: int = 50
    """Write a checkpoint every this many iterations (and always at the end)."""
    experiment_name: str = "cartpole"
    """Folder under <log_dir> that groups the runs of one experiment."""
    run_name: Annotated[str, tyro.conf.arg(aliases=("--run-name",))] = ""
    """Suffix of the run folder name (empty: the timestamp alone)."""
    logger: Annotated[MetricsLogger, tyro.conf.arg(aliases=("--logger",))] = "tensorboard"
    """Metrics writer: 'tensorboard', 'wandb' (needs the wandb package) or 'none' (checkpoints and summary only)."""
    wandb_project: str = "cartpole_warp"
    """Weights & Biases project when logger is 'wandb'."""
    cuda_graph: bool = True
    """With SyncFreePPO on one GPU: capture one iteration's rollout and its update as CUDA graphs after the first
    iterations and replay them, one launch each instead of thousands. Ignored on the CPU, under torchrun (a 2-GPU run
    with graphs hung at its end), with rsl-rl's PPO (whose sampling and update read the device) and with console
    'rsl_rl' (whose per-step bookkeeping does)."""
    algorithm: PpoConfig = field(default_factory=PpoConfig)
    actor: ActorConfig = field(default_factory=ActorConfig)
    critic: ModelConfig = field(default_factory=ModelConfig)

    def to_rsl_rl(self) -> dict:
        """rsl-rl's ``train_cfg`` dict: class names added, our own fields left out."""
        cfg = dataclasses.asdict(self)
        for key in ("max_iterations", "experiment_name", "wandb_project", "cuda_graph"):
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
    log_dir: str = "logs"
    """Root folder of all runs; a run lives in <log_dir>/rsl_rl/<agent.experiment_name>/<timestamp>[_<run_name>]."""
    console: Console = "compact"
    """Console output per iteration: 'compact' (one line) or 'rsl_rl' (rsl-rl's block)."""
    stop_when_solved: bool = False
    """End training at the first iteration that meets the 'solved' criterion."""
    torch_threads: int = 1
    """CPU threads for torch (torch.set_num_threads); 0 keeps torch's default. 1 is fastest on small CPUs: the
    networks are tiny, and more threads fight the env and other processes for cores (10x slower when oversubscribed)."""

    def validate(self) -> TrainConfig:
        """Raise ConfigError naming the first invalid value; return self."""
        self.env.validate()
        agent, ppo = self.agent, self.agent.algorithm
        rollout = self.env.num_envs * agent.num_steps_per_env
        require(agent.max_iterations >= 1, f"agent.max_iterations must be >= 1, got {agent.max_iterations!r}")
        require(agent.num_steps_per_env >= 1, f"agent.num_steps_per_env must be >= 1, got {agent.num_steps_per_env!r}")
        require(agent.save_interval >= 1, f"agent.save_interval must be >= 1, got {agent.save_interval!r}")
        require(self.torch_threads >= 0, f"torch_threads must be >= 0, got {self.torch_threads!r}")
        require(ppo.num_mini_batches >= 1 and rollout % ppo.num_mini_batches == 0,
                f"agent.algorithm.num_mini_batches ({ppo.num_mini_batches}) must divide num_envs * "
                f"agent.num_steps_per_env ({rollout})")
        for name, model in (("actor", agent.actor), ("critic", agent.critic)):
            require(all(d >= 1 for d in model.hidden_dims),
                    f"agent.{name}.hidden_dims must be positive, got {model.hidden_dims!r}")
        return self


def train_config(preset: str = "default") -> TrainConfig:
    """TrainConfig from the dataclass defaults and a preset (not validated: flags may still change it)."""
    return from_dict(TrainConfig, merge(dataclasses.asdict(TrainConfig()), load_preset(preset)), f"preset {preset!r}")


__all__ = ["ActorConfig", "ConfigError", "DistributionConfig", "ModelConfig", "PpoConfig", "RunnerConfig",
           "TrainConfig", "train_config"]
