"""Run folders: layout, resolved config, atomic writes, checkpoints, ``summary.json``.

A run lives in ``<log_dir>/<algo>/<experiment>/<timestamp>[_<run_name>]/`` and holds ``config.yaml`` (the
resolved config), ``model_<iteration>.pt`` checkpoints, ``summary.json``, ``learning_curve.png``,
``exported/policy.onnx`` + ``exported/policy.pt`` and the logger's event files; ``play/`` gets play.py's
video and USD recording. The helpers are algorithm-agnostic so every trainer shares the layout.
"""

from __future__ import annotations

import datetime
import importlib.metadata
import json
import os
import platform
import re
import tempfile
from pathlib import Path

import yaml

from .config import ConfigError, TrainConfig, apply_overrides, to_dict

CONFIG_FILE = "config.yaml"
SUMMARY_FILE = "summary.json"
CURVE_FILE = "learning_curve.png"
EXPORT_DIR = "exported"
PLAY_DIR = "play"
SB3_MODEL_FILE = "ppo_cartpole.zip"
"""The trained model of an SB3 run (the tutorial's ``model.save("ppo_cartpole")``)."""
_CHECKPOINT = re.compile(r"^model_(\d+)\.pt$")


class RunError(ValueError):
    """A run folder, checkpoint or config is missing or unusable; the message names the path."""


def experiment_dir(log_dir: str | Path, algo: str, experiment: str) -> Path:
    """``<log_dir>/<algo>/<experiment>``: the folder holding one experiment's runs."""
    return Path(log_dir) / algo / experiment


def create_run_dir(log_dir: str | Path, algo: str, experiment: str, run_name: str = "") -> Path:
    """Make a new ``<log_dir>/<algo>/<experiment>/<YYYY-mm-dd_HH-MM-SS>[_<run_name>]`` folder and return it."""
    if run_name and not re.fullmatch(r"[\w.-]+", run_name):
        raise ConfigError(f"run name {run_name!r} may hold only letters, digits, '_', '-' and '.'")
    stamp = datetime.datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    base = experiment_dir(log_dir, algo, experiment) / (f"{stamp}_{run_name}" if run_name else stamp)
    path, n = base, 1
    while path.exists():
        path, n = base.with_name(f"{base.name}-{n}"), n + 1
    path.mkdir(parents=True)
    return path


def list_checkpoints(run_dir: Path) -> list[Path]:
    """The run's ``model_<iteration>.pt`` files (rsl-rl), oldest iteration first, or its SB3 model."""
    found = [(int(m.group(1)), p) for p in Path(run_dir).glob("model_*.pt") if (m := _CHECKPOINT.match(p.name))]
    sb3_model = Path(run_dir) / SB3_MODEL_FILE
    return [p for _, p in sorted(found)] + ([sb3_model] if sb3_model.is_file() else [])


def latest_checkpoint(run_dir: Path) -> Path:
    """The checkpoint with the highest iteration in ``run_dir``."""
    checkpoints = list_checkpoints(run_dir)
    if not checkpoints:
        raise RunError(f"no checkpoint (model_<iteration>.pt or {SB3_MODEL_FILE}) in {run_dir}")
    return checkpoints[-1]


def latest_run(log_dir: str | Path, algo: str, experiment: str) -> Path:
    """The newest run folder (by name, i.e. timestamp) that holds a config and a checkpoint."""
    root = experiment_dir(log_dir, algo, experiment)
    runs = sorted(p for p in root.glob("*") if (p / CONFIG_FILE).is_file() and list_checkpoints(p)) if root.is_dir() else []
    if not runs:
        raise RunError(f"no checkpoint under {root}; run train.py first or pass --checkpoint")
    return runs[-1]


def atomic_write(path: Path, write) -> Path:
    """Call ``write(tmp_path)`` on a temporary file next to ``path``, then rename it onto ``path``:
    readers see the old file or the complete new one, never a half-written one."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def write_text(path: Path, text: str) -> Path:
    """Write a text file atomically."""
    return atomic_write(path, lambda tmp: Path(tmp).write_text(text))


def save_config(run_dir: Path, cfg: TrainConfig) -> Path:
    """Write the resolved config as ``config.yaml``."""
    return write_text(Path(run_dir) / CONFIG_FILE, yaml.safe_dump(to_dict(cfg), sort_keys=False))


def load_config(run_dir: Path) -> TrainConfig:
    """The TrainConfig a run was trained with (its ``config.yaml``)."""
    path = Path(run_dir) / CONFIG_FILE
    if not path.is_file():
        raise RunError(f"{path} not found: is {run_dir} a run folder?")
    try:
        return apply_overrides(TrainConfig(), yaml.safe_load(path.read_text()) or {})
    except (yaml.YAMLError, ConfigError) as err:
        raise RunError(f"cannot read {path}: {err}") from None


def versions() -> dict[str, str]:
    """Versions of Python and the packages a run depends on."""
    result = {"python": platform.python_version()}
    for name in ("cartpole_warp", "torch", "warp-lang", "newton", "rsl-rl-lib", "stable-baselines3"):
        try:
            result[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            pass
    return result


def write_summary(run_dir: Path, summary: dict) -> Path:
    """Write ``summary.json`` atomically."""
    return write_text(Path(run_dir) / SUMMARY_FILE, json.dumps(summary, indent=2) + "\n")
