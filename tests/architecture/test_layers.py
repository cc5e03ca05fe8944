"""The layering of docs/architecture.md holds: the import-linter contracts of pyproject.toml pass, and
the page lists the same layers in the same order."""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

from tests.helpers import REPO

LINT_IMPORTS = Path(sys.executable).with_name("lint-imports")


def _contracts() -> list[dict[str, object]]:
    config = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))
    return list(config["tool"]["importlinter"]["contracts"])


def test_import_linter_contracts_are_kept() -> None:
    assert LINT_IMPORTS.exists(), f"{LINT_IMPORTS} missing: the test extra has import-linter (pip install -e '.[test]')"
    result = subprocess.run(
        [str(LINT_IMPORTS), "--no-cache"], cwd=REPO, capture_output=True, text=True, timeout=300, check=False
    )
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
    assert "BROKEN" not in result.stdout


def test_every_package_is_in_a_layer() -> None:
    (layers,) = [c for c in _contracts() if c["type"] == "layers"]
    named = {name.strip() for line in layers["layers"] for name in str(line).split("|")}  # type: ignore[union-attr]
    top = {p.stem if p.suffix == ".py" else p.name for p in (REPO / "ecu_monitor").iterdir()}
    top -= {"__init__", "__pycache__", "data"}
    assert {f"ecu_monitor.{name}" for name in top} | {"virtual_bus"} == named


def test_architecture_page_lists_the_contract_layers() -> None:
    (layers,) = [c for c in _contracts() if c["type"] == "layers"]
    page = (REPO / "docs" / "architecture.md").read_text(encoding="utf-8")
    block = re.search(r"<!-- layers:.*?-->\n```\n(.*?)```", page, re.DOTALL)
    assert block, "docs/architecture.md: the layers block is missing"
    listed = [re.split(r"\s{2,}", line.strip())[0] for line in block.group(1).splitlines() if line.strip()]
    assert listed == list(layers["layers"]), "docs/architecture.md lists other layers than pyproject.toml"  # type: ignore[call-overload]


def test_architecture_page_lists_every_module() -> None:
    """The page's one-line index names every module of the package and the virtual bus, and no other."""
    page = (REPO / "docs" / "architecture.md").read_text(encoding="utf-8")
    block = re.search(r"<!-- modules:.*?-->\n(.*?)<!-- /modules -->", page, re.DOTALL)
    assert block, "docs/architecture.md: the module index is missing"
    listed = set(re.findall(r"^- `([^`]+\.py)`", block.group(1), re.MULTILINE))
    package = REPO / "ecu_monitor"
    sources = [p for p in package.rglob("*.py") if p.name != "__init__.py" and "data" not in p.parts]
    modules = {str(p.relative_to(package)) for p in sources}
    modules |= {f"../{p.relative_to(REPO)}" for p in (REPO / "virtual_bus").rglob("*.py") if p.name != "__init__.py"}
    assert listed == modules, f"missing: {sorted(modules - listed)}; gone: {sorted(listed - modules)}"
