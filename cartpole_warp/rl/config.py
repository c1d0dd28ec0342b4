"""Training configuration: ``task`` names the registered task, ``agent`` is shaped like rsl-rl's own ``train_cfg``
(``rl.policies.to_rsl_rl``), ``env`` is the task's ``EnvConfig``; the rest says where runs go and what the console
shows.

The defaults are the dataclass defaults, then the task's own (``tasks.TaskSettings``), resolved in one pass with the
learner's and a preset's by ``train_config``. A preset (``configs/<name>.yaml``) holds partial overrides of
``TrainConfig`` (sections ``env``, ``agent`` and the top-level fields); ``train.py`` and ``play.py`` take every field
as a flag (``--agent.algorithm.entropy-coef 0.01``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from .. import tasks
from ..settings.agent import (
    LEARNER_CPU_DEFAULTS,
    LEARNER_DEFAULTS,
    PPO_UPDATE_LEARNERS,
    ActorConfig,
    DistributionConfig,
    ModelConfig,
    PpoConfig,
    RunnerConfig,
    with_current_learner_names,
)
from ..settings.config import (
    NO_UNKNOWN_KEYS,
    ConfigError,
    Name,
    TaskT,
    apply_overrides,
    changes,
    checked,
    from_dict,
    merge,
    overrides_dict,
    require,
)
from ..settings.presets import TrainSettings


@dataclass(kw_only=True)
class TrainConfig(TrainSettings[TaskT]):
    """Everything ``train.py`` needs: the task, its env, rsl-rl's runner configuration and where the run goes."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    task: Name = tasks.DEFAULT_TASK
    """The registered task (``cartpole_warp.tasks.names()``), which picks its settings."""

    @property
    def task_spec(self) -> tasks.Task:
        """The registered task that ``task`` names (its env class, solved rule, play metric): the one lookup by name
        that training needs, passed along from here."""
        return tasks.get(self.task)

    @property
    def experiment(self) -> str:
        """The experiment folder's name: ``agent.experiment_name``, or the task's name."""
        return self.agent.experiment_name or self.task

    def validate(self) -> TrainConfig[TaskT]:
        """Raise ConfigError naming the first invalid value and what is allowed; return self (each field's type and
        range are checked by ``checked`` where flags become a config; the checks here relate fields)."""
        self.env.validate()
        require(isinstance(self.env.task, self.task_spec.env_class.config_class),
                f"env.task holds {type(self.env.task).__name__}, not the settings of task {self.task!r}")
        require(self.eval.min_interval <= self.eval.max_interval,
                f"eval.min_interval ({self.eval.min_interval}) must be at most eval.max_interval "
                f"({self.eval.max_interval})")
        rollout = self.env.num_envs * self.agent.num_steps_per_env
        mini_batches = self.agent.algorithm.num_mini_batches
        require(self.agent.learner not in PPO_UPDATE_LEARNERS or rollout % mini_batches == 0,
                f"agent.algorithm.num_mini_batches ({mini_batches}) must divide num_envs * agent.num_steps_per_env "
                f"({rollout})")
        sapg = self.agent.sapg
        followers, entropies = sapg.num_blocks - 1, len(sapg.follower_entropy_coefs)
        require(entropies in (0, followers), f"agent.sapg.follower_entropy_coefs: {entropies} given for {followers} "
                                             "followers (agent.sapg.num_blocks - 1)")
        return self


def train_config(task: str = tasks.DEFAULT_TASK, preset: str | None = None, device: str | None = None,
                 learner: str | None = None) -> TrainConfig:
    """TrainConfig of ``task``, resolved in one pass: the dataclass defaults; the task's settings
    (``tasks.TaskSettings``: every run's, then its device's); where a learner is chosen (``learner``, the flag, or the
    one the preset names), the learner's own defaults (``settings.agent.LEARNER_DEFAULTS``) and what the task tunes
    for it; then the preset (ConfigError for another task's), so that its settings win over the task's and the
    learner's, and ``device``; then one check of every value (flags may still change them: ``validate`` after them)."""
    preset_data = tasks.preset_overrides(task, preset)
    spec = tasks.get(task)
    cfg = tasks.fresh_settings(spec)
    run_device = device or preset_data.get("env", {}).get("device")
    chosen = learner or preset_data.get("agent", {}).get("learner")
    _apply(cfg, spec.settings.common)
    _apply(cfg, spec.settings.for_device(run_device or cfg.env.device))
    if chosen is not None:
        apply_overrides(cfg, own_learner_defaults(chosen, run_device or cfg.env.device))
        _apply(cfg, spec.settings.for_learner.get(chosen))
        cfg.agent.learner = chosen
    data = dataclasses.asdict(cfg)
    if preset is not None:
        data = merge(data, overrides_dict(preset_data, f"preset {preset!r}:"))
    if device is not None:
        data["env"]["device"] = device
    where = f"task {task!r}" + (f", preset {preset!r}" if preset else "")
    resolved = from_dict(TrainConfig[spec.env_class.config_class], data, where)
    resolved.env.validate()
    return resolved


def _apply(cfg: TrainSettings, configure: tasks.Configure | None):
    if configure is not None:
        configure(cfg)


