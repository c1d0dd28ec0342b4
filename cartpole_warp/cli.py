"""Command-line glue shared by ``train``, ``play`` and ``bench``: tyro over the config dataclasses (docstrings become
``--help``), a preset or a run's saved config as the defaults, and one clear error line instead of a traceback."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TypeVar

import tyro

Args = TypeVar("Args")


def process_age_s() -> float | None:
    """Seconds since this process started (Linux: from /proc, to 10 ms), None where that is not known."""
    try:
        start_ticks = int(Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()[19])
        uptime_s = float(Path("/proc/uptime").read_text().split()[0])
        return max(0.0, uptime_s - start_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return None


def quiet_libraries():
    """The scripts' choice (the library changes no global setting): warnings but no info lines from Warp (greeting,
    one line per module load) and Newton (e.g. where ViewerUSD saved); the library's own progress lines (logger
    ``cartpole_warp``, e.g. that kernels compile) on stdout."""
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    logging.getLogger("newton").setLevel(logging.WARNING)
    progress = logging.getLogger("cartpole_warp")
    progress.setLevel(logging.INFO)
    if not progress.handlers:
        handler = logging.StreamHandler(sys.stdout)
        handler.setFormatter(logging.Formatter("%(message)s"))
        progress.addHandler(handler)


def peek(argv: list[str], **flags: str | None) -> argparse.Namespace:
    """The values of a few flags (``name=default``) that decide the defaults of the others, read before tyro parses
    the whole command line; ``--a-flag`` and ``--a_flag`` both count. Everything else is left alone."""
    parser = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    for name, default in flags.items():
        parser.add_argument(f"--{name.replace('_', '-')}", f"--{name}", dest=name, default=default)
    return parser.parse_known_args(argv)[0]


def asks_help(argv: list[str]) -> bool:
    """Whether ``argv`` asks for --help (then no run needs to exist for the defaults)."""
    return "-h" in argv or "--help" in argv


def with_default_value(argv: list[str], flag: str, value: str) -> list[str]:
    """``argv`` where a bare ``flag`` (last, or followed by another flag) gets ``value``: lets ``--resume`` alone
    mean ``--resume latest``."""
    out = []
    for i, arg in enumerate(argv):
        out.append(arg)
        if arg == flag and (i + 1 == len(argv) or argv[i + 1].startswith("-")):
            out.append(value)
    return out


def parse(cls: type[Args], default: Args, argv: list[str], description: str) -> Args:
    """tyro's parse of ``argv`` into ``cls``, starting from ``default``; bad or unknown flags exit with code 2 and
    tyro's message naming the flag."""
    return tyro.cli(cls, default=default, args=argv, description=description)


@contextmanager
def clean_errors(*expected: type[BaseException]) -> Iterator[None]:
    """Turn the expected (user-facing) errors into one ``error: ...`` line on stderr and exit 2; Ctrl-C into 130."""
    try:
        yield
    except expected as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        sys.exit(130)
