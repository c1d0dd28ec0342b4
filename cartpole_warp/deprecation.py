"""Renamed public names: the old one still works for a release, with a ``DeprecationWarning`` naming the new one."""

import sys
import warnings
from collections.abc import Callable


def renamed(module: str, names: dict[str, str]) -> Callable[[str], object]:
    """A module's ``__getattr__`` that answers each old name in ``names`` (old -> new) with the module's new one."""

    def __getattr__(name: str) -> object:
        if name not in names:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        warnings.warn(f"{module}.{name} is now {names[name]}; the old name goes in a later release", DeprecationWarning,
                      stacklevel=2)
        return getattr(sys.modules[module], names[name])

    return __getattr__
