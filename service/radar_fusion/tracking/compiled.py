"""The one way this package compiles a Python function to machine code (numba).

The engine's hot loops that numpy cannot express without many passes over large arrays
(the IMM's per-track cycle, imm_kernels.py; the association's plot search,
association.py) are compiled with the same settings, here.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar, cast

from numba import njit

__all__ = ["compiled"]

_F = TypeVar("_F", bound=Callable[..., object])


def compiled(fn: _F) -> _F:
    """numba's ``njit``, cached on disk, releasing the GIL; floating-point sums may be
    reordered and multiply-adds fused (``reassoc``, ``contract``: round-off only; no
    assumption about NaN or infinity, which imm_kernels.update_kernel relies on).  Typed as the
    Python function it compiles (numba's own annotations type it as a Dispatcher).

    The cache is the package's ``__pycache__``, else ``NUMBA_CACHE_DIR``, else the user's
    cache directory (numba's order); where none is writable (a read-only install run by a
    user without a home: deploy/ sets NUMBA_CACHE_DIR) numba refuses ``cache=True`` at
    import, and each process compiles the kernels instead, a few seconds at start-up."""
    flags = {"reassoc", "contract"}
    try:
        return cast(_F, njit(cache=True, nogil=True, fastmath=flags)(fn))
    except RuntimeError:  # "cannot cache function ...: no locator available"
        return cast(_F, njit(cache=False, nogil=True, fastmath=flags)(fn))
