"""Command-line glue shared by ``train``, ``play`` and ``bench``: tyro over the config dataclasses (docstrings become
``--help``), a preset or a run's saved config as the defaults, and one clear error line instead of a traceback."""

from __future__ import annotations

import argparse
import difflib
import io
import logging
import os
import re
import socket
import sys
import textwrap
import warnings
from collections.abc import Iterator
from contextlib import contextmanager, redirect_stderr
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import tyro

from .settings.config import ConfigError
from .settings.deprecation import REMOVED_IN

Args = TypeVar("Args")


@dataclass
class ViserArgs:
    """Where ``--viewer viser`` serves its page (train.py and play.py alike), and what it shows."""

    host: str = "127.0.0.1"
    """--viewer viser: the address the page is served on; 0.0.0.0 serves it to every network this machine is on,
    where anyone who reaches the port can watch and pause the run."""
    port: int = 8080
    """--viewer viser: the page's port."""
    viewer_envs: int = 16
    """--viewer viser: how many envs the page shows, in a grid."""

    def problem(self) -> str | None:
        """What is wrong with these values, in one line (None: nothing)."""
        if not 1 <= self.port <= 65535:
            return f"--port must be a TCP port, 1-65535, got {self.port}"
        return None if self.viewer_envs >= 1 else f"--viewer-envs must be >= 1, got {self.viewer_envs}"

    def host_problem(self) -> str | None:
        """Why no page can be served on ``host`` (no address, or not one of this machine's), in one line; None if
        one can: a socket bound there on a free port and closed (viser's own thread would fail and hang the
        program)."""
        try:
            family, _, _, _, address = socket.getaddrinfo(self.host, None, type=socket.SOCK_STREAM)[0]
            with socket.socket(family, socket.SOCK_STREAM) as probe:
                probe.bind((address[0], 0))
        except OSError as err:
            return f"--host {self.host}: no page can be served there ({err.strerror or err})"
        return None


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


FULL_HELP = "--help-all"

ENV_ALIASES = {"--num-envs": "--env.num-envs", "--device": "--env.device", "--seed": "--env.seed"}
"""The short flags of the env settings that train.py and play.py share (short flag: the config field's own flag)."""


def flag_name(arg: str) -> str:
    """The flag of a command-line word, written with dashes (``--num_envs=8`` -> ``--num-envs``)."""
    return arg.partition("=")[0].replace("_", "-")


@contextmanager
def flags_named(argv: list[str], aliases: dict[str, str]) -> Iterator[None]:
    """A ConfigError raised inside names each config field that ``argv`` set by the flag that set it, as typed
    (``env.num_envs`` -> ``--num-envs``)."""
    try:
        yield
    except ConfigError as err:
        message = str(err)
        for arg in argv:
            typed = arg.partition("=")[0]
            if typed.startswith("--"):
                field = aliases.get(flag_name(typed), flag_name(typed)).removeprefix("--").replace("-", "_")
                message = re.sub(rf"(?<![\w.]){re.escape(field)}(?![\w.])", typed, message)
        raise ConfigError(message) from None


def expand_aliases(argv: list[str], aliases: dict[str, str]) -> list[str]:
    """``argv`` with each short flag (``--num-envs 8``, ``--num-envs=8``, ``--num_envs 8``) written as the config
    field's own flag (``--env.num-envs``), which tyro parses; the config classes name no program's flags."""
    out = []
    for arg in argv:
        _, equals, value = arg.partition("=")
        target = aliases.get(flag_name(arg)) if arg.startswith("--") else None
        out.append(f"{target}{equals}{value}" if target else arg)
    return out


def renamed_flags(argv: list[str], renames: dict[str, str]) -> list[str]:
    """``argv`` with each old spelling of a flag (``renames``: old -> new; an old name ending in '.' renames every
    flag under it, ``--agent.apg.`` -> ``--agent.shac.``) written as the new one, and a line on stderr naming both:
    the old spelling is taken until ``settings.deprecation.REMOVED_IN``."""

    def new_name(flag: str) -> str | None:
        if flag in renames:
            return renames[flag]
        prefix = next((old for old in renames if old.endswith(".") and flag.startswith(old)), None)
        return None if prefix is None else renames[prefix] + flag[len(prefix):]

    typed = sorted({flag_name(arg) for arg in argv if arg.startswith("--")})
    moves = {old: new for old in typed if (new := new_name(old)) is not None}
    for old, new in moves.items():
        print(f"note: {old} is now {new}; the old spelling goes in {REMOVED_IN}", file=sys.stderr)
    return expand_aliases(argv, moves)


def renamed_values(argv: list[str], flags: tuple[str, ...], renames: dict[str, str]) -> list[str]:
    """``argv`` with each old value (``renames``: old -> new) given to one of ``flags`` (``--learner apg``,
    ``--learner=apg``) written as the new one, and a line on stderr naming both: the old value is taken until
    ``settings.deprecation.REMOVED_IN``."""
    out = []
    for i, arg in enumerate(argv):
        name, equals, value = arg.partition("=")
        if equals and arg.startswith("--") and flag_name(name) in flags and value in renames:
            flag, old, arg = name, value, f"{name}={renames[value]}"
        elif i and argv[i - 1].startswith("--") and flag_name(argv[i - 1]) in flags and arg in renames:
            flag, old, arg = argv[i - 1], arg, renames[arg]
        else:
            out.append(arg)
            continue
        print(f"note: {flag} {old} is now {flag} {renames[old]}; the old spelling goes in {REMOVED_IN}",
              file=sys.stderr)
        out.append(arg)
    return out


