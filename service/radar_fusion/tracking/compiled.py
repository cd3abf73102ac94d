"""The one way this package compiles a Python function to machine code (numba).

The engine's hot loops that numpy cannot express without many passes over large arrays
(the IMM's per-track cycle, imm_kernels.py; the association's plot search,
association.py; the live wild-plot gate, live_gate.py; the two-stage registration's
sensitivities, registration.py) are compiled with the same settings, here.

Compilation is lazy: decorating registers the function, and numba is imported, and every
function a module registered is handed to it, at the first call of any of them. A
process that imports these modules without running them (the safety-nets child, which
reads the engine's column types) does not load numba and LLVM (~115 MB resident).
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from typing import Any, TypeVar, cast

__all__ = ["compiled"]

_F = TypeVar("_F", bound=Callable[..., object])

#: per module, its registered functions (name, Python function), in definition order
_REGISTERED: dict[str, list[tuple[str, Callable[..., Any]]]] = {}


def compiled(fn: _F) -> _F:
    """Register ``fn`` to be compiled by numba's ``njit`` (see the module docstring), and
    return a stand-in that compiles its module's functions on first use and then calls
    the compiled ``fn``. Inside compiled code, calls to another registered function of the
    same module reach its compiled version (the module's global names are replaced).

    Settings: cached on disk, releasing the GIL; floating-point sums may be reordered and
    multiply-adds fused (``reassoc``, ``contract``: round-off only; no assumption about NaN
    or infinity, which imm_kernels.update_kernel relies on); a division by zero gives inf
    or NaN as in numpy (``error_model="numpy"``), never an exception in the daemon's
    processing thread (numba's default raises ZeroDivisionError). The cache is the package's
    ``__pycache__``, else ``NUMBA_CACHE_DIR``, else the user's cache directory (numba's
    order); where none is writable (a read-only install run by a user without a home:
    deploy/ sets NUMBA_CACHE_DIR) numba refuses ``cache=True``, and each process compiles
    the functions instead, a few seconds at start-up. numba's cache is keyed on the source
    file of each function, not on these settings: after changing them here, delete the
    ``*.nbi`` and ``*.nbc`` files under ``__pycache__`` (an install or upgrade does so, its
    files being new)."""
    _REGISTERED.setdefault(fn.__module__, []).append((fn.__name__, fn))
    dispatcher: Callable[..., Any] | None = None

    @functools.wraps(fn)
    def call(*args: Any) -> Any:
        nonlocal dispatcher
        if dispatcher is None:
            _materialise(fn.__module__)
            dispatcher = getattr(sys.modules[fn.__module__], fn.__name__)
        return dispatcher(*args)

    return cast(_F, call)


def _materialise(module: str) -> None:
    """Hand every function ``module`` registered to numba, each in place of its stand-in."""
    from numba import njit

    namespace = vars(sys.modules[module])
    flags = {"reassoc", "contract"}
    for name, fn in _REGISTERED.get(module, []):
        if getattr(namespace.get(name), "py_func", None) is fn:
            continue  # already compiled
        try:
            namespace[name] = njit(cache=True, nogil=True, fastmath=flags, error_model="numpy")(fn)
        except RuntimeError:  # "cannot cache function ...: no locator available"
            namespace[name] = njit(cache=False, nogil=True, fastmath=flags, error_model="numpy")(fn)
