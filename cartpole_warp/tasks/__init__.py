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
from dataclasses import dataclass, field
from typing import get_args

from ..engine.env import BatchedEnv
from ..evaluation.statistics import METRICS, SolvedRule
from ..settings.agent import RENAMED_LEARNERS, Learner
from ..settings.config import ConfigError, EnvConfig, from_dict, merge, overrides_dict, raise_config_errors, require
from ..settings.deprecation import REMOVED_IN
from ..settings.presets import load_preset, overrides_errors

DEFAULT_TASK = "cartpole-balance"
"""The task of ``make_env``, ``train.py`` and ``play.py`` unless told otherwise."""


DENSE_PATH = {"env": {"sim": {"tile_gemm": "off"}}}
"""The defaults of a task whose GPU seeds were measured on SolverFeatherstone's dense path alone: the tile path
(``sim.tile_gemm``, 'auto' on CUDA) rounds differently, every seed's run with it, and a chain's seed that solved on
one path did not on the other (docs/benchmarks.md, 2026-12-01). A task takes 'auto' once its seeds, run on both paths
in one GPU session, all solve on tiles with a lower median and worst time to solved."""


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
    defaults: dict = field(default_factory=dict)
    """Nested overrides of the training config (``env``, ``agent`` sections) that make this task's defaults, applied
    before a preset and the flags."""
    gpu_defaults: dict = field(default_factory=dict)
    """Overrides of ``defaults`` (``agent`` and run sections, no ``env``) where the run's device is a GPU: settings
    whose best value differs by device (there a gradient step costs its kernel launches whatever its batch, and a small
    evaluation as much as a large one; on a CPU both cost their samples). train.py names them in its first lines. A
    variant made with ``dataclasses.replace`` inherits them: give it its own (``{}``: none) unless measured with
    them."""
    cpu_defaults: dict = field(default_factory=dict)
    """Overrides of ``defaults`` (``agent`` and run sections, no ``env``) where the run's device is a CPU, as
    ``gpu_defaults`` where it is a GPU (there a network's width costs little; on a CPU every product and activation
    costs its samples). train.py names them in its first lines; a variant inherits them as ``gpu_defaults``."""
    learner_defaults: dict[str, dict] = field(default_factory=dict)
    """Per learner, what this task tunes for it (``env``, ``agent`` and run sections) over the learner's own defaults
    (``settings.agent.LEARNER_DEFAULTS``) where the run trains with ``--learner NAME``; train.py names them in its first
    lines. A variant made with ``dataclasses.replace`` inherits them: give it its own (``{}``: none) unless measured
    with them."""
    gym_ids: dict[str, str | None] = field(default_factory=dict)
    """gymnasium ids (``cartpole_warp/...-v0``) and the preset each builds (None: the task's defaults)."""


_TASKS: dict[str, Task] = {}


def register(task: Task) -> Task:
    """Add ``task`` to the registry (a task module calls this once) and return it as registered (its learners by
    their names: ``with_current_learners``); ValueError if its name is taken or its ``play_metric`` names no episode
    mean, ConfigError naming each unknown key or bad value of its ``defaults``."""
    task = with_current_learners(task)
    if task.play_metric not in METRICS:
        raise ValueError(f"task {task.name!r}: play_metric {task.play_metric!r} is not one of {', '.join(METRICS)}")
    if task.name in _TASKS and _TASKS[task.name] != task:
        raise ValueError(f"task {task.name!r} is already registered")
    raise_config_errors(f"task {task.name!r}: defaults",
                        overrides_errors(task.defaults, EnvConfig[task.env_class.config_class]))
    for name, defaults in (("gpu_defaults", task.gpu_defaults), ("cpu_defaults", task.cpu_defaults)):
        raise_config_errors(f"task {task.name!r}: {name}", overrides_errors(defaults)
                            + ["env settings do not depend on the device"] * ("env" in defaults))
    for learner, defaults in task.learner_defaults.items():
        raise_config_errors(f"task {task.name!r}: learner_defaults[{learner!r}]",
                            overrides_errors(defaults, EnvConfig[task.env_class.config_class]))
    _TASKS[task.name] = task
    return task


def with_current_learners(task: Task) -> Task:
    """``task`` with its ``learner_defaults`` keyed by the learners' names: an old name (``RENAMED_LEARNERS``) as the
    new, with a DeprecationWarning, until ``settings.deprecation.REMOVED_IN``; ConfigError for a name no learner has."""
    learners = {}
    for name, defaults in task.learner_defaults.items():
        if name in RENAMED_LEARNERS:
            warnings.warn(f"task {task.name!r}: learner_defaults[{name!r}] is now [{RENAMED_LEARNERS[name]!r}]; the "
                          f"old name goes in {REMOVED_IN}", DeprecationWarning, stacklevel=3)  # register's caller
            name = RENAMED_LEARNERS[name]
        require(name in get_args(Learner), f"task {task.name!r}: learner_defaults names {name!r}, no learner "
                                           f"(the learners: {', '.join(get_args(Learner))})")
        learners[name] = defaults
    return task if learners == task.learner_defaults else dataclasses.replace(task, learner_defaults=learners)


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
    """The env config of task ``name``, validated: the dataclass defaults, the task's defaults, the preset's ``env``
    section (``preset_data``: the preset as ``preset_overrides`` read it, where the caller has), then nested keyword
    overrides (``num_envs=64, sim={"solver": "mujoco"}, task={...}``; None values ignored)."""
    task = get(name)
    cls = EnvConfig[task.env_class.config_class]
    data = merge(dataclasses.asdict(cls(task=task.env_class.config_class())), task.defaults.get("env", {}))
    where = f"task {name!r}" + (f", preset {preset!r}" if preset else "")
    if preset is not None:
        preset_data = preset_overrides(name, preset) if preset_data is None else preset_data
        data = merge(data, overrides_dict(preset_data.get("env", {}), f"preset {preset!r}: env:"))
    data = merge(data, overrides_dict({k: v for k, v in overrides.items() if v is not None}, "overrides:"))
    return from_dict(cls, data, where).validate()


def make(name: str, num_envs: int | None = None, device: str | None = None, seed: int | None = None,
         preset: str | None = None, **overrides) -> BatchedEnv:
    """Build task ``name``'s env from its defaults, a preset (a name under configs/ or a YAML path) and nested
    overrides of the env config: ``sim={"solver": "mujoco"}``, ``task={"episode_length_s": 5}`` (``task`` here means
    the task's settings; the task itself is ``name``)."""
    cfg = env_config(name, preset, num_envs=num_envs, device=device, seed=seed, **overrides)
    return get(name).env_class(cfg)


__all__ = ["DEFAULT_TASK", "SolvedRule", "Task", "env_config", "get", "make", "names", "preset_overrides", "register"]
