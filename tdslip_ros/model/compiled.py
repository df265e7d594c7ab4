"""Compilation of the model's scalar kernels (numba), where the compiled code is cached, and the few
primitives a kernel needs to run both in real and in complex-step arithmetic.

The analytic map (:mod:`tdslip_ros.model.analytic.map_kernels`) and the policies' solvers
(:mod:`tdslip_ros.model.policies.controller_kernels`, :mod:`tdslip_ros.model.policies.deadbeat_kernels`) are
written once, as scalar functions of one lane, and compiled with :func:`kernel`. The controller calls them for
one apex; the vectorised API loops over the lanes of a batch in compiled code; the complex step
(``closed_loop.map_jacobian``) runs the very same source in complex128 (numba compiles one specialisation per
argument type). The few large kernels of the map's hot path are compiled with :func:`inlined_kernel`, which
copies them into their callers.

Cache. Compiling every kernel takes minutes (once for float64 and once for complex128 arguments), so the
machine code is kept on disk and a new process only loads it. It goes to a folder ``model-<hash>``, the hash
of every source file of ``tdslip_ros.model`` and its sub-packages (kernels call kernels and use constants of
other modules, so any change to the model recompiles; numba alone would only watch each kernel's own file), in
the first of these that is writable:

1. ``$NUMBA_CACHE_DIR`` when set (numba's own setting);
2. the user's cache directory, ``~/.cache/tdslip_ros`` (``$XDG_CACHE_HOME/tdslip_ros``): shared by every
   copy of the same sources, so a colcon install of a checkout finds what ``./run.sh setup`` compiled;
3. ``__pycache__`` beside the model's sources.

If none is writable (a read-only install run by a user without a home), the kernels are compiled in memory
in every process and a warning says so once: slow to start (a minute), never wrong. Set NUMBA_CACHE_DIR to
a writable folder there. Folders of older sources are not removed (about 13 MB each).
"""

from __future__ import annotations

import hashlib
import math
import os
import warnings
from collections.abc import Callable
from functools import cache
from pathlib import Path
from typing import Any, Literal, TypeVar, cast

import numba
from numba import types
from numba.core import caching
from numba.extending import overload, register_jitable

F = TypeVar("F", bound=Callable[..., Any])

MODEL_DIR = Path(__file__).resolve().parent


def source_stamp(package_dir: Path) -> str:
    """sha256 over the paths (relative to ``package_dir``) and contents of every Python source file in it and
    its sub-packages: a file of the same name in two sub-packages, or a file moved between them, changes
    it."""
    digest = hashlib.sha256()
    for path in sorted(package_dir.rglob("*.py")):
        digest.update(path.relative_to(package_dir).as_posix().encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()


@cache
def model_source_stamp() -> str:
    """:func:`source_stamp` of the model package, the key of the kernels' cache folder."""
    return source_stamp(MODEL_DIR)


def _cache_bases() -> list[str]:
    """The folders the cache may go to, in order (module docstring)."""
    numba_cache = str(getattr(numba.config, "CACHE_DIR", ""))  # $NUMBA_CACHE_DIR, as numba read it
    user_cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "tdslip_ros"
    return [*([numba_cache] if numba_cache else []), str(user_cache), str(MODEL_DIR / "__pycache__")]


def _kernel_cache_class() -> type | None:
    """numba's function cache in the first writable folder of :func:`_cache_bases`, stamped with the model
    package's hash; None where numba lacks the classes this builds on (another numba than the pinned one:
    then its own cache=True)."""
    try:
        base_locator, implementation_base = caching._CacheLocator, caching.CompileResultCacheImpl
    except AttributeError:
        return None

    class ModelLocator(base_locator):  # type: ignore[valid-type,misc]  # a class of the numba found
        def __init__(self, py_func: Callable[..., Any], path: str) -> None:
            self._lineno = py_func.__code__.co_firstlineno
            self._path = path

        def get_cache_path(self) -> str:
            return self._path

        def get_source_stamp(self) -> str:
            return model_source_stamp()

        def get_disambiguator(self) -> str:
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func: Callable[..., Any], py_file: str) -> ModelLocator | None:
            for base in _cache_bases():
                locator = cls(py_func, os.path.join(base, f"model-{model_source_stamp()[:16]}"))
                try:
                    locator.ensure_cache_path()
                except OSError:
                    continue
                return locator
            return None

    implementation = type("KernelCacheImpl", (implementation_base,), {"_locator_classes": [ModelLocator]})
    return type("KernelCache", (caching.FunctionCache,), {"_impl_class": implementation})


