"""Discovery of one-module-per-task registries (tasks, experts)."""

from __future__ import annotations

import importlib
import importlib.util
import inspect
from collections.abc import Callable, Iterable


def discover(package: str, names: Iterable[str], matches: Callable[[type, str], bool]) -> dict[str, type]:
    """Import `package.<name>` for every name whose module exists and return, per name, the one
    class in it for which `matches(cls, name)` holds. Import errors propagate (they are bugs,
    not missing modules); zero or several matching classes raise ImportError."""
    found = {}
    for name in names:
        module_name = f"{package}.{name}"
        if importlib.util.find_spec(module_name) is None:
            continue
        module = importlib.import_module(module_name)
        classes = [c for _, c in inspect.getmembers(module, inspect.isclass)
                   if c.__module__ == module_name and matches(c, name)]
        if len(classes) != 1:
            raise ImportError(f"{module_name} must define exactly one matching class for {name!r}, "
                              f"found {[c.__name__ for c in classes]}")
        found[name] = classes[0]
    return found
