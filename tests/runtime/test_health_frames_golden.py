"""The health.dbc frames a LiveMonitor publishes, to the byte, against golden digests.

A five-minute flight of a four-cylinder engine (tests/data/flight_four_cylinders.csv, cylinder 3's
probe reading open for 20 s) goes through the live path frame by frame, as one CHT channel (example.yaml)
and per cylinder (four_cylinders.yaml: Health_Spread and Health_Cylinder too). Each health message's
frames (time, id, payload) are hashed; tests/data/health_frames_golden.json holds the digests. A change
that moves any byte of any health frame fails here, naming the message. After an intended change of
what the service computes, rewrite the digests:
``ECU_UPDATE_GOLDEN=1 pytest tests/runtime/test_health_frames_golden.py``.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import pytest

from ecu_monitor.config import load_config
from ecu_monitor.flightlog import read_csv
from ecu_monitor.offline.replay import frames_from_flight
from ecu_monitor.runtime.publishers import LiveMonitor

DATA = Path(__file__).resolve().parents[1] / "data"
GOLDEN = DATA / "health_frames_golden.json"
CONFIGS = Path(__file__).resolve().parents[2] / "ecu_monitor" / "data" / "configs"


def health_frame_digests(config_name: str) -> dict[str, Any]:
    """Per health message of the flight under ``config_name``: frame count and sha256 of (time, id, data)."""
    config = load_config(CONFIGS / config_name)
    frames = frames_from_flight(read_csv(DATA / "flight_four_cylinders.csv"), config)
    monitor = LiveMonitor(config, config.load_cylinder_params())
    sent: list[Any] = []
    for msg in frames.messages():
        sent += monitor.advance_to(msg.timestamp)
        monitor.feed(msg)
    names = {int(monitor.publishers[0].encoder.message(n).frame_id): n for n in monitor.publishers[0].periods}
    out: dict[str, Any] = {}
    for frame_id, name in sorted(names.items()):
        mine = [f for f in sent if f.arbitration_id == frame_id]
        digest = hashlib.sha256()
        for f in mine:
            digest.update(f"{f.timestamp:.6f} {f.arbitration_id:x} {bytes(f.data).hex()}\n".encode("ascii"))
        out[name] = {"frames": len(mine), "sha256": digest.hexdigest()}
    return out


@pytest.mark.parametrize("config_name", ["example.yaml", "four_cylinders.yaml"])
def test_health_frames_are_the_golden_bytes(config_name: str) -> None:
    got = health_frame_digests(config_name)
    golden = json.loads(GOLDEN.read_text(encoding="utf-8")) if GOLDEN.exists() else {}
    if os.environ.get("ECU_UPDATE_GOLDEN"):
        golden[config_name] = got
        GOLDEN.write_text(json.dumps(golden, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    assert set(got) == set(golden[config_name])
    for name, want in golden[config_name].items():
        assert got[name] == want, f"{config_name}: {name} frames differ from the golden ones"
