"""The computations several figures share (the sweeps that take the time), in an explicit registry: each is
computed once per process and arguments, and can be run by its name elsewhere (a study engine's worker)
with every shared result it made handed back, so that the figures then draw from them."""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

SharedKey = tuple[str, tuple[Any, ...]]
"""A shared result's key: the computation's name and its arguments."""
Function = TypeVar("Function", bound=Callable[..., Any])


class SharedComputations:
    """Pure computations by name, and their results by (name, arguments)."""

    def __init__(self) -> None:
        self._functions: dict[str, Callable[..., Any]] = {}
        self._results: dict[SharedKey, Any] = {}

    def register(self, function: Function) -> Function:
        """Decorator: ``function`` (pure) under its name, computed once per arguments (as functools.cache)."""
        name = function.__name__
        if name in self._functions:
            raise ValueError(f"a shared computation named {name!r} is registered already")

        @functools.wraps(function)
        def cached(*args: Any) -> Any:
            key = (name, args)
            if key not in self._results:
                self._results[key] = function(*args)
            return self._results[key]

        self._functions[name] = cached
        return cached  # type: ignore[return-value]

    def __contains__(self, name: object) -> bool:
        """Whether a computation of this name is registered."""
        return name in self._functions

    def run(self, name: str, args: tuple[Any, ...]) -> dict[SharedKey, Any]:
        """Run the computation ``name`` and return every shared result it made, itself and the shared parts
        it used (fig04's exact check brings its analytic trace along)."""
        before = set(self._results)
        self._functions[name](*args)
        made = self._results.items()
        return {key: value for key, value in made if key not in before or key == (name, args)}

    def store(self, results: Mapping[SharedKey, Any]) -> None:
        """Take results made elsewhere (by :meth:`run` in another process) as this process's own."""
        self._results.update(results)


SHARED = SharedComputations()
"""The figures' shared computations (the modules of the figure families register theirs on import)."""
