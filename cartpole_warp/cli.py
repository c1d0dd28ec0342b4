"""Command-line plumbing shared by train.py and play.py: config flags, the field reference, clean errors."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import typing
from contextlib import contextmanager

from .config import ConfigError, TrainConfig, field_docs, set_field


def config_reference(cls=TrainConfig, prefix: str = "") -> list[str]:
    """One line per config field: dotted key, type, default and its docstring."""
    lines = []
    docs, hints, default = field_docs(cls), typing.get_type_hints(cls), cls()
    for f in dataclasses.fields(cls):
        key, value = f"{prefix}{f.name}", getattr(default, f.name)
        if dataclasses.is_dataclass(value):
            lines += config_reference(type(value), f"{key}.")
        else:
            kind = getattr(hints[f.name], "__name__", str(hints[f.name]).replace("typing.", ""))
            lines.append(f"  {key} ({kind}, default {value!r}): {' '.join(docs.get(f.name, '').split())}")
    return lines


def add_config_arguments(parser: argparse.ArgumentParser):
    """``--config PRESET`` and repeatable ``--set KEY=VALUE``; the epilog lists every settable key."""
    parser.add_argument("--config", default=None, metavar="PRESET",
                        help="preset name under configs/ (default, tutorial) or a YAML file; default: 'default'")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="set any config field (value parsed as YAML), e.g. --set ppo.entropy_coef=0.01; repeatable")
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = ("Precedence: dataclass defaults < --config preset < --set < the flags above.\n"
                     "Config fields (for --set and the YAML presets):\n" + "\n".join(config_reference()))


def apply_sets(cfg, assignments: list[str]):
    """Apply ``KEY=VALUE`` strings to ``cfg``."""
    for item in assignments:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"--set expects KEY=VALUE, got {item!r}")
        set_field(cfg, key.strip(), value)
    return cfg


@contextmanager
def clean_errors(*expected: type[BaseException]):
    """Turn the expected (user-facing) errors into 'error: ...' on stderr and exit 2; Ctrl-C into exit 130."""
    try:
        yield
    except expected as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        sys.exit(130)
