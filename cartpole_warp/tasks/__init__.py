"""The task registry: every module in this folder that calls ``register(Task(...))`` is a task, found by name.

    import cartpole_warp
    cartpole_warp.tasks.names()   # ['cartpole-balance', 'cart-double-pole-balance', ..., 'cartpole-swingup-sparse']
    env = cartpole_warp.tasks.make("cartpole-swingup", num_envs=4096, device="cpu", seed=0)

A task module (``balance.py``, ``swingup.py``, ``double_pole.py``) holds the task's spec docstring, its ``TaskConfig``
subclass, its Warp functions, its ``BatchedEnv`` subclass and one ``register(Task(...))`` call: adding a task is adding
a module here (plus its stage and presets if it has them). A variant (``balance_sparse.py``, ``swingup_sparse.py``,
``pole_chain.py``) replaces what differs in its parent's functions, env class and ``Task``. Machinery reaches tasks only
through this registry.
"""

from __future__ import annotations

import dataclasses
import importlib
import pkgutil
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import get_args

from ..engine.env import BatchedEnv
from ..evaluation.statistics import METRICS, SolvedRule
from ..settings.agent import RENAMED_LEARNERS, Learner
from ..settings.config import (
    ConfigError,
    EnvConfig,
    apply_overrides,
    changes,
    config_errors,
    from_dict,
    merge,
    overrides_dict,
    raise_config_errors,
    require,
    stray_fields,
)
from ..settings.deprecation import REMOVED_IN
from ..settings.presets import TrainSettings, load_preset, overrides_errors

DEFAULT_TASK = "cartpole-balance"
"""The task of ``make_env``, ``train.py`` and ``play.py`` unless told otherwise."""


Configure = Callable[[TrainSettings], None]
"""A part of a task's settings: a function that sets fields of a run's config in place (``cfg.agent.max_iterations =
500``), typed as the config's dataclasses (``settings.presets.TrainSettings``)."""


def dense_path(cfg: TrainSettings):
    """SolverFeatherstone's dense path (``sim.tile_gemm`` 'off'), for a task whose GPU seeds were measured on it alone:
    the tile path ('auto' on CUDA) rounds differently, every seed's run with it, and a chain's seed that solved on one
    path did not on the other (docs/benchmarks.md, 2026-12-01). A task takes 'auto' once its seeds, run on both paths
    in one GPU session, all solve on tiles with a lower median and worst time to solved."""
    cfg.env.sim.tile_gemm = "off"


def compose(*parts: Configure | None) -> Configure | None:
    """The parts applied in order (a variant's settings: its parent's, then its own); None where none is given."""
    given = [part for part in parts if part is not None]
    if len(given) <= 1:
        return given[0] if given else None

    def configure(cfg: TrainSettings):
        for part in given:
            part(cfg)

    return configure


@dataclass(frozen=True)
class TaskSettings:
    """A task's training settings, declared once in typed code: ``common`` sets what every run of the task takes (its
    env, agent and run fields), and named here, what differs ``on_gpu`` and ``on_cpu`` (by the run's device; never
    the env, which does not depend on it) and ``for_learner`` (by the run's learner, over the learner's own defaults,
    ``settings.agent.LEARNER_DEFAULTS``). ``rl.config.train_config`` applies them in that order, then a preset, then
    the flags; ``register`` runs each and refuses one that sets a field the config has not or a value its type
    refuses. A variant made with ``dataclasses.replace`` names the settings it was measured with (``compose`` of its
    parent's ``common`` and its own, say): nothing measured for its parent comes with it unasked."""

    common: Configure | None = None
    on_gpu: Configure | None = None
    on_cpu: Configure | None = None
    for_learner: Mapping[str, Configure] = field(default_factory=dict)

    def for_device(self, device: str) -> Configure | None:
        """``on_gpu`` or ``on_cpu``, by ``device`` (a Warp/torch device name)."""
        return self.on_gpu if device.startswith("cuda") else self.on_cpu


