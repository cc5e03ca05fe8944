"""Settings and fixtures the whole suite shares (helpers that are not fixtures: tests/helpers/).

``NUMBA_CACHE_DIR=""`` unless the developer set it: numba's own default, ``__pycache__`` beside the
sources, where the suite's kernels were cached before the command line chose
``~/.cache/ecu-monitor/numba`` (ecu_monitor/compile_cache.py). The ``ecu-monitor`` and ``virtual-ecu``
mains that tests run (in this process or as children) find the variable set and leave it alone, so the
suite writes nothing into the developer's home. tests/cli/test_compile_cache.py removes it for the
processes that check the default.

Before the workers start (pytest-xdist's controller, or the one process of ``-n 0``), the step's compiled
code is loaded once, which on a fresh clone compiles it into that cache: otherwise every worker, and every
process a test starts meanwhile, would compile the same code at the same time (numba has no lock for it).
Meanwhile a second process compiles the kernels most other tests share (tests/helpers/warm_kernels.py), so
both cores compile on a fresh clone.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator

import pytest

from tests.helpers import REPO
from tests.helpers.netns import Namespace, netns_unavailable

os.environ.setdefault("NUMBA_CACHE_DIR", "")
# One BLAS thread per process: the suite already runs a worker per core (pytest-xdist), and OpenBLAS's
# threads spinning against the other worker made a small SVD (the identification's polish) take minutes.
for _blas_threads in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_blas_threads, "1")


def pytest_sessionstart(session: pytest.Session) -> None:
    if hasattr(session.config, "workerinput"):  # a pytest-xdist worker: its controller did it
        return
    from ecu_monitor.config import load_config
    from ecu_monitor.pipeline.engine import Pipeline
    from ecu_monitor.shipped import resolve_file

    # the kernels most tests share, in a second process meanwhile (tests/helpers/warm_kernels.py: none of
    # them is one the step's warm-up writes, so the two never write the same cache file)
    others = subprocess.Popen([sys.executable, "-m", "tests.helpers.warm_kernels"], cwd=REPO, stderr=subprocess.PIPE)
    try:
        config = load_config(resolve_file("example", "config"))
        Pipeline(config, config.load_cylinder_params()).warm_up()
    finally:
        _, stderr = others.communicate()
    if others.returncode != 0:  # not fatal: the tests compile what they need, and say what is broken
        sys.stderr.write(f"tests/helpers/warm_kernels.py failed:\n{stderr.decode(errors='replace')}\n")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The modules that hold a ``slow`` test first (a stable sort, the rest in their order): pytest-xdist
    hands a module to a worker whole, and a long one handed out last would keep one core busy alone at the
    end of the run."""
    slow = {item.nodeid.split("::")[0] for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.nodeid.split("::")[0] not in slow)


@pytest.fixture
def ns() -> Iterator[Namespace]:
    """A fresh network namespace (a unique name, its own ports), deleted with its processes afterwards."""
    reason = netns_unavailable()
    if reason is not None:
        pytest.skip(reason)
    made = Namespace()
    try:
        made.create()
        yield made
    finally:
        made.close()
