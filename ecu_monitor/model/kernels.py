"""How the package compiles with numba: one decorator for the compiled entry points, the swarm's flags.

A function Python calls compiled (a kernel, a filter loop, the step) carries :func:`njit` on its own
definition; its ``.py_func`` is the plain-Python reference the tests compare against. A building block
that both Python and compiled code call (an equation, a filter step) carries numba's
``register_jitable``: called from Python it is a plain Python function (numpy on arrays), called from
a compiled function numba compiles it into that caller. So ``kernel.py_func`` runs pure Python all the
way down, and no module global is ever re-bound to a compiled twin.

The on-disk cache: numba checks only a function's own source file for staleness, yet a cached kernel
embeds the machine code of everything it calls in other files. :func:`njit` therefore names each cache
entry after a fingerprint of every compiled source of the package (:data:`COMPILED_PACKAGES`), so an
edit to any of them (or an upgrade) gets fresh entries instead of stale code. Where the cache lives and
the first run's "compiling" line: :mod:`ecu_monitor.compile_cache`.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numba

__all__ = ["COMPILED_PACKAGES", "SWARM_FASTMATH", "fingerprint", "njit", "python_reference"]

F = TypeVar("F", bound=Callable[..., Any])

#: LLVM fast-math flags of the swarm kernel: reassociation and reciprocals, but NaN and inf kept
#: (the failure mask and the "not logged" mixture index rely on them).
SWARM_FASTMATH = frozenset({"nsz", "arcp", "contract", "afn", "reassoc"})
#: The packages (folders of ``ecu_monitor``) whose sources compiled code is made of.
COMPILED_PACKAGES = ("model", "estimation", "pipeline")


@functools.cache
def fingerprint() -> str:
    """Short hash of every source file of :data:`COMPILED_PACKAGES`."""
    root = Path(__file__).resolve().parent.parent
    digest = hashlib.sha256()
    for package in COMPILED_PACKAGES:
        for path in sorted((root / package).glob("*.py")):
            digest.update(path.name.encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


def njit(*, fastmath: frozenset[str] | bool = False, nogil: bool = True, inline: bool = False) -> Callable[[F], F]:
    """``numba.njit`` with the package's options, applied to the function itself: cached on disk (an entry
    per :func:`fingerprint`), numpy's error model (a division by zero gives inf or NaN, as in the
    reference, instead of a check per division that would stop the particle loop from vectorising).

    ``fastmath``: False (exact IEEE: the filters, whose complex-step derivative needs it) or a set of LLVM
    flags (:data:`SWARM_FASTMATH`); the building blocks numba inlines into the function get its flags.
    ``nogil=False`` for the live path's short calls (tens of microseconds): releasing the GIL around them
    lets another thread take it, and getting it back can then wait for that thread (up to the
    interpreter's 5 ms switch interval), which is latency on the bus thread for no gain (a whole log's
    replay calls the step through a wrapper that releases it: ``step.replay_loop_released``).
    ``inline``: numba inlines the function into its compiled callers (no call, no argument copies)."""
    flags: Any = set(fastmath) if isinstance(fastmath, frozenset) else fastmath
    more: dict[str, Any] = {"inline": "always"} if inline else {}

    def decorate(function: F) -> F:
        function.__qualname__ = f"{function.__qualname__}_{fingerprint()}"  # the cache entry's name
        compiled: F = numba.njit(cache=True, nogil=nogil, fastmath=flags, error_model="numpy", **more)(function)
        return compiled

    return decorate


def python_reference(function: Callable[..., Any]) -> Callable[..., Any]:
    """The plain-Python function of a compiled one (``.py_func``; itself when numba's JIT is disabled)."""
    return getattr(function, "py_func", function)
