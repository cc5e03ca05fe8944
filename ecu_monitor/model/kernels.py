"""numba twins of the model's equations, compiled from their own source (no equation written twice).

:func:`compiled_equations` compiles every function of :mod:`ecu_monitor.model.equations` with its
primitives bound to the ``math`` module; :func:`rebound` makes a copy of any other function (a loop
that calls the equations) whose callees are these twins. The swarm kernel
(:mod:`ecu_monitor.model.compiled`), the filter loops (:mod:`ecu_monitor.estimation.runner`) and the
isolation filter (:mod:`ecu_monitor.estimation.isolation`) are built this way.

numba is imported on first use. The on-disk cache is keyed by a fingerprint of the source files
involved: numba checks only a function's own file for staleness, not its callees' (a cached loop
embeds the machine code of everything it calls), so any edit to any of them gets a fresh entry.
"""

from __future__ import annotations

import functools
import hashlib
import types
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from ecu_monitor.model import atmosphere as _atmosphere
from ecu_monitor.model import equations as _equations

__all__ = ["SWARM_FASTMATH", "compiled_equations", "fingerprint", "jit", "rebound"]

#: LLVM fast-math flags of the swarm kernel: reassociation and reciprocals, but NaN and inf kept
#: (the failure mask and the "not logged" mixture index rely on them).
SWARM_FASTMATH = frozenset({"nsz", "arcp", "contract", "afn", "reassoc"})


def fingerprint(extra: Iterable[str] = ()) -> str:
    """Short hash of the model's equation sources plus the files ``extra``."""
    digest = hashlib.sha256()
    for path in (_equations.__file__, _atmosphere.__file__, __file__, *extra):
        digest.update(Path(str(path)).read_bytes())
    return digest.hexdigest()[:12]


def rebound(function: Callable[..., Any], tag: str, **callees: Any) -> types.FunctionType:
    """A copy of ``function`` whose global names ``callees`` point at other (compiled) functions.

    ``tag`` is appended to the qualified name, which numba uses to name its on-disk cache entry.
    """
    original: Any = function
    namespace = dict(original.__globals__)
    namespace.update(callees)
    clone = types.FunctionType(original.__code__, namespace, original.__name__, original.__defaults__)
    clone.__module__ = original.__module__
    clone.__qualname__ = f"{original.__qualname__}_{tag}"
    return clone


def jit(
    function: Callable[..., Any],
    tag: str,
    fastmath: Any = False,
    nogil: bool = True,
    inline: str = "never",
    **callees: Any,
) -> Any:
    """numba.njit of a :func:`rebound` copy of ``function``: cached, nogil, and numpy's error model
    (a division by zero gives inf or NaN, as in the numpy reference, instead of a check per division
    that would stop the particle loop from vectorising).

    ``nogil=False`` for the live path's short calls (tens of microseconds): releasing the GIL around
    them lets another thread take it, and getting it back can then wait for that thread (up to the
    interpreter's 5 ms switch interval), which is latency on the bus thread for no gain.

    ``inline="always"``: numba inlines the function into its callers (a small helper of the kernels)."""
    import numba  # first use only

    options: dict[str, Any] = {"cache": True, "nogil": nogil, "fastmath": fastmath, "error_model": "numpy"}
    if inline != "never":
        options["inline"] = inline
    return numba.njit(**options)(rebound(function, tag, **callees))


@functools.cache
def compiled_equations(fastmath: frozenset[str] | bool = False) -> types.SimpleNamespace:
    """The equations of :mod:`ecu_monitor.model.equations` compiled by numba (math-module primitives).

    ``fastmath``: False (exact IEEE: the filters, whose complex-step derivative needs it) or a set of
    LLVM flags (:data:`SWARM_FASTMATH` for the swarm kernel).
    """
    import numba  # first use only

    flags = "".join(sorted(f[0] for f in fastmath)) if isinstance(fastmath, frozenset) else str(int(bool(fastmath)))
    tag = f"{fingerprint()}_{flags}"

    options: dict[str, Any] = {"cache": True, "nogil": True, "fastmath": fastmath, "error_model": "numpy"}
    if isinstance(fastmath, frozenset):
        options["fastmath"] = set(fastmath)
        options["inline"] = "always"  # numba-level inlining: the particle loop vectorises

    def wrap(name: str, function: Any) -> Any:
        function.__qualname__ = f"{function.__qualname__}_{tag}"
        return numba.njit(**options)(function)

    return _equations.bind(_equations.SCALAR_PRIMITIVES, wrap)
