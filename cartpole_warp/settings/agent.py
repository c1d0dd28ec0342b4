"""rsl-rl's training settings as dataclasses, shaped like its ``train_cfg`` (the ``agent`` section of a training config
and of a preset): the runner, PPO, the actor and critic networks. ``rl.policies.to_rsl_rl`` turns them into rsl-rl's
dict; the preset loader checks a preset's ``agent`` section against them, so an unknown key is refused.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Annotated, Literal

import pydantic

from .config import NO_UNKNOWN_KEYS, Count, Finite, Flag, Fraction, Name, NonNegative, Positive
from .deprecation import REMOVED_IN, renamed

Activation = Literal["elu", "selu", "relu", "crelu", "lrelu", "tanh", "sigmoid", "softplus", "gelu", "swish", "mish"]
"""rsl-rl's activation names (``rsl_rl.utils.resolve_nn_activation``)."""
Schedule = Literal["adaptive", "fixed"]
Algorithm = Literal["PPO", "SyncFreePPO"]
"""rsl-rl's ``PPO``, or ``SyncFreePPO`` (``rl.learners.ppo``: the same update without host syncs)."""
MetricsLogger = Literal["tensorboard", "wandb", "none"]
Learner = Literal["ppo", "shac", "sapg", "fasttd3"]
"""'ppo' (rsl-rl's PPO on the env's transitions), 'shac' (``rl.learners.shac``: short-horizon analytic policy gradients
through the simulator, with a critic), 'sapg' (``rl.learners.sapg``: a leader PPO policy learning from its
followers' envs too) or 'fasttd3' (``rl.learners.fast_td3``: off-policy TD3 with a distributional twin critic and a
replay of every env's transitions on the device)."""
LEARNER_DEFAULTS: dict[str, dict] = {
    "shac": {"env": {"num_envs": 64}, "agent": {"num_steps_per_env": 32, "max_iterations": 100,
                                                "actor": {"obs_normalization": False, "hidden_dims": [32, 32]},
                                                "critic": {"obs_normalization": False, "hidden_dims": [32, 32]}},
             "eval": {"in_step": False}},
    "fasttd3": {"agent": {"num_steps_per_env": 8, "actor": {"obs_normalization": True, "hidden_dims": [256, 128, 64]}},
                "eval": {"in_step": False}},
}
"""What a learner changes in every task's defaults (``env``, ``agent`` and run sections), before what a task tunes
for it (``tasks.TaskSettings.for_learner``) and a preset; 'ppo' and 'sapg' take the task's own. SHAC: 64 envs,
windows of 32 env steps, no observation normalisation (with it the swing-up's actor stalled), 32 x 32 networks on
every device (a task's PPO may take narrower ones on a CPU), evaluations on envs of their own (the learner steps its
envs itself); chosen on the balance and the swing-up (docs/benchmarks.md, "Training by backpropagation"). FastTD3:
iterations of 8 env steps, a normalised 256-128-64 actor on every device, evaluations on envs of their own."""
LEARNER_CPU_DEFAULTS: dict[str, dict] = {
    "fasttd3": {"env": {"num_envs": 256}, "agent": {"actor": {"hidden_dims": [64, 64]},
                                                    "fasttd3": {"batch_size": 512, "critic_hidden_dims": [128, 128]}}},
}
"""What a learner changes on a CPU, after ``LEARNER_DEFAULTS``: FastTD3's batch of 32,768 and its critic are for a
GPU (on the 2-core CPU one iteration of them takes over a minute); with these, 256 envs, a batch of 512 and a
128-128 critic, the balance trains in seconds there (docs/benchmarks.md, "Issue 74 ..., session 31")."""
PPO_UPDATE_LEARNERS = ("ppo", "sapg")
"""The learners whose update is PPO's (``algorithm``'s settings, whose mini-batches must split a rollout evenly)."""
RENAMED_LEARNERS = {"apg": "shac"}
"""Old learner names (``--learner apg`` named SHAC, which has a critic; Brax's APG has none) -> their names, taken
with a note until ``deprecation.REMOVED_IN``; a saved config's old section (``agent.apg``) is read as the new one."""


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
class CnnConfig:
    """The image encoder of a policy that sees camera frames (rsl-rl ``CNN``; its flattened output feeds the MLP). The
    default, chosen by experiment (docs/benchmarks.md): a first convolution over non-overlapping 4x4 pixel blocks, then
    two small ones; narrow, since an encoder's update costs more than the env's step."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    output_channels: Annotated[list[Count], pydantic.Field(min_length=1)] = field(
        default_factory=lambda: [8, 16, 16])
    """Channels of each convolution."""
    kernel_size: Annotated[list[Count], pydantic.Field(min_length=1)] = field(default_factory=lambda: [4, 4, 3])
    """Kernel size of each convolution (one value: all)."""
    stride: Annotated[list[Count], pydantic.Field(min_length=1)] = field(default_factory=lambda: [4, 2, 1])
    """Stride of each convolution (one value: all)."""
    activation: Activation = "elu"
    """Activation after each convolution."""
    precision: Literal["bfloat16", "float32"] = "bfloat16"
    """Arithmetic of the encoder on a GPU (its weights, the MLP after it and the losses stay float32); the CPU
    computes in float32."""


@dataclass
class ActorConfig(ModelConfig):
    """The policy network: an MLP whose output is the mean of a Gaussian (after a CNN where it sees camera frames)."""

    distribution_cfg: DistributionConfig = field(default_factory=DistributionConfig)
    cnn: CnnConfig = field(default_factory=CnnConfig)
    """Used only where the policy sees camera frames (``env.camera.image``)."""


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
class ShacConfig:
    """Short-horizon analytic policy gradients (``rl.learners.shac``, after SHAC: Xu et al., ICLR 2022): each iteration
    backpropagates the return of a window of ``num_steps_per_env`` env steps of every env, plus the critic's value of
    where each window ends, through the simulator into the actor; the critic learns TD(lambda) targets of the same
    windows. The defaults were chosen by experiment on the balance (docs/benchmarks.md)."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    actor_learning_rate: Positive = 5.0e-3
    """Adam learning rate of the actor, decayed linearly to 0 at the end of each train.py call where
    ``linear_decay`` (a resumed run decays again over the iterations it adds)."""
    critic_learning_rate: Positive = 1.0e-3
    """Adam learning rate of the critic (decayed as the actor's)."""
    linear_decay: Flag = True
    """Decay both learning rates linearly to 0 over each train.py call's ``max_iterations``."""
    gamma: Annotated[Fraction, pydantic.Field(gt=0)] = 0.99
    """Discount factor per env step."""
    lam: Fraction = 0.95
    """TD(lambda) of the critic's targets."""
    critic_iterations: Count = 16
    """Passes over each window's states to fit the critic."""
    critic_mini_batches: Count = 4
    """Mini-batches per pass."""
    target_critic_alpha: Fraction = 0.2
    """The value of a window's end comes from a target critic: after each iteration target = alpha * target + (1 -
    alpha) * critic."""
    max_grad_norm: Positive = 1.0
    """Gradient norm clip of both networks."""
    action_noise_std: NonNegative = 0.0
    """Gaussian noise added to the actor's actions in the windows (the gradient passes through it); 0: the
    deterministic policy."""


