"""Name -> class registries for the benchmark's extension points (tasks, experts, conditions).

A `Registry` maps a name (a class attribute of the registered classes) to the class. Classes get in
two ways: `discover` imports every module of a package and registers the classes defined there (so
adding a task or an expert is adding its file), and `register` is the decorator for classes defined
anywhere else (plugins, tests). Unknown names raise a `ValueError` that lists the registered ones.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil


class Registry(dict):
    """Registered classes by name, in registration order.

    Args:
        kind: what is registered, for messages ("task", "condition", ...).
        key: the class attribute holding the name ("name", "task_name").
    """

    def __init__(self, kind: str, key: str = "name"):
        super().__init__()
        self.kind, self.key = kind, key

    def register(self, cls: type) -> type:
        """Add `cls` under `getattr(cls, key)`; usable as a class decorator. The same class (or the same
        class re-imported) may register twice; another class under a taken name raises."""
        name = getattr(cls, self.key, "")
        if not isinstance(name, str) or not name:
            raise ValueError(f"{cls.__qualname__} sets no {self.key!r}: a {self.kind} needs a non-empty name")
        old = self.get(name)
        if old is not None and (old.__module__, old.__qualname__) != (cls.__module__, cls.__qualname__):
            raise ValueError(
                f"{self.kind} {name!r} is already registered by {old.__module__}.{old.__qualname__}"
            )
        self[name] = cls
        return cls

    def lookup(self, name: str) -> type:
        """The class registered as `name`; a ValueError listing the registered names otherwise."""
        if name not in self:
            raise ValueError(f"unknown {self.kind} {name!r}; registered: {', '.join(self) or 'none'}")
        return self[name]

    def discover(self, package: str, base: type, order=None) -> None:
        """Import every module of `package` (names not starting with "_") and register the concrete
        `base` subclasses each one defines, sorted by `order(cls)` (default: module order). Import
        errors propagate: a broken module is a bug, not a missing extension."""
        found = []
        pkg = importlib.import_module(package)
        for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda m: m.name):
            if info.name.startswith("_"):
                continue
            module = importlib.import_module(f"{package}.{info.name}")
            found += [
                c
                for _, c in inspect.getmembers(module, inspect.isclass)
                if c.__module__ == module.__name__ and issubclass(c, base) and not inspect.isabstract(c)
            ]
        for cls in sorted(found, key=order) if order is not None else found:
            self.register(cls)
