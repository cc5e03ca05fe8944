"""Property: no frame sequence makes the DroneCAN decoder raise, and its batch path equals the live one;
random DroneCAN logs replayed with dronecan.yaml exit 0 or 2, never a traceback.

Frames are drawn around real transfers (frames the ``dronecan`` package built, then bytes flipped,
frames dropped, repeated, cut or reordered, nodes and priorities changed) and fully random ones. The
suite runs a few examples (``ECU_FUZZ_EXAMPLES``, default 3: 30 of the cheap decoder property); the
full search by hand: ``ECU_FUZZ_EXAMPLES=500 .venv/bin/python -m pytest -q tests/bus/test_dronecan_fuzz.py``.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest

from ecu_monitor.bus.dronecan import DroneCanDecoder
from ecu_monitor.config import load_config

hypothesis = pytest.importorskip("hypothesis")
dronecan = pytest.importorskip("dronecan")
from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from tests.helpers.fuzz import EXAMPLES, check_cli_outcome, fuzz_settings  # noqa: E402


def _transfer(draw: st.DrawFn) -> list[tuple[int, bytes]]:
    """The frames of one real broadcast (ICE status with 0-16 cylinders or an air-data message)."""
    ice = dronecan.uavcan.equipment.ice.reciprocating
    air = dronecan.uavcan.equipment.air_data
    value = st.floats(allow_nan=True, allow_infinity=True, width=32)
    kind = draw(st.integers(0, 3))
    if kind == 0:
        msg = ice.Status(
            engine_speed_rpm=draw(st.integers(0, 2**17 - 1)), throttle_position_percent=draw(st.integers(0, 127))
        )
        for _ in range(draw(st.integers(0, 16))):
            msg.cylinder_status.append(ice.CylinderStatus(cylinder_head_temperature=draw(value)))
    elif kind == 1:
        msg = air.StaticPressure(static_pressure=draw(value))
    elif kind == 2:
        msg = air.IndicatedAirspeed(indicated_airspeed=draw(value))
    else:
        msg = air.StaticTemperature(static_temperature=draw(value))
    transfer = dronecan.transport.Transfer(
        transfer_id=draw(st.integers(0, 31)),
        source_node_id=draw(st.integers(1, 127)),
        payload=msg,
        transfer_priority=draw(st.integers(0, 31)),
    )
    return [(f.message_id, bytes(f.bytes)) for f in transfer.to_frames()]


@st.composite
def frame_streams(draw: st.DrawFn) -> list[tuple[float, int, bool, bytes]]:
    """(time, id, extended, payload) frames: real transfers spoiled in every way, plus random frames."""
    frames: list[tuple[int, bool, bytes]] = []
    for _ in range(draw(st.integers(0, 8))):
        if draw(st.integers(0, 4)) == 0:
            frames.append((draw(st.integers(0, 0x1FFFFFFF)), draw(st.booleans()), draw(st.binary(max_size=8))))
            continue
        for can_id, payload in _transfer(draw):
            roll = draw(st.integers(0, 12))
            if roll == 0:
                continue  # lost
            if roll == 1 and payload:
                i = draw(st.integers(0, len(payload) - 1))
                payload = payload[:i] + bytes([payload[i] ^ draw(st.integers(1, 255))]) + payload[i + 1 :]
            if roll == 2:
                payload = payload[: draw(st.integers(0, len(payload)))]
            frames.append((can_id, True, payload))
            if roll == 3:
                frames.append((can_id, True, payload))  # repeated
    if frames and draw(st.booleans()):
        order = draw(st.permutations(range(len(frames))))
        frames = [frames[i] for i in order]
    t = 0.0
    out = []
    for can_id, extended, payload in frames:
        t += draw(st.sampled_from([0.0, 0.001, 0.1, 2.5, math.nan]))
        out.append((t, can_id, extended, payload))
    return out


SPECS = [spec.signal_spec() for spec in load_config("dronecan.yaml").inputs]


@fuzz_settings(max(30, 10 * EXAMPLES))
@given(stream=frame_streams())
def test_no_frame_stream_raises_and_batch_equals_live(stream: list[tuple[float, int, bool, bytes]]) -> None:
    live = DroneCanDecoder(SPECS)
    expected: dict[str, list[tuple[int, float]]] = {}
    for row, (t, can_id, extended, payload) in enumerate(stream):
        for slot, value in live.decode(can_id, extended, payload, t) or ():
            assert math.isfinite(value)
            expected.setdefault(live.names[slot], []).append((row, value))
    n = len(stream)
    data = np.zeros((n, 8), dtype=np.uint8)
    for i, (_, _, _, payload) in enumerate(stream):
        data[i, : len(payload)] = np.frombuffer(payload, dtype=np.uint8)
    batch = DroneCanDecoder(SPECS).decode_batch(
        np.array([s[1] for s in stream], dtype=np.int64),
        np.array([s[2] for s in stream], dtype=bool),
        np.array([len(s[3]) for s in stream], dtype=np.int64),
        data,
        np.array([s[0] for s in stream], dtype=np.float64),
    )
    assert batch.counts == live.counters
    for name in live.names:
        pairs = expected.get(name, [])
        assert batch.values[name][0].tolist() == [r for r, _ in pairs]
        assert batch.values[name][1].tolist() == [v for _, v in pairs]


def _asc(stream: list[tuple[float, int, bool, bytes]]) -> bytes:
    lines = ["date Sun Nov 22 12:00:00.000 pm 2026", "base hex  timestamps absolute", "no internal events logged"]
    t = 0.0
    for dt, can_id, extended, payload in stream:
        t += 0.0 if math.isnan(dt) else dt
        name = f"{can_id & 0x1FFFFFFF:X}x" if extended else f"{can_id & 0x7FF:X}"
        lines.append(f"   {t:.6f} 1  {name}             Rx   d {len(payload)} {' '.join(f'{b:02X}' for b in payload)}")
    return ("\n".join(lines) + "\n").encode()


@fuzz_settings(EXAMPLES)
@given(stream=frame_streams())
def test_replay_of_random_dronecan_logs_exits_0_or_2(
    capsys: pytest.CaptureFixture[str], stream: list[tuple[float, int, bool, bytes]]
) -> None:
    from ecu_monitor.cli import main  # noqa: F401  (the entry point check_cli_outcome runs)

    with tempfile.TemporaryDirectory(prefix="ecu-fuzz-") as tmp:
        work = Path(tmp)
        (work / "in.asc").write_bytes(_asc(stream))
        argv = ["replay", f"{tmp}/in.asc", "--config", "dronecan.yaml", "--out", f"{tmp}/health.csv"]
        check_cli_outcome(argv, work / "health.csv", work, capsys)