def asks_help(argv: list[str]) -> bool:
    """Whether ``argv`` asks for --help or --help-all (then no run needs to exist for the defaults)."""
    return "-h" in argv or "--help" in argv or FULL_HELP in argv


def with_default_value(argv: list[str], flag: str, value: str) -> list[str]:
    """``argv`` where a bare ``flag`` (last, or followed by another flag) gets ``value``: lets ``--resume`` alone
    mean ``--resume latest``."""
    out = []
    for i, arg in enumerate(argv):
        out.append(arg)
        if arg == flag and (i + 1 == len(argv) or argv[i + 1].startswith("-")):
            out.append(value)
    return out


def parse(cls: type[Args], default: Args, argv: list[str], description: str,
          aliases: dict[str, str] | None = None, default_notes: dict[str, str] | None = None) -> Args:
    """tyro's parse of ``argv`` into ``cls``, starting from ``default``, with the program's short flags (``aliases``:
    short flag -> the field's flag); bad or unknown flags exit with code 2 and tyro's message naming the flag.
    ``--help`` prints ``short_help`` (with ``default_notes``), ``--help-all`` tyro's help of every flag."""
    aliases = aliases or {}
    if FULL_HELP in argv:
        argv = ["--help"]
        if aliases:
            description += "\n\nshort flags: " + ", ".join(f"{short} = {flag}" for short, flag in aliases.items())
    elif asks_help(argv):
        print(short_help(cls, default, description, aliases, default_notes=default_notes))
        sys.exit(0)
    report = io.StringIO()  # what tyro writes to stderr: its error box, shown where the error is not an unknown flag
    try:
        with redirect_stderr(report):
            parsed = tyro.cli(cls, default=default, args=expand_aliases(argv, aliases), description=description)
    except SystemExit as exit_:
        if exit_.code:
            known = {flag_name(flag) for action in flag_parser(cls, default)._actions for flag in action.option_strings}
            unknown = [flag_name(arg) for arg in argv
                       if arg.startswith("-") and flag_name(arg) not in known | aliases.keys()]
            if unknown:
                print(f"error: {unknown_flag_line(unknown[0], known, aliases)}", file=sys.stderr)
                sys.exit(2)
        sys.stderr.write(report.getvalue())
        named = sorted(short for short in {flag_name(arg) for arg in argv} & aliases.keys()
                       if aliases[short] in report.getvalue())
        if exit_.code and named:  # tyro's message names the field's flag: say which short flag that was
            print(f"({', '.join(f'{short} is {aliases[short]}' for short in named)})", file=sys.stderr)
        raise
    sys.stderr.write(report.getvalue())
    return parsed


def flag_parser(cls: type[Args], default: Args) -> argparse.ArgumentParser:
    """The argparse parser tyro builds for ``cls`` (its ``--help-all``)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # tyro 1.0 deprecates get_parser, not yet removed
        return tyro.extras.get_parser(cls, default=default)


def unknown_flag_line(flag: str, known: set[str], aliases: dict[str, str]) -> str:
    """The error of an unknown ``flag``: the closest spelling ``--help`` shows (the short flags and the top level's),
    else the closest of every flag (``known``)."""
    shown = [name for name in sorted(known | aliases.keys()) if "." not in name and name not in aliases.values()]
    close = (difflib.get_close_matches(flag, shown, n=1, cutoff=0.6)
             or difflib.get_close_matches(flag, sorted(known), n=1, cutoff=0.6))
    guess = f" (did you mean {close[0]}?)" if close else ""
    return f"unknown flag {flag}{guess}; --help lists the common flags, {FULL_HELP} every one"


def short_help(cls: type[Args], default: Args, description: str, aliases: dict[str, str], width: int = 100,
               default_notes: dict[str, str] | None = None) -> str:
    """``description``, then the flags of the top level and the short flags (``aliases``: ``--num-envs`` for
    ``--env.num-envs``), but those whose help starts with another flag (an option of that flag, e.g. "--video: env
    steps per clip"): each with the first sentence of its help and its default (and ``default_notes``' words on it, by
    flag), from the parser tyro builds for ``--help-all`` (which lists the other flags, every config field, in
    groups)."""
    default_notes = default_notes or {}
    short_of = {flag: short for short, flag in aliases.items()}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # tyro 1.0 deprecates get_parser, not yet removed
        parser = tyro.extras.get_parser(cls, default=default)
    common, other = [], 0
    for action in parser._actions:
        flags = [flag for flag in action.option_strings if flag.startswith("--")]
        short = [short_of.get(flag, flag) for flag in flags if "." not in flag or flag in short_of]
        if "-h" in action.option_strings:
            continue
        if not short or action.help == argparse.SUPPRESS or (action.help or "").startswith("--"):
            other += bool(flags)  # a config field, or an option of another flag ("--video: ..."): --help-all's
            continue
        metavar = f" {action.metavar}" if action.metavar and action.nargs != 0 else ""
        text = " ".join((action.help or "").split())
        default_text = text[text.rfind("(default:"):] if "(default:" in text else ""
        first = re.split(r"(?<=\.)\s", text.removesuffix(default_text).strip(), maxsplit=1)[0]
        if short[0] in default_notes and default_text:
            default_text = f"{default_text.removesuffix(')')}; {default_notes[short[0]]})"
        wrapped = textwrap.fill(f"{first} {default_text}".strip(), width, initial_indent=" " * 6,
                                subsequent_indent=" " * 6)
        common.append(f"  {', '.join(short)}{metavar}\n{wrapped}")
    return (f"{description.strip()}\n\noptions (the common ones; {FULL_HELP} lists all {other + len(common)} flags, "
            f"every config field):\n  -h, --help\n      this help; {FULL_HELP}: every flag\n" + "\n".join(common))


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
