"""The layering of docs/architecture.md holds: each layer imports only the ones below it."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: layer -> layers it may import (besides itself). virtual_bus (the emulator) is a tool beside the
#: product: the evaluation campaigns (estimation/evaluation.py, gap/blind.py) fly it; the service never does.
ALLOWED: dict[str, set[str]] = {
    "errors": set(),
    "__init__": {"errors"},
    "flightlog": {"errors"},
    "model": {"errors"},
    "bus": {"errors"},
    "estimation": {"errors", "flightlog", "model", "virtual_bus"},
    "identify": {"errors", "flightlog", "model"},
    "gap": {"errors", "flightlog", "model", "estimation", "identify", "virtual_bus"},
    "service": {"errors", "flightlog", "model", "estimation", "bus"},
    "virtual_bus": {"errors", "flightlog", "model", "bus"},
    "cli": {"errors"},
    "commands": {"errors", "flightlog", "model", "estimation", "identify", "gap", "bus", "service", "virtual_bus"},
}
#: modules of a layer allowed to reach virtual_bus (the evaluation campaigns only)
EMULATOR_USERS = {"ecu_monitor.estimation.evaluation", "ecu_monitor.gap.blind"}


def _layer(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] == "virtual_bus":
        return "virtual_bus"
    if parts[0] != "ecu_monitor":
        return None
    return "__init__" if len(parts) == 1 else parts[1]


def _imports(path: Path) -> set[str]:
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
    return found


def test_each_layer_imports_only_the_layers_below():
    violations = []
    for package in ("ecu_monitor", "virtual_bus"):
        for path in sorted((ROOT / package).rglob("*.py")):
            module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            source = _layer(module)
            assert source in ALLOWED, f"{module}: layer {source!r} is not in the architecture"
            for imported in _imports(path):
                target = _layer(imported)
                if target is None or target == source:
                    continue
                if target not in ALLOWED[source]:
                    violations.append(f"{module} imports {imported}")
                elif target == "virtual_bus" and source in ("estimation", "gap") and module not in EMULATOR_USERS:
                    violations.append(f"{module} imports the emulator {imported}")
    assert not violations, "\n".join(violations)