@dataclass(frozen=True)
class Task:
    """What the machinery needs to know of a task."""

    name: str
    """Registry name, e.g. 'cartpole-swingup'; also the default experiment name of its runs."""
    env_class: type[BatchedEnv]
    """The env (its docstring is the task's spec; its config class, sizes, stage and joint roles)."""
    solved: SolvedRule
    play_metric: str
    """The ``EpisodeSummary`` mean (``statistics.METRICS``) that play.py reports first and the sweep tabulates."""
    summary: str
    """One line for ``--help``, beside the task's name."""
    settings: TaskSettings = field(default_factory=TaskSettings)
    """Its training settings (``TaskSettings``): every run's, and what differs by device and by learner; train.py
    names those that differ in its first lines."""
    gym_ids: dict[str, str | None] = field(default_factory=dict)
    """gymnasium ids (``cartpole_warp/...-v0``) and the preset each builds (None: the task's defaults)."""
    defaults: dict = field(default_factory=dict)
    gpu_defaults: dict = field(default_factory=dict)
    cpu_defaults: dict = field(default_factory=dict)
    learner_defaults: dict[str, dict] = field(default_factory=dict)
    """The settings as nested dicts, before ``settings``: ``register`` adds each, checked, after the part of
    ``settings`` it names (``common``, ``on_gpu``, ``on_cpu``, ``for_learner``), with a DeprecationWarning, until
    ``settings.deprecation.REMOVED_IN``."""


_TASKS: dict[str, Task] = {}


def register(task: Task) -> Task:
    """Add ``task`` to the registry (a task module calls this once) and return it as registered (its learners by
    their names: ``with_current_learners``; the dict settings of before ``settings`` added to it); ValueError if its
    name is taken or its ``play_metric`` names no episode mean, ConfigError naming each setting a part of its
    ``settings`` sets that the config has not and each bad value (``check_settings``)."""
    task = with_dict_settings(with_current_learners(task))
    if task.play_metric not in METRICS:
        raise ValueError(f"task {task.name!r}: play_metric {task.play_metric!r} is not one of {', '.join(METRICS)}")
    if task.name in _TASKS and _TASKS[task.name] != task:
        raise ValueError(f"task {task.name!r} is already registered")
    check_settings(task)
    _TASKS[task.name] = task
    return task


def fresh_settings(task: Task) -> TrainSettings:
    """A run's config of ``task`` as the dataclasses' defaults make it, for its settings to set."""
    cls = task.env_class.config_class
    return TrainSettings[cls](env=EnvConfig[cls](task=cls()), task=task.name)


def check_settings(task: Task):
    """Run every part of ``task.settings`` (after ``common``) on a fresh config: ConfigError naming each field a part
    sets that the config has not, each value its type refuses, and an env setting a device's part sets."""
    settings = task.settings
    parts = {"common": None, "on_gpu": settings.on_gpu, "on_cpu": settings.on_cpu,
             **{f"for_learner[{name!r}]": part for name, part in settings.for_learner.items()}}
    for label, part in parts.items():
        cfg, where = fresh_settings(task), f"task {task.name!r}: settings.{label}"
        try:
            for configure in (settings.common, part):
                before = dataclasses.asdict(cfg)
                if configure is not None:
                    configure(cfg)
        except AttributeError as err:
            raise ConfigError(f"{where}: {err}") from None
        errors = [f"unknown config key {name!r}" for name in stray_fields(cfg)]
        errors += config_errors(TrainSettings[task.env_class.config_class], dataclasses.asdict(cfg))
        if label in ("on_gpu", "on_cpu") and "env" in changes(before, dataclasses.asdict(cfg)):
            errors.append("env settings do not depend on the device")
        raise_config_errors(where, errors)


def with_dict_settings(task: Task) -> Task:
    """``task`` with the dict settings of before ``settings`` (``defaults``, ``gpu_defaults``, ``cpu_defaults``,
    ``learner_defaults``; ConfigError naming each unknown key or bad value) each added after the part it names, and
    a DeprecationWarning, until ``settings.deprecation.REMOVED_IN``."""
    dicts = {"defaults": task.defaults, "gpu_defaults": task.gpu_defaults, "cpu_defaults": task.cpu_defaults}
    if not any(dicts.values()) and not task.learner_defaults:
        return task
    warnings.warn(f"task {task.name!r}: Task(defaults=, gpu_defaults=, cpu_defaults=, learner_defaults=) is now "
                  "Task(settings=TaskSettings(common=, on_gpu=, on_cpu=, for_learner=)), functions that set the "
                  f"config's fields; the dicts go in {REMOVED_IN}", DeprecationWarning, stacklevel=3)
    env_type = EnvConfig[task.env_class.config_class]
    for name, data in dicts.items():
        device_env = ["env settings do not depend on the device"] * (name != "defaults" and "env" in data)
        raise_config_errors(f"task {task.name!r}: {name}",
                            overrides_errors(data, env_type if name == "defaults" else None) + device_env)
    for learner, data in task.learner_defaults.items():
        raise_config_errors(f"task {task.name!r}: learner_defaults[{learner!r}]", overrides_errors(data, env_type))
    settings = task.settings
    learners = {name: compose(settings.for_learner.get(name), setter(data))
                for name, data in task.learner_defaults.items()}
    settings = TaskSettings(compose(settings.common, setter(task.defaults)),
                            compose(settings.on_gpu, setter(task.gpu_defaults)),
                            compose(settings.on_cpu, setter(task.cpu_defaults)), {**settings.for_learner, **learners})
    return dataclasses.replace(task, settings=settings, defaults={}, gpu_defaults={}, cpu_defaults={},
                               learner_defaults={})


