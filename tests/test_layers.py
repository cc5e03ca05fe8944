"""The layering of docs/architecture.md holds: each layer imports only the ones below it."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: layer -> layers it may import (besides itself). virtual_bus (the emulator) is a tool beside the
#: product: only research/ (campaigns, paper figures, blind cases) and the commands fly it.
ALLOWED: dict[str, set[str]] = {
    "errors": set(),
    "__init__": {"errors"},
    "shipped": {"errors"},
    "flightlog": {"errors", "shipped"},
    "model": {"errors"},
    "bus": {"errors"},
    "estimation": {"errors", "flightlog", "model"},
    "identify": {"errors", "flightlog", "model"},
    "gap": {"errors", "flightlog", "model", "estimation", "identify"},
    "service": {"errors", "shipped", "flightlog", "model", "estimation", "bus"},
    "virtual_bus": {"errors", "shipped", "flightlog", "model", "bus"},
    "research": {"errors", "flightlog", "model", "estimation", "identify", "gap", "bus", "service", "virtual_bus"},
    "cli": {"errors"},
    "commands": {
        "errors",
        "shipped",
        "flightlog",
        "model",
        "estimation",
        "identify",
        "gap",
        "bus",
        "service",
        "research",
        "virtual_bus",
    },
}


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
    assert not violations, "\n".join(violations)
