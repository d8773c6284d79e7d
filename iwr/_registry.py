"""One registry of plug-ins by name, imported on first use: what the measurement kinds
(:mod:`iwr.kinds`) and the non-geometric effects (:mod:`iwr.effects`) are registered in.

A plug-in is registered as an object or as ``"package.module:Attribute"``, a name imported on
first use (so that a low layer may name an implementation that lives in a higher one). The
registry is thread-safe: whichever thread asks first imports and checks it, every thread gets
the same object. It imports nothing of iwr.
"""

from __future__ import annotations

import importlib
import threading
from collections.abc import Callable
from typing import Any, Generic, TypeVar

__all__ = ["Registry"]

T = TypeVar("T")


class Registry(Generic[T]):
    """Plug-ins of one sort by name.

    Parameters
    ----------
    what : str
        What a plug-in is, as messages name it (``"kind"``, ``"effect"``).
    accepts : callable
        ``accepts(obj)``: whether ``obj`` (given to :meth:`register`, or what its
        ``"module:Attribute"`` names, made by ``make``) is a plug-in of this sort.
    expected : str
        What ``accepts`` wants, for messages (``"a MeasurementKind"``).
    make : callable, optional
        What the registry keeps of an imported attribute: default the attribute itself (the
        effects' classes); ``lambda cls: cls()`` keeps one instance (the kinds).
    """

    def __init__(self, what: str, accepts: Callable[[Any], bool], expected: str,
                 make: Callable[[Any], T] | None = None) -> None:
        self.what = what
        self._accepts = accepts
        self._expected = expected
        self._make: Callable[[Any], T] = make if make is not None else (lambda obj: obj)
        self._specs: dict[str, str | T] = {}
        self._loaded: dict[str, T] = {}
        self._lock = threading.RLock()

    def register(self, name: str, spec: str | T) -> None:
        """Make ``name`` known: ``spec`` a plug-in, or ``"package.module:Attribute"`` imported
        on first use. ValueError for a name that is no identifier or is already registered,
        TypeError for a spec of another sort, ValueError for a plug-in named otherwise."""
        if not isinstance(name, str) or not name.isidentifier():
            raise ValueError(f"name: {name!r}; expected an identifier")
        if not (isinstance(spec, str) or self._accepts(spec)):
            raise TypeError(f"{self.what}: expected {self._expected} or 'module:Class', got "
                            f"{type(spec).__name__}")
        if not isinstance(spec, str) and getattr(spec, "name", name) != name:
            raise ValueError(f"{self.what}: {getattr(spec, '__name__', type(spec).__name__)} "
                             f"is named {spec.name!r}, not {name!r}")  # type: ignore[attr-defined]
        with self._lock:
            if name in self._specs:
                raise ValueError(f"{self.what}: {name!r} is already registered")
            self._specs[name] = spec

    def names(self) -> list[str]:
        """The registered names, in the order registered."""
        return list(self._specs)

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in self._specs

    def get(self, name: str) -> T:
        """The plug-in registered as ``name`` (imported and checked on first use); ValueError
        naming the registered ones when there is none."""
        if name not in self:
            raise ValueError(f"{self.what}: {name!r} is not registered; registered: "
                             + ", ".join(self.names()))
        loaded = self._loaded.get(name)
        if loaded is not None:
            return loaded
        with self._lock:
            if name not in self._loaded:
                spec = self._specs[name]
                if isinstance(spec, str):
                    module, _, attribute = spec.partition(":")
                    spec = self._make(getattr(importlib.import_module(module), attribute))
                if not self._accepts(spec) or getattr(spec, "name", None) != name:
                    raise TypeError(f"{self.what} {name!r}: {self._specs[name]!r} is not "
                                    f"{self._expected} named {name!r}")
                self._loaded[name] = spec
            return self._loaded[name]