@dataclass
class FastTd3Config:
    """Off-policy TD3 for many parallel envs (``rl.learners.fast_td3``, after FastTD3: Seo et al. 2025): every env
    step of every env goes into a replay on the device; after each iteration's ``num_steps_per_env`` steps the learner
    takes ``num_updates`` gradient steps per env step of a distributional twin critic (``num_atoms`` atoms on
    [``v_min``, ``v_max``], clipped double Q), and of the deterministic actor every ``policy_frequency``-th. Defaults:
    FastTD3's, but the smaller networks (the critic here, the actor's 256-128-64 in ``LEARNER_DEFAULTS``; FastTD3's
    are 1024-512-256 and 512-256-128), the replay's length and the support, which holds this project's returns
    (rewards of at most 1 per step, discounted by 0.99)."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    actor_learning_rate: Positive = 3.0e-4
    """AdamW learning rate of the actor."""
    critic_learning_rate: Positive = 3.0e-4
    """AdamW learning rate of the critics."""
    weight_decay: NonNegative = 0.1
    """AdamW weight decay of both."""
    gamma: Annotated[Fraction, pydantic.Field(gt=0)] = 0.99
    """Discount factor per env step."""
    tau: Annotated[Fraction, pydantic.Field(gt=0)] = 0.1
    """The target critics follow the critics by target = (1 - tau) target + tau critic after each gradient step."""
    batch_size: Count = 32768
    """Transitions per gradient step, drawn uniformly from the replay (twice as many with the mirror images)."""
    replay_steps: Count = 1024
    """Env steps of every env the replay holds (the oldest overwritten)."""
    num_updates: Count = 2
    """Gradient steps of the critics per env step."""
    policy_frequency: Count = 2
    """The actor takes a gradient step every this many of the critics'."""
    critic_hidden_dims: list[Count] = field(default_factory=lambda: [512, 256, 128])
    """Hidden layers of each critic (ReLU), on the observation and the action."""
    num_atoms: Annotated[int, pydantic.Field(ge=2)] = 101
    """Atoms of each critic's distribution of returns."""
    v_min: Finite = -10.0
    """The lowest atom (returns below it count as it)."""
    v_max: Finite = 110.0
    """The highest atom."""
    std_min: NonNegative = 0.001
    """Exploration: each env acts with Gaussian noise of a std drawn from U(std_min, std_max), drawn again when its
    episode ends."""
    std_max: NonNegative = 0.4
    """The largest exploration noise."""
    policy_noise: NonNegative = 0.001
    """Target policy smoothing: the std of the noise on the next action in the critics' targets."""
    noise_clip: NonNegative = 0.5
    """The smoothing noise is clipped to +-noise_clip."""
    init_scale: Positive = 0.01
    """The actor's last layer starts with weights ~ N(0, init_scale) and zero biases."""
    max_grad_norm: Positive | None = None
    """Gradient norm clip of each network (None: none, FastTD3's default)."""
    symmetry: Flag = True
    """Where the task has a mirror: every sampled batch is followed by its mirror image (states, actions, next
    states)."""