_KERNEL_CACHE = _kernel_cache_class()
_warned_uncached = False


def kernel(function: F) -> F:
    """Compile ``function`` (nopython, numpy's error model: 1/0 gives inf, never an exception), cached on
    disk as the module docstring says. The result is typed as ``function`` itself: it takes and returns
    the same values, compiled on the first call for each set of argument types."""
    return _compiled(function, "never")


def inlined_kernel(function: F) -> F:
    """:func:`kernel`, whose body numba copies into every kernel that calls it (``inline="always"``).

    For the few large kernels on the map's hot path (the stance start, the stance, the ascent, the stride):
    LLVM does not inline them on its own, and the calls, which pass named tuples of 30-60 numbers each way
    and keep the optimiser from seeing across them, cost about as much as their arithmetic (one stride
    without corrections: about 390 ns with the calls, 210 ns inlined). Each copy costs compile time, so
    the kernels that call these many times (the policies' solvers) stay plain kernels.
    """
    return _compiled(function, "always")


def _compiled(function: F, inline: Literal["never", "always"]) -> F:
    global _warned_uncached
    try:
        if _KERNEL_CACHE is None:
            return cast(F, numba.njit(error_model="numpy", inline=inline, cache=True)(function))
        dispatcher = numba.njit(error_model="numpy", inline=inline)(function)
        # What cache=True does, with this module's locators. numba keeps the cache in an attribute that
        # its type hints do not declare.
        dispatcher._cache = _KERNEL_CACHE(function)  # type: ignore[attr-defined]
        return cast(F, dispatcher)
    except RuntimeError:  # no writable cache directory
        if not _warned_uncached:
            _warned_uncached = True
            warnings.warn(
                "tdslip_ros: no writable cache directory for the compiled kernels (set NUMBA_CACHE_DIR to "
                "one); they are compiled in memory in every process",
                RuntimeWarning,
                stacklevel=3,
            )
        return cast(F, numba.njit(error_model="numpy", inline=inline)(function))


# --- complex-step primitives --------------------------------------------------------------------------
# Plain functions for mypy and the interpreter; in compiled code numba picks the implementation by the
# argument types (float64 or complex128) when it compiles a kernel.


@register_jitable
def real(x: complex) -> float:
    """The real part (of a float: itself)."""
    return x.real


def _carried_atan2(y: complex, x: complex) -> complex:
    yr, xr = y.real, x.real
    return complex(math.atan2(yr, xr), (xr * y.imag - yr * x.imag) / (xr**2 + yr**2))


def _real_atan2(y: complex, x: complex) -> complex:
    return math.atan2(y.real, x.real)


def atan2(y: complex, x: complex) -> complex:
    """atan2 carrying infinitesimal imaginary parts (complex step): d atan2 = (x dy - y dx)/(x^2 + y^2)."""
    if isinstance(y, float) and isinstance(x, float):
        return _real_atan2(y, x)
    return _carried_atan2(y, x)


def is_complex(x: complex) -> bool:
    """Whether x is complex: in compiled code a constant of each specialisation, so a branch on it costs
    nothing and a real specialisation never takes its complex branch."""
    return isinstance(x, complex)


def _any_complex(*numba_types: object) -> bool:
    return any(isinstance(value, types.Complex) for value in numba_types)


# numba matches an overload's parameters (names and annotations) with its implementations' parameters.


@overload(atan2)
def _atan2_overload(y: complex, x: complex) -> Callable[[complex, complex], complex]:
    return _carried_atan2 if _any_complex(y, x) else _real_atan2


def _complex(x: complex) -> bool:
    return True


def _not_complex(x: complex) -> bool:
    return False


@overload(is_complex)
def _is_complex_overload(x: complex) -> Callable[[complex], bool]:
    return _complex if _any_complex(x) else _not_complex