def setter(overrides: dict) -> Configure | None:
    """A part that sets ``overrides`` (nested dicts; ``settings.presets.apply_overrides``); None for none."""
    return (lambda cfg: apply_overrides(cfg, overrides)) if overrides else None


def with_current_learners(task: Task) -> Task:
    """``task`` with its settings for learners (``settings.for_learner``, ``learner_defaults``) keyed by the learners'
    names: an old name (``RENAMED_LEARNERS``) as the new, with a DeprecationWarning, until
    ``settings.deprecation.REMOVED_IN``; ConfigError for a name no learner has."""
    def current(field_name: str, by_learner: Mapping) -> dict:
        learners = {}
        for name, part in by_learner.items():
            if name in RENAMED_LEARNERS:
                warnings.warn(f"task {task.name!r}: {field_name}[{name!r}] is now [{RENAMED_LEARNERS[name]!r}]; the "
                              f"old name goes in {REMOVED_IN}", DeprecationWarning, stacklevel=4)  # register's caller
                name = RENAMED_LEARNERS[name]
            require(name in get_args(Learner), f"task {task.name!r}: {field_name} names {name!r}, no learner "
                                               f"(the learners: {', '.join(get_args(Learner))})")
            learners[name] = part
        return learners

    settings = dataclasses.replace(task.settings, for_learner=current("settings.for_learner",
                                                                      task.settings.for_learner))
    return dataclasses.replace(task, settings=settings,
                               learner_defaults=current("learner_defaults", task.learner_defaults))


def _discover():
    for module in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{module.name}")


def names() -> list[str]:
    """The registered task names, the default first."""
    _discover()
    return sorted(_TASKS, key=lambda name: (name != DEFAULT_TASK, name))


def get(name: str) -> Task:
    """The task called ``name``; ConfigError listing the known tasks if there is none."""
    if name not in names():
        raise ConfigError(f"unknown task {name!r}; known tasks: {', '.join(names())}")
    return _TASKS[name]


def preset_overrides(name: str, preset: str | None) -> dict:
    """The overrides preset ``preset`` holds for task ``name`` (``load_preset``: every section checked, its ``env``
    against the task's settings; ConfigError for a preset that names another task); {} for no preset."""
    return {} if preset is None else load_preset(preset, name, EnvConfig[get(name).env_class.config_class])


def env_config(name: str, preset: str | None = None, *, preset_data: dict | None = None, **overrides) -> EnvConfig:
    """The env config of task ``name``, validated: the dataclass defaults, what the task's settings set in it
    (``TaskSettings.common``), the preset's ``env`` section (``preset_data``: the preset as ``preset_overrides`` read
    it, where the caller has), then nested keyword overrides (``num_envs=64, sim={"solver": "mujoco"}, task={...}``;
    None values ignored)."""
    task = get(name)
    cfg = fresh_settings(task)
    if task.settings.common is not None:
        task.settings.common(cfg)
    data = dataclasses.asdict(cfg.env)
    where = f"task {name!r}" + (f", preset {preset!r}" if preset else "")
    if preset is not None:
        preset_data = preset_overrides(name, preset) if preset_data is None else preset_data
        data = merge(data, overrides_dict(preset_data.get("env", {}), f"preset {preset!r}: env:"))
    data = merge(data, overrides_dict({k: v for k, v in overrides.items() if v is not None}, "overrides:"))
    return from_dict(EnvConfig[task.env_class.config_class], data, where).validate()


def make(name: str, num_envs: int | None = None, device: str | None = None, seed: int | None = None,
         preset: str | None = None, **overrides) -> BatchedEnv:
    """Build task ``name``'s env from its defaults, a preset (a name under configs/ or a YAML path) and nested
    overrides of the env config: ``sim={"solver": "mujoco"}``, ``task={"episode_length_s": 5}`` (``task`` here means
    the task's settings; the task itself is ``name``)."""
    cfg = env_config(name, preset, num_envs=num_envs, device=device, seed=seed, **overrides)
    return get(name).env_class(cfg)


__all__ = ["DEFAULT_TASK", "SolvedRule", "Task", "env_config", "get", "make", "names", "preset_overrides", "register"]