def changed_by(task: tasks.Task, part: tasks.Configure | None, before: list) -> dict:
    """What ``part`` of ``task``'s settings changes (nested overrides) in a fresh config once ``before`` (parts, or
    dicts of overrides) have been applied to it."""
    cfg = tasks.fresh_settings(task)
    for earlier in before:
        if isinstance(earlier, dict):
            apply_overrides(cfg, earlier)
        else:
            _apply(cfg, earlier)
    unchanged = dataclasses.asdict(cfg)
    _apply(cfg, part)
    return changes(unchanged, dataclasses.asdict(cfg))


def on_gpu(device: str) -> bool:
    """Whether ``device`` (a Warp/torch device name) is a GPU."""
    return device.startswith("cuda")


def device_defaults(task: tasks.Task, device: str) -> dict:
    """What the task's settings for ``device`` change (``TaskSettings.for_device``), as nested overrides; {} for
    nothing."""
    return changed_by(task, task.settings.for_device(device), [task.settings.common])


def device_settings(cfg: TrainConfig) -> dict[str, object]:
    """The settings the task chooses for ``cfg``'s device (``device_defaults``), by dotted name, with the values
    ``cfg`` has (a flag may have changed them); {} where the task chooses none."""
    return chosen_settings(cfg, device_defaults(cfg.task_spec, cfg.env.device))


def gpu_settings(cfg: TrainConfig) -> dict[str, object]:
    """``device_settings`` where ``cfg`` runs on a GPU; {} on a CPU."""
    return device_settings(cfg) if on_gpu(cfg.env.device) else {}


def own_learner_defaults(learner: str, device: str) -> dict:
    """What ``learner`` changes in every task's runs on ``device``: ``settings.agent.LEARNER_DEFAULTS``, on a CPU
    then ``LEARNER_CPU_DEFAULTS``, as nested overrides."""
    own = LEARNER_DEFAULTS.get(learner, {})
    return own if on_gpu(device) else merge(own, LEARNER_CPU_DEFAULTS.get(learner, {}))


def learner_defaults(task: tasks.Task, learner: str, device: str = "cuda") -> dict:
    """What ``learner`` changes in ``task``'s runs on ``device``: its own defaults (``own_learner_defaults``), then
    what the task tunes for it (``TaskSettings.for_learner``), as nested overrides."""
    own = own_learner_defaults(learner, device)
    return merge(own, changed_by(task, task.settings.for_learner.get(learner), [task.settings.common, own]))


def learner_settings(cfg: TrainConfig) -> dict[str, object]:
    """The settings ``cfg``'s learner and the task choose for it on its device (``learner_defaults``), as
    ``gpu_settings``; {} where they choose none (PPO, ``sapg``)."""
    return chosen_settings(cfg, learner_defaults(cfg.task_spec, cfg.agent.learner, cfg.env.device))


def chosen_settings(cfg: TrainConfig, defaults: dict) -> dict[str, object]:
    """The leaves of ``defaults`` (nested overrides) by dotted name, with the values ``cfg`` has."""

    def leaves(data: dict, prefix: str = "") -> list[str]:
        return [name for key, value in data.items()
                for name in (leaves(value, f"{prefix}{key}.") if isinstance(value, dict) else [f"{prefix}{key}"])]

    def value(name: str) -> object:
        node = cfg
        for part in name.split("."):
            node = getattr(node, part)
        return node

    return {name: value(name) for name in leaves(defaults)}


def with_env_preset(cfg: TrainConfig, preset: str) -> TrainConfig:
    """``cfg`` with the ``env`` section of ``preset`` on top, its ``randomization`` replacing the run's whole (a trained
    run played on other physics: its training settings stay); ConfigError where the preset is another task's or sets
    more than the env."""
    data = tasks.preset_overrides(cfg.task, preset)
    extra = sorted(set(data) - {"env", "task"})
    require(not extra, f"--config {preset} on a trained run may set only env settings (the run's training settings "
                       f"stay); it sets {', '.join(extra)}")
    env = overrides_dict(data.get("env", {}), f"preset {preset!r}: env:")
    base = dataclasses.asdict(cfg)
    if "randomization" in env:  # the preset's physics, not a mix with the run's ranges
        base["env"]["randomization"] = dataclasses.asdict(type(cfg.env.randomization)())
    return from_dict(TrainConfig[type(cfg.env.task)], merge(base, {"env": env}), f"the run's config, preset {preset!r}")


def load_train_config(data: dict, where: str) -> TrainConfig:
    """A saved TrainConfig (a run's ``config.yaml``) from its dict: the task it names picks the settings' class, and
    its defaults fill any field the file lacks (one written before the field existed)."""
    task = overrides_dict(data, f"{where}:").get("task", tasks.DEFAULT_TASK)
    base, saved = train_config(task), with_current_learner_names(data, where)
    return from_dict(TrainConfig[type(base.env.task)], merge(dataclasses.asdict(base), saved), where)


__all__ = ["ActorConfig", "ConfigError", "DistributionConfig", "ModelConfig", "PpoConfig", "RunnerConfig",
           "TrainConfig", "checked", "device_settings", "gpu_settings", "learner_settings", "load_train_config",
           "train_config", "with_env_preset"]
