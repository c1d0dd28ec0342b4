"""Renamed public names and moved modules: the old one still works until ``REMOVED_IN``, with a ``DeprecationWarning``
naming the new one."""

import dataclasses
import importlib
import importlib.abc
import importlib.util
import sys
import warnings
from collections.abc import Callable

REMOVED_IN = "0.2.0"
"""The release that drops every old name and path answered here (a test fails once the package reaches it)."""


def caller_level() -> int:
    """The ``stacklevel`` of a warning raised in a dataclass's ``__post_init__`` that names the code which built the
    object, past the generated ``__init__`` and ``dataclasses.replace``."""
    frame, level = sys._getframe(2), 2
    while frame is not None and (frame.f_code.co_filename == dataclasses.__file__
                                 or (frame.f_code.co_filename, frame.f_code.co_name) == ("<string>", "__init__")):
        frame, level = frame.f_back, level + 1
    return level


def renamed(module: str, names: dict[str, str]) -> Callable[[str], object]:
    """A module's ``__getattr__`` that answers each old name in ``names`` (old -> new) with the module's new one."""

    def __getattr__(name: str) -> object:
        if name not in names:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        warnings.warn(f"{module}.{name} is now {names[name]}; the old name goes in {REMOVED_IN}", DeprecationWarning,
                      stacklevel=2)
        return getattr(sys.modules[module], names[name])

    return __getattr__


def renamed_attribute(old: str, new: str) -> property:
    """A class's property that answers the attribute ``old`` with ``new``."""

    def get(self) -> object:
        warnings.warn(f"{type(self).__name__}.{old} is now .{new}; the old name goes in {REMOVED_IN}",
                      DeprecationWarning, stacklevel=2)
        return getattr(self, new)

    return property(get, doc=f"The old name of ``{new}``, until {REMOVED_IN}.")


def moved_names(module: str, new_module: str) -> Callable[[str], object]:
    """A package's ``__getattr__`` that answers a public name of the module it replaced with that name in
    ``new_module`` (imported on first use)."""

    def __getattr__(name: str) -> object:
        if name.startswith("_"):
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        target = importlib.import_module(new_module)
        if not hasattr(target, name):
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        warnings.warn(f"{module}.{name} is now {new_module}.{name}; the old path goes in {REMOVED_IN}",
                      DeprecationWarning, stacklevel=2)
        value = getattr(target, name)
        setattr(sys.modules[module], name, value)  # warned once: later lookups find it
        return value

    return __getattr__


class MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """An import hook that answers each old module path (old -> new) with the module at its new path: the same module
    object, so classes and module state are shared."""

    def __init__(self, moves: dict[str, str]):
        self.moves = moves

    def find_spec(self, fullname, path=None, target=None):
        return importlib.util.spec_from_loader(fullname, self) if fullname in self.moves else None

    def create_module(self, spec):
        new = self.moves[spec.name]
        warnings.warn(f"module {spec.name} is now {new}; the old path goes in {REMOVED_IN}", DeprecationWarning,
                      stacklevel=2)  # warnings skips the import machinery's frames: this points at the import
        module = importlib.import_module(new)
        spec.loader_state = module.__spec__
        return module

    def exec_module(self, module):
        """Nothing to run (the module at its new path is loaded); give it back its own spec, which the import
        machinery replaced with the old path's."""
        module.__spec__ = module.__spec__.loader_state


def alias_moved_modules(moves: dict[str, str]) -> None:
    """Make each old module path in ``moves`` import as its new one (once per process)."""
    if not any(isinstance(finder, MovedModules) and finder.moves == moves for finder in sys.meta_path):
        sys.meta_path.append(MovedModules(moves))
