"""Preset files and the schema they are checked against: the run settings, and the one loader that refuses an unknown
section or key anywhere, whoever loads the preset (``train.py --config``, ``make_env``, ``gym.make``). A preset
(``configs/<name>.yaml`` or a YAML path) holds partial overrides of ``rl.config.TrainConfig``; its ``agent`` section
is checked against rsl-rl's settings (``agent.py``), its ``env`` section against the task's own settings where the
task is known (``tasks.env_config``), and a preset that names another task is refused.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, Literal

import yaml

from .agent import RunnerConfig, with_current_learner_names
from .config import (
    NO_UNKNOWN_KEYS,
    ConfigError,
    Count,
    EnvConfig,
    Flag,
    Name,
    NonNegativeInt,
    TaskT,
    config_errors,
    merge,
    overrides_dict,
    raise_config_errors,
    require,
)
from .files import data_path

Console = Literal["compact", "rsl_rl"]


@dataclass
class EvalConfig:
    """The deterministic evaluation that decides 'solved' and picks the best checkpoint: the policy's mean action,
    each env's first episode from the run's seed to the time limit, on a batch of envs of its own (or inside the
    training's: ``in_step``). With ``num_envs`` equal to play.py's --num-envs (256 by default) these are the episodes
    ``play.py --headless`` plays."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    num_envs: Count = 256
    """Envs (one episode each) of an evaluation."""
    min_interval: Count = 5
    """Evaluate when an iteration's training episodes meet the task's solved rule, at most once in this many
    iterations ..."""
    max_interval: Count = 25
    """... and after this many iterations without an evaluation (a policy that fails only through its exploration
    noise)."""
    in_step: Flag = False
    """Run the evaluation's envs inside the training's env, stepped with it by a frozen copy of the policy (one
    evaluation at a time, its verdict an episode later), instead of as an env of their own between iterations."""


@dataclass
class RunSettings:
    """Where runs go and what the console shows (the top-level fields of a training config besides its task, env
    and agent)."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    log_dir: Name = "logs"
    """Root folder of all runs; a run lives in <log_dir>/rsl_rl/<agent.experiment_name>/<timestamp>[_<run_name>]."""
    console: Console = "compact"
    """Console output per iteration: 'compact' (one line) or 'rsl_rl' (rsl-rl's block)."""
    stop_when_solved: Flag = True
    """End training at the first evaluation that meets the task's solved rule (``eval``); --no-stop-when-solved
    trains all of --max-iterations."""
    eval: EvalConfig = field(default_factory=EvalConfig)
    torch_threads: NonNegativeInt = 1
    """CPU threads for torch (torch.set_num_threads); 0 keeps torch's default. 1 is fastest on small CPUs: the
    networks are tiny, and more threads fight the env and other processes for cores (oversubscribed cores slow both)."""

    def apply_torch_threads(self) -> None:
        """Set torch's CPU threads to ``torch_threads`` (0: leave torch's default)."""
        if self.torch_threads:
            import torch

            torch.set_num_threads(self.torch_threads)


@dataclass(kw_only=True)
class TrainSettings(RunSettings, Generic[TaskT]):
    """A training config's settings (``rl.config.TrainConfig``'s fields), as a task's settings functions set them in
    place (``tasks.TaskSettings``): the env, the task's name, the agent (rsl-rl's runner, ``settings.agent``) and
    the run's fields."""

    __pydantic_config__ = NO_UNKNOWN_KEYS

    env: EnvConfig[TaskT]
    task: Name = ""
    """The registered task's name (``rl.config.TrainConfig`` gives its default)."""
    agent: RunnerConfig = field(default_factory=RunnerConfig)


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


RETIRED_PRESETS = {"swingup_gpu": "a task's settings for a GPU come with the task now, taken where --device is cuda"}
"""Presets that are gone, and why."""


def load_preset(preset: str, task: str | None = None, env_type: type | None = None) -> dict:
    """The overrides a preset holds, as a nested dict: a name under ``configs/`` or a path to a YAML file. ConfigError
    naming every unknown section or key and bad value (in ``env`` only where its type ``env_type``, the task's
    ``EnvConfig[...]``, is given), or a preset that names another task than ``task`` (a preset without ``task:``
    applies to any)."""
    path = Path(preset)
    if path.suffix not in (".yaml", ".yml"):
        path = data_path("configs", f"{preset}.yaml")
        require(preset not in RETIRED_PRESETS, f"preset {preset!r} is retired: {RETIRED_PRESETS.get(preset)}")
        require(path.is_file(), f"unknown preset {preset!r}; known presets: {', '.join(presets())}")
    require(path.is_file(), f"config file {path} does not exist")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise ConfigError(f"cannot parse {path}: {err}") from None
    data = with_current_learner_names(overrides_dict(data, f"{path}: expected a mapping at the top level;"), str(path))
    raise_config_errors(f"preset {preset!r}", overrides_errors(data, env_type))
    require(task is None or data.get("task", task) == task,
            f"preset {preset!r} is for task {data.get('task')!r}, not {task!r}")
    return with_paths_from(path.parent, data)


def with_paths_from(folder: Path, data: dict) -> dict:
    """A preset's ``env.sim.stage_path`` as a path that works from any folder: a relative one is the preset's
    ``folder``'s file, unless that folder has none and the package has a stage of that name (``SimConfig.stage_path``:
    ``multiarm_pendulum.usda``)."""
    sim = data.get("env", {}).get("sim", {}) if isinstance(data.get("env"), dict) else {}
    stage = sim.get("stage_path") if isinstance(sim, dict) else None
    if not isinstance(stage, str) or not stage or Path(stage).is_absolute():
        return data
    beside = (folder / stage).resolve()
    if beside.is_file() or not data_path("usd", stage).is_file():
        sim["stage_path"] = str(beside)
    return data


def overrides_errors(data: dict, env_type: type | None = None) -> list[str]:
    """Every unknown section or key and bad value of ``data``, partial overrides of a training config (a preset's, or
    a task's defaults), its ``env`` section checked against ``env_type`` (the task's ``EnvConfig[...]``) where given."""
    errors = config_errors(PresetFile, merge(dataclasses.asdict(PresetFile()), data))
    if env_type is not None and isinstance(data.get("env"), dict):
        errors += config_errors(env_type, data["env"], key_prefix="env.")
    return errors
