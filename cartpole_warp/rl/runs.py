"""Run folders: layout, resolved config, atomic writes, checkpoints, ``summary.json``.

A run lives in ``<log_dir>/rsl_rl/<experiment>/<timestamp>[_<run_name>]/`` and holds ``config.yaml`` (the resolved
``TrainConfig``; play.py rebuilds the env from it), ``model_<iteration>.pt`` checkpoints, ``summary.json``
(``RunSummary``), ``learning_curve.png``, the exports (``exported/policy.onnx``, ``policy.pt2``, ``policy.pt``) and the
logger's event files; ``play/`` gets play.py's pictures and result.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import importlib.metadata
import json
import platform
import re
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import yaml

from ..settings.config import ConfigError
from ..settings.files import write_text
from .config import TrainConfig, load_train_config

CONFIG_FILE = "config.yaml"
SUMMARY_FILE = "summary.json"
CURVE_FILE = "learning_curve.png"
EXPORT_DIR = "exported"
PLAY_DIR = "play"
TRAINER_DIR = "rsl_rl"
"""Folder under ``log_dir`` that holds the experiments (Isaac Lab's layout: logs/rsl_rl/<experiment>)."""
BEST_CHECKPOINT = "model_best.pt"
"""The checkpoint whose evaluation was the best of the run (play.py's default)."""
MEMBERS_FILE, POPULATION_FILE = "members.md", "population.json"
"""A population's folder: its members' table and its own summary (each member a run folder beside them)."""
LINEAGE_FILE = "lineage.json"
"""A population member's exploits under population-based training (``rl.modes.Exploitation``), in its run folder."""
_CHECKPOINT = re.compile(r"^model_(\d+)\.pt$")


class RunError(ValueError):
    """A run folder, checkpoint or config is missing or unusable; the message names the path."""


def experiment_dir(log_dir: str | Path, experiment: str) -> Path:
    """``<log_dir>/rsl_rl/<experiment>``: the folder holding one experiment's runs."""
    return Path(log_dir) / TRAINER_DIR / experiment


def new_run_dir(log_dir: str | Path, experiment: str, run_name: str = "") -> Path:
    """A fresh ``<log_dir>/rsl_rl/<experiment>/<YYYY-mm-dd_HH-MM-SS>[_<run_name>]`` path (not created yet)."""
    if run_name and not re.fullmatch(r"[\w.-]+", run_name):
        raise ConfigError(f"run name {run_name!r} may hold only letters, digits, '_', '-' and '.'")
    stamp = datetime.datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    base = experiment_dir(log_dir, experiment) / (f"{stamp}_{run_name}" if run_name else stamp)
    path, n = base, 1
    while path.exists():
        path, n = base.with_name(f"{base.name}-{n}"), n + 1
    return path


def list_checkpoints(run_dir: Path) -> list[Path]:
    """The run's ``model_<iteration>.pt`` files, oldest iteration first."""
    found = [(int(m.group(1)), p) for p in Path(run_dir).glob("model_*.pt") if (m := _CHECKPOINT.match(p.name))]
    return [p for _, p in sorted(found)]


def latest_checkpoint(run_dir: Path) -> Path:
    """The checkpoint with the highest iteration in ``run_dir``."""
    if not Path(run_dir).is_dir():
        raise RunError(f"no run folder {run_dir}")
    checkpoints = list_checkpoints(run_dir)
    if not checkpoints:
        members = population_members(Path(run_dir))
        hint = (f": it is a population of {len(members)} members ({', '.join(m.name for m in members)}); give one "
                f"member's folder, e.g. the best-evaluated, {best_member(members)}" if members else "")
        raise RunError(f"no checkpoint (model_<iteration>.pt) in {run_dir}{hint}")
    return checkpoints[-1]


def population_members(folder: Path) -> list[Path]:
    """The members' run folders of a population's folder (the one holding ``population.json``), else []."""
    table = folder / POPULATION_FILE
    return [folder / row["member"] for row in json.loads(table.read_text())["members"]] if table.is_file() else []


def best_member(members: list[Path]) -> Path:
    """The member whose best evaluation (``RunSummary.best``) is the best: solved first, then by its play metric;
    the first member where none has been evaluated."""
    def rank(member: Path) -> tuple:
        summary = member / SUMMARY_FILE
        best = (json.loads(summary.read_text()).get("best") if summary.is_file() else None) or {}
        metric = next((value for key, value in best.items() if key not in ("iteration", "solved")), None)
        return bool(best.get("solved")), metric if metric is not None else float("-inf")

    return max(members, key=rank)


def populations(experiment: Path) -> list[Path]:
    """The population folders among an experiment's runs (``experiment_dir``), oldest first."""
    return sorted(p for p in Path(experiment).glob("*") if population_members(p))


def newer_populations(run_dir: Path) -> list[Path]:
    """The population folders of ``run_dir``'s experiment newer than it (by name, i.e. timestamp)."""
    return [p for p in populations(Path(run_dir).parent) if p.name > Path(run_dir).name]


def copy_policy(run_dir: Path, into: Path) -> list[Path]:
    """The policy of the run in ``run_dir`` copied ``into`` another folder, which then plays and exports as that run
    (``play.py --run``): its ``config.yaml``, ``model_best.pt`` (its best evaluation's policy) and exports; the copies
    out."""
    copies = [Path(shutil.copy2(run_dir / name, into / name)) for name in (CONFIG_FILE, BEST_CHECKPOINT)]
    return copies + [Path(shutil.copytree(run_dir / EXPORT_DIR, into / EXPORT_DIR, dirs_exist_ok=True))]


def play_checkpoint(run_dir: Path) -> Path:
    """The checkpoint play.py loads from a run: its best (``model_best.pt``) where it has one, else its latest."""
    best = Path(run_dir) / BEST_CHECKPOINT
    return best if best.is_file() else latest_checkpoint(run_dir)


def find_checkpoint(checkpoint: str | Path | None, run: str | Path | None, newest_run: Callable[[], Path],
                    pick: Callable[[Path], Path], run_flag: str) -> Path:
    """The checkpoint a program starts from: ``checkpoint`` where given (it must exist, and lie in ``run`` where that
    is given too: the program's ``run_flag``), else ``pick``'s of ``run`` or, without one, of ``newest_run()`` (the
    program's ``latest_run``)."""
    if checkpoint:
        path = Path(checkpoint)
        if not path.is_file():
            raise RunError(f"checkpoint {path} not found")
        if run and Path(run).resolve() != path.parent.resolve():
            raise ConfigError(f"--checkpoint {path} is not in {run_flag} {run}: a checkpoint belongs to its own run "
                              "folder (its config.yaml, its play/): give one of them")
        return path
    return pick(Path(run) if run else newest_run())


def latest_run(log_dir: str | Path, experiment: str, experiment_flag: str = "--agent.experiment-name") -> Path:
    """The newest run folder (by name, i.e. timestamp) of ``experiment`` that holds a config and a checkpoint
    (``experiment_flag``: the program's flag that names another experiment, for the error)."""
    root = experiment_dir(log_dir, experiment)
    runs = sorted(p for p in root.glob("*") if (p / CONFIG_FILE).is_file() and list_checkpoints(p))
    if not runs:
        others = sorted(p.name for p in root.parent.glob("*") if p.is_dir())
        hint = (f" (experiments there: {', '.join(others)}; pick one with --task or {experiment_flag})"
                if others else "")
        found = populations(root)
        if found:
            hint += (f"; it holds populations, the newest {found[-1]}: give one member's folder, e.g. "
                     f"the best-evaluated, {best_member(population_members(found[-1]))}")
        raise RunError(f"no checkpoint under {root}{hint}; run train.py first or pass --checkpoint")
    return runs[-1]


def save_config(run_dir: Path, cfg: TrainConfig) -> Path:
    """Write the resolved config as ``config.yaml``."""
    return write_text(Path(run_dir) / CONFIG_FILE, yaml.safe_dump(dataclasses.asdict(cfg), sort_keys=False))


def load_config(run_dir: Path) -> TrainConfig:
    """The TrainConfig a run was trained with (its ``config.yaml``)."""
    path = Path(run_dir) / CONFIG_FILE
    if not path.is_file():
        raise RunError(f"{path} not found: is {run_dir} a run folder?")
    try:
        return load_train_config(yaml.safe_load(path.read_text()) or {}, str(path))
    except (yaml.YAMLError, ConfigError) as err:
        raise RunError(f"cannot read {path}: {err}") from None


def versions() -> dict[str, str]:
    """Versions of Python and the packages a run depends on."""
    result = {"python": platform.python_version()}
    for name in ("cartpole_warp", "torch", "warp-lang", "newton", "rsl-rl-lib"):
        with contextlib.suppress(importlib.metadata.PackageNotFoundError):
            result[name] = importlib.metadata.version(name)
    return result


@dataclass
class Progress:
    """Where training stands; saved in every checkpoint (``infos``) so that ``--resume`` continues it."""

    iterations: int = 0
    env_steps: int = 0
    train_time_s: float = 0.0
    solved_at: dict | None = None
    """``{"iterations", "env_steps", "train_time_s", <play metric>}`` of the first evaluation that met the task's
    rule: the iterations and env steps that trained the judged policy, the training seconds until the verdict (later
    for an evaluation inside the step, ``eval.in_step``)."""
    best: dict | None = None
    """``{"iteration", "solved", <play metric>}`` of the best evaluation so far (its policy: ``model_best.pt``)."""
    history: list[dict] = field(default_factory=list)
    """One entry per iteration: the training episodes' means, env steps, time, solved, and the evaluation's means
    ('evaluation') where a verdict came (with 'policy_iteration' where it judged an earlier iteration's policy)."""

    @classmethod
    def from_infos(cls, infos: dict) -> Progress:
        """The progress a checkpoint's ``infos`` holds."""
        return cls(**{f.name: infos[f.name] for f in dataclasses.fields(cls) if f.name in infos})

    def infos(self) -> dict:
        """The progress as a checkpoint's ``infos``: a shallow dict, for ``torch.save`` to write at once (a deep copy
        of the history would cost each of a population's checkpoints time that grows with the iterations)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def as_of(self, iteration: int) -> dict:
        """The progress as it stood after ``iteration`` (a checkpoint's ``infos``), with the verdicts since."""
        history = [h for h in self.history if h["iteration"] <= iteration]
        return dict(self.infos(), iterations=iteration + 1, env_steps=history[-1]["env_steps"],
                    train_time_s=history[-1]["train_time_s"], history=history)


@dataclass
class RunSummary:
    """``summary.json``: what a run did, in one schema."""

    status: Literal["completed", "solved", "interrupted", "non-finite", "outdone"]
    """Why training ended: its budget, solved, a signal, non-finite networks, or (a population's member, with
    ``--population.until first-solved``) another member judged solved first."""
    iterations: int
    env_steps: int
    train_time_s: float
    setup_time_s: float
    env_steps_per_s: int | None
    collection_ms: float | None
    """Median over the iterations of one iteration's collection (rollout and returns), measured on the device."""
    learning_ms: float | None
    """Median over the iterations of one iteration's PPO update, measured on the device."""
    final: dict
    """Episode means of the last iteration in which training episodes finished."""
    evaluation: dict | None
    """The last evaluation's episode means (the deterministic policy; what decides 'solved') and its iteration."""
    evaluations: int
    """Evaluations the run has had."""
    evaluation_s: float
    """Their seconds, part of ``train_time_s``."""
    best: dict | None
    """The best evaluation (``Progress.best``): the policy of ``model_best.pt``."""
    max_episode_length: int | None
    env_dt_s: float
    solved: bool
    solved_at: dict | None
    solved_definition: str
    task: str
    num_envs: int
    """Envs of all processes together."""
    processes: int
    """Processes (GPUs) of a torchrun job; 1 otherwise."""
    device: str
    checkpoint: str
    exports: list[str]
    timing_s: dict[str, float] = field(default_factory=dict)
    """Seconds by phase, from the process start to the summary: 'start' (Python and the command line's imports),
    'config', 'imports' (torch, rsl-rl, tensordict), 'newton' (Warp's start-up and Newton's import), 'kernels'
    (loading or compiling the env's Warp modules, first launches), 'scene', 'capture' (the env), 'eval_env' (the
    evaluation's envs), 'networks' (rsl-rl's runner, resume, config.yaml), 'training' (evaluations included), 'export'
    (ONNX and TorchScript), 'curve'."""
    versions: dict[str, str] = field(default_factory=versions)

    def write(self, run_dir: Path) -> Path:
        """Write ``summary.json`` atomically."""
        return write_text(Path(run_dir) / SUMMARY_FILE, json.dumps(dataclasses.asdict(self), indent=2) + "\n")
