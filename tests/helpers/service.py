"""The daemon's config and pipeline on a test bus: the shipped example.yaml with absolute paths."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from ecu_monitor.config import load_config
from ecu_monitor.runtime.publishers import LiveMonitor
from tests.helpers import REPO

ENGINE_DBC = REPO / "ecu_monitor" / "data" / "dbc" / "engine.dbc"
HEALTH_DBC = REPO / "ecu_monitor" / "data" / "dbc" / "health.dbc"


def write_config(tmp_path: Path, bus: dict[str, Any], name: str = "service.yaml", **changes: Any) -> Path:
    """The shipped example.yaml with absolute DBC paths, the given bus and a state_dir under tmp_path."""
    data = yaml.safe_load((REPO / "ecu_monitor" / "data" / "configs" / "example.yaml").read_text())
    data["dbc"] = [str(ENGINE_DBC)]
    data["health_dbc"] = str(HEALTH_DBC)
    data["bus"] = bus
    data["state_dir"] = str(tmp_path / "state")
    data["reopen_backoff_s"] = {"initial": 0.1, "max": 0.4}
    data.update(changes)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def service_pipeline(tmp_path: Path, channel: str) -> LiveMonitor:
    """The pipeline and publishers of a config on python-can's ``virtual`` bus ``channel``."""
    config = load_config(write_config(tmp_path, {"interface": "virtual", "channel": channel}))
    return LiveMonitor(config, config.load_params())
