"""File I/O at the bottom of the package: files shipped with it (stages, presets) and atomic writes."""

from __future__ import annotations

import importlib.resources
import os
import tempfile
from collections.abc import Callable
from pathlib import Path


def data_path(folder: str, name: str = "") -> Path:
    """A file shipped with the package (``folder`` is 'usd' or 'configs'): inside the installed package, or at the
    top of the repository when running from a checkout."""
    packaged = Path(str(importlib.resources.files("cartpole_warp"))) / folder
    base = packaged if packaged.is_dir() else Path(__file__).resolve().parents[2] / folder
    return base / name if name else base


def atomic_write(path: Path, write: Callable[[str], object]) -> Path:
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


def unwritable(folder: Path) -> str | None:
    """Why ``folder`` (which may not exist yet) cannot be created and written, in words; None if it can: a folder
    made and removed in its nearest existing parent (permission bits do not tell root's failures, e.g. in /proc)."""
    parent = Path(folder).absolute()
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        return f"{parent} is not a folder"
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".write-test-", dir=parent))
    except OSError as err:
        return f"cannot write in {parent}: {err.strerror}"
    return None