@dataclass
class SapgConfig:
    """Split and aggregate policy gradients (``rl.learners.sapg``, after SAPG: Singla, Agarwal and Pathak, ICML 2024):
    the run's envs are ``num_blocks`` blocks of ``env.num_envs`` envs, each block a policy's: block 0 the leader's, the
    others followers'. Every policy learns rsl-rl's PPO (``algorithm``'s settings) on its own block; the leader also
    learns from one follower's block per iteration, drawn at random, through an importance-weighted clipped surrogate
    loss and a value loss, with one-step targets of its own critic. The leader is the run's policy: evaluated, saved and
    exported."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    num_blocks: Annotated[int, pydantic.Field(ge=2)] = 4
    """Policies (the leader and ``num_blocks - 1`` followers), each with ``env.num_envs`` envs."""
    off_policy_coef: NonNegative = 1.0
    """Weight of the leader's losses on the follower's block beside those on its own (0: the leader learns PPO)."""
    dual_clip: Annotated[float, pydantic.Field(gt=1)] | None = 3.0
    """On the follower's samples, a negative advantage's surrogate loss bounded by ``dual_clip`` times its size
    (dual-clip PPO: a follower's action the leader finds far likelier than the follower did cannot dominate the
    loss; None: unbounded, as PPO's)."""
    follower_entropy_coefs: list[NonNegative] = field(default_factory=list)
    """Each follower's entropy bonus, ``num_blocks - 1`` values (empty: ``algorithm.entropy_coef`` for every one);
    SAPG's exploration by entropy gives the followers larger bonuses than the leader's."""


@dataclass
class RunnerConfig:
    """rsl-rl's ``OnPolicyRunner`` configuration (its ``train_cfg``), plus the run's length and name."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    num_steps_per_env: Count = 8
    """Env steps collected per env per iteration; a rollout holds num_envs * num_steps_per_env steps."""
    max_iterations: Count = 150
    """Iterations to run (on --resume: to add)."""
    init_at_random_ep_len: Flag = True
    """Start training with each env's time-out counter at a random point of the time limit (rsl-rl's ``learn``
    argument, as Isaac Lab's train script sets it): time-outs, hence resets from random states, spread over every
    iteration instead of arriving all at once. Reported episode lengths stay the steps each episode really ran."""
    save_interval: Count = 50
    """Write a checkpoint every this many iterations (and always at the end)."""
    experiment_name: Name | None = None
    """Folder under <log_dir>/rsl_rl that groups the runs of one experiment; None: the task's name."""
    run_name: str = ""
    """Suffix of the run folder name (empty: the timestamp alone)."""
    logger: MetricsLogger = "tensorboard"
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
    learner: Learner = "ppo"
    """The learner (``train.py --learner``): 'ppo', rsl-rl's PPO (settings ``algorithm``); 'shac', short-horizon
    analytic policy gradients through the simulator (``shac``); 'sapg', a PPO leader learning from followers' envs too
    (``sapg`` and ``algorithm``); 'fasttd3', off-policy TD3 from a replay on the device (``fasttd3``);
    docs/training.md says what each trains."""
    algorithm: PpoConfig = field(default_factory=PpoConfig)
    shac: ShacConfig = field(default_factory=ShacConfig)
    sapg: SapgConfig = field(default_factory=SapgConfig)
    fasttd3: FastTd3Config = field(default_factory=FastTd3Config)
    actor: ActorConfig = field(default_factory=ActorConfig)
    critic: ModelConfig = field(default_factory=ModelConfig)


def with_current_learner_names(data: dict, where: str) -> dict:
    """A config's dict (a preset, a saved run's ``config.yaml``: ``where``) with an old learner name
    (``RENAMED_LEARNERS``) in ``agent.learner`` and its old section as the new one's, until
    ``deprecation.REMOVED_IN``. A FutureWarning (shown by default: the user wrote or chose the file) names a learner
    asked for by its old name; the old section alone, which every config.yaml of those releases holds, is renamed
    silently."""
    agent = data.get("agent")
    if not isinstance(agent, dict):
        return data
    agent = dict(agent)
    for old, new in RENAMED_LEARNERS.items():
        if agent.get("learner") == old:
            agent["learner"] = new
            warnings.warn(f"{where}: learner {old!r} is now {new!r}; the old name goes in {REMOVED_IN}", FutureWarning,
                          stacklevel=2)
        if old in agent:
            agent[new] = agent.pop(old)
    return {**data, "agent": agent}


__getattr__ = renamed(__name__, {"ApgConfig": "ShacConfig"})
"""The old name of ``ShacConfig``, until ``deprecation.REMOVED_IN``."""
