"""DroneCAN input (bus/dronecan.py, protocol: dronecan): frames built by the ``dronecan`` package itself
decode to the mapped inputs in canonical units; the multi-frame corner cases (toggle, CRC, transfer-id
wrap, interleaved nodes, node filter, orphans, timeouts) are counted, never raised; the batch decoder
equals the live one; configs are checked at load; a DroneCAN .blf of a virtual flight replays."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
import yaml

from ecu_monitor.bus.canlog import FrameArrays, read_frames
from ecu_monitor.bus.codec import SignalSpec
from ecu_monitor.bus.dronecan import TRANSFER_TIMEOUT_S, DroneCanDecoder, looks_like_dronecan, parse_field
from ecu_monitor.bus.dronecan_codec import message_codec, transfer_frames
from ecu_monitor.config import load_config, parse_config
from ecu_monitor.errors import ConfigError
from ecu_monitor.model import paper_table_a1
from ecu_monitor.offline.replay import replay_frames, replay_live
from ecu_monitor.units import pressure_altitude_m
from tests.helpers import REPO

dronecan = pytest.importorskip("dronecan")

SHIPPED = REPO / "ecu_monitor" / "data" / "configs" / "dronecan.yaml"
STATUS = "uavcan.equipment.ice.reciprocating.Status"
SPECS = [
    SignalSpec("rpm", STATUS, "engine_speed_rpm", "rpm"),
    SignalSpec("throttle_pct", STATUS, "throttle_position_percent", "pct"),
    SignalSpec("fuel_flow_lph", STATUS, "fuel_consumption_rate_cm3pm", "cc_per_min"),
    SignalSpec("cht_c", STATUS, "cylinder_status[mean].cylinder_head_temperature", "K"),
    SignalSpec("cht1_c", STATUS, "cylinder_status[0].cylinder_head_temperature", "K"),
    SignalSpec("cht4_c", STATUS, "cylinder_status[3].cylinder_head_temperature", "K"),
    SignalSpec("altitude_m", "uavcan.equipment.air_data.StaticPressure", "static_pressure", "Pa"),
    SignalSpec("airspeed_mps", "uavcan.equipment.air_data.IndicatedAirspeed", "indicated_airspeed", "mps"),
    SignalSpec("oat_c", "uavcan.equipment.air_data.StaticTemperature", "static_temperature", "K"),
]


def _status(rpm: int = 5500, chts_k: tuple[float, ...] = (420.0, 430.0, 440.0, 450.0)) -> Any:
    """An ICE status built with the dronecan package's own types (not our encoder)."""
    ice = dronecan.uavcan.equipment.ice.reciprocating
    msg = ice.Status(engine_speed_rpm=rpm, throttle_position_percent=63, fuel_consumption_rate_cm3pm=250.0)
    for k in chts_k:
        msg.cylinder_status.append(ice.CylinderStatus(cylinder_head_temperature=k, exhaust_gas_temperature=900.0))
    return msg


def _frames(
    payload: Any, node: int, transfer_id: int = 0, time_s: float = 0.0, priority: int = 16
) -> list[can.Message]:
    """The frames of one broadcast, split and CRC'd by the dronecan package's Transfer."""
    transfer = dronecan.transport.Transfer(
        transfer_id=transfer_id, source_node_id=node, payload=payload, transfer_priority=priority
    )
    return [
        can.Message(timestamp=time_s, arbitration_id=f.message_id, is_extended_id=True, data=bytes(f.bytes))
        for f in transfer.to_frames()
    ]


def _feed(decoder: DroneCanDecoder, frames: list[can.Message]) -> dict[str, list[float]]:
    got: dict[str, list[float]] = {}
    for msg in frames:
        out = decoder.decode(msg.arbitration_id, msg.is_extended_id, msg.data, msg.timestamp)
        for slot, value in out or ():
            got.setdefault(decoder.names[slot], []).append(value)
    return got


def test_frames_of_the_dronecan_package_decode_to_canonical_units() -> None:
    decoder = DroneCanDecoder(SPECS)
    air = dronecan.uavcan.equipment.air_data
    frames = _frames(_status(), node=20)
    assert len(frames) > 1  # a multi-frame transfer: tail bytes, toggle, transfer CRC
    frames += _frames(air.StaticPressure(static_pressure=70108.0), node=21)
    frames += _frames(air.IndicatedAirspeed(indicated_airspeed=23.5), node=21)
    frames += _frames(air.StaticTemperature(static_temperature=280.0), node=21)
    got = _feed(decoder, frames)
    assert got["rpm"] == [5500.0] and got["throttle_pct"] == [63.0]
    assert got["fuel_flow_lph"] == pytest.approx([250.0 * 0.06])
    assert got["cht_c"] == pytest.approx([435.0 - 273.15])  # the mean of the four cylinders
    assert got["cht1_c"] == pytest.approx([420.0 - 273.15]) and got["cht4_c"] == pytest.approx([450.0 - 273.15])
    assert got["altitude_m"] == pytest.approx([pressure_altitude_m(70.108)], abs=1e-6)
    assert 2900.0 < got["altitude_m"][0] < 3100.0
    assert got["airspeed_mps"] == [23.5] and got["oat_c"] == pytest.approx([280.0 - 273.15])
    assert decoder.counters["ok"] == len(frames) and decoder.counters["malformed"] == 0


def test_a_cylinder_missing_or_nan_gives_no_value_and_the_mean_skips_it() -> None:
    decoder = DroneCanDecoder(SPECS)
    got = _feed(decoder, _frames(_status(chts_k=(400.0, math.nan)), node=20))
    assert got["cht_c"] == pytest.approx([400.0 - 273.15])
    assert "cht4_c" not in got and decoder.counters["unknown_value"] == 1
    assert decoder.counters["malformed"] == 0


def _spoil(frames: list[can.Message], index: int, xor: int, at: int = -1) -> list[can.Message]:
    out = [can.Message(timestamp=m.timestamp, arbitration_id=m.arbitration_id, is_extended_id=True,
                       data=bytearray(m.data)) for m in frames]  # fmt: skip
    out[index].data[at] ^= xor
    return out


def test_toggle_crc_and_tail_errors_drop_the_transfer_and_are_counted() -> None:
    frames = _frames(_status(), node=20)
    for spoiled, reason in (
        (_spoil(frames, 2, 0x20), "bad_toggle"),  # toggle bit of the third frame flipped
        (_spoil(frames, 1, 0x01, at=0), "bad_crc"),  # a payload byte changed: the transfer CRC fails
        (frames[:2] + frames[3:], "bad_toggle"),  # a frame lost in the middle
    ):
        decoder = DroneCanDecoder(SPECS)
        assert _feed(decoder, spoiled) == {}
        assert decoder.counters[reason] == len(spoiled) == decoder.counters["malformed"], reason
    decoder = DroneCanDecoder(SPECS)  # the next good transfer decodes
    assert _feed(decoder, _spoil(frames, 2, 0x20) + _frames(_status(rpm=4000), node=20, transfer_id=1))["rpm"] == [
        4000.0
    ]


def test_transfer_id_wraps_and_interleaved_nodes_reassemble_apart() -> None:
    decoder = DroneCanDecoder(SPECS)
    a = [_frames(_status(rpm=1000 + i), node=20, transfer_id=i % 32) for i in range(40)]  # 0..31, 0..7
    b = [_frames(_status(rpm=3000 + i, chts_k=(500.0,)), node=30, transfer_id=(i + 30) % 32) for i in range(40)]
    mixed: list[can.Message] = []
    for fa, fb in zip(a, b, strict=True):  # frame by frame, two multi-frame transfers at once
        for k in range(max(len(fa), len(fb))):
            mixed.extend(f[k] for f in (fa, fb) if k < len(f))
    got = _feed(decoder, mixed)
    assert sorted(got["rpm"]) == sorted([1000.0 + i for i in range(40)] + [3000.0 + i for i in range(40)])
    assert decoder.counters["malformed"] == 0 and decoder.counters["ok"] == len(mixed)
    only_20 = DroneCanDecoder(SPECS, source_node_ids=[20])
    got = _feed(only_20, mixed)
    assert got["rpm"] == [1000.0 + i for i in range(40)]
    assert only_20.counters["filtered_node"] == sum(len(f) for f in b)


def test_orphans_timeouts_foreign_frames_and_empty_frames() -> None:
    frames = _frames(_status(), node=20)
    decoder = DroneCanDecoder(SPECS)
    assert _feed(decoder, frames[1:]) == {}  # joined mid-transfer
    assert decoder.counters["orphan_frame"] == len(frames) - 1
    late = [can.Message(timestamp=i * (TRANSFER_TIMEOUT_S + 0.5), arbitration_id=m.arbitration_id,
                        is_extended_id=True, data=m.data) for i, m in enumerate(frames)]  # fmt: skip
    decoder = DroneCanDecoder(SPECS)
    assert _feed(decoder, late) == {}
    assert decoder.counters["transfer_timeout"] == 2 and decoder.counters["orphan_frame"] == len(frames) - 2
    decoder = DroneCanDecoder(SPECS)
    decoder.decode(0x100, False, b"\x00" * 8, 0.0)  # an 11-bit frame (a DBC ECU on the same bus)
    decoder.decode(frames[0].arbitration_id | 0x80, True, b"\xc0", 0.0)  # a service frame
    node_status = _frames(dronecan.uavcan.protocol.NodeStatus(uptime_sec=5), node=20)[0]
    decoder.decode(node_status.arbitration_id, True, node_status.data, 0.0)
    assert decoder.counters["unknown_id"] == 3
    decoder.decode(frames[0].arbitration_id, True, b"", 0.0)
    assert decoder.counters["bad_dlc"] == 1 and decoder.counters["malformed"] == 1


def _arrays(frames: list[can.Message]) -> FrameArrays:
    data = np.zeros((len(frames), 8), dtype=np.uint8)
    for i, m in enumerate(frames):
        data[i, : len(m.data)] = np.frombuffer(bytes(m.data), dtype=np.uint8)
    return FrameArrays(
        np.array([m.timestamp for m in frames]),
        np.array([m.arbitration_id for m in frames], dtype=np.int64),
        np.array([m.is_extended_id for m in frames]),
        np.array([len(m.data) for m in frames], dtype=np.int64),
        data,
        np.zeros(len(frames), dtype=bool),
    )


def test_batch_decode_equals_the_live_decoder() -> None:
    frames: list[can.Message] = []
    for i in range(12):
        good = _frames(_status(rpm=2000 + i), node=20, transfer_id=i, time_s=0.1 * i)
        frames += _spoil(good, 1, 0x20) if i == 5 else good[1:] if i == 7 else good
        frames += _frames(dronecan.uavcan.equipment.air_data.IndicatedAirspeed(indicated_airspeed=20.0 + i),
                          node=21, transfer_id=i, time_s=0.1 * i)  # fmt: skip
    frames.append(can.Message(timestamp=2.0, arbitration_id=0x123, is_extended_id=False, data=b"\x01"))
    live = DroneCanDecoder(SPECS)
    rows: dict[str, list[tuple[int, float]]] = {}
    for row, m in enumerate(frames):
        for slot, value in live.decode(m.arbitration_id, m.is_extended_id, m.data, m.timestamp) or ():
            rows.setdefault(live.names[slot], []).append((row, value))
    arrays = _arrays(frames)
    batch = DroneCanDecoder(SPECS).decode_batch(arrays.arbitration_id, arrays.is_extended, arrays.dlc, arrays.data,
                                                arrays.time_s)  # fmt: skip
    for name in live.names:
        expected = rows.get(name, [])
        assert batch.values[name][0].tolist() == [r for r, _ in expected], name
        assert batch.values[name][1].tolist() == [v for _, v in expected], name
    assert {k: v for k, v in batch.counts.items()} == live.counters
    assert live.counters["bad_toggle"] > 0 and live.counters["orphan_frame"] > 0 and live.counters["unknown_id"] == 1
    assert looks_like_dronecan(arrays.arbitration_id, arrays.is_extended, arrays.dlc, arrays.data)


def test_a_clean_log_is_decoded_with_numpy_to_the_live_values(monkeypatch: pytest.MonkeyPatch) -> None:
    air = dronecan.uavcan.equipment.air_data
    frames: list[can.Message] = []
    for i in range(48):
        chts = tuple((400.0 + i, math.nan, 450.5, 1e6)[: i % 5])  # 0-4 cylinders, NaN, float16 infinity
        a = _frames(_status(rpm=1000 + i, chts_k=chts), node=20, transfer_id=i % 32, time_s=0.1 * i)
        b = _frames(_status(rpm=3000 + i), node=30, transfer_id=(i + 7) % 32, time_s=0.1 * i)
        if i == 5:
            a = _spoil(a, 1, 0x01, at=0)  # a payload byte: the transfer CRC fails
        for k in range(max(len(a), len(b))):  # two multi-frame transfers at once
            frames.extend(f[k] for f in (a, b) if k < len(f))
        frames += _frames(air.StaticPressure(static_pressure=90000.0 - i), node=21, transfer_id=i % 32, time_s=0.1 * i)
        frames += _frames(air.IndicatedAirspeed(indicated_airspeed=math.nan if i == 3 else 20.0 + i), node=21,
                          transfer_id=i % 32, time_s=0.1 * i)  # fmt: skip
    frames.append(
        can.Message(timestamp=5.0, arbitration_id=frames[0].arbitration_id, is_extended_id=True, data=b"\x01\x02\xc9")
    )  # fmt: skip  (a one-frame ICE status too short to unpack)
    arrays = _arrays(frames)
    for nodes in ((), (20, 21)):
        live = DroneCanDecoder(SPECS, source_node_ids=nodes)
        rows: dict[str, list[tuple[int, float]]] = {}
        for row, m in enumerate(frames):
            for slot, value in live.decode(m.arbitration_id, m.is_extended_id, m.data, m.timestamp) or ():
                rows.setdefault(live.names[slot], []).append((row, value))
        assert live.counters["bad_crc"] > 0 and live.counters["decode_error"] == 1 and live.counters["unknown_value"]
        with monkeypatch.context() as patch:  # the per-frame path may not run: numpy does it all
            patch.setattr(DroneCanDecoder, "_take", lambda *args: pytest.fail("per-frame path taken"))
            batch = DroneCanDecoder(SPECS, source_node_ids=nodes).decode_batch(
                arrays.arbitration_id, arrays.is_extended, arrays.dlc, arrays.data, arrays.time_s
            )
        assert batch.counts == live.counters
        for name in live.names:
            assert batch.values[name][0].tolist() == [r for r, _ in rows.get(name, [])], name
            assert batch.values[name][1].tolist() == [v for _, v in rows.get(name, [])], name


def test_field_paths_are_checked_against_the_dsdl() -> None:
    assert parse_field(f"{STATUS}.cylinder_status[2].exhaust_gas_temperature").steps == (
        "cylinder_status", 2, "exhaust_gas_temperature")  # fmt: skip
    for bad, words in (
        ("uavcan.equipment.nothing.Here.x", "no DroneCAN data type"),
        (STATUS, "name a field"),
        (f"{STATUS}.cylinder_status", "is an array"),
        (f"{STATUS}.cylinder_status[0]", "not a number field"),
        (f"{STATUS}.engine_speed_rpm[1]", "not an array"),
        (f"{STATUS}.rpm", "has no field 'rpm'"),
        ("uavcan.protocol.GetNodeInfo.status", "not a broadcast message"),
    ):
        with pytest.raises(ConfigError, match=words):
            parse_field(bad)


def _shipped() -> dict[str, Any]:
    data: dict[str, Any] = yaml.safe_load(SHIPPED.read_text(encoding="utf-8"))
    return data


def test_shipped_config_loads_and_bad_keys_name_the_file_and_key(tmp_path: Path) -> None:
    config = load_config("dronecan.yaml")
    assert config.protocol == "dronecan" and config.dronecan.node_id == 100 and config.dbc_paths == ()
    assert config.input("cht_c").signal == "cylinder_status[mean].cylinder_head_temperature"
    src = tmp_path / "x.yaml"
    spoilt: list[tuple[dict[str, Any], str]] = []
    data = _shipped()
    data["inputs"]["rpm"] = {"field": f"{STATUS}.rpm", "unit": "rpm", "stale_after_s": 1}
    spoilt.append((data, "inputs.rpm.field: .*has no field 'rpm'"))
    data = _shipped()
    data["inputs"]["altitude_m"]["unit"] = "degC"
    spoilt.append((data, "inputs.altitude_m.unit: .*pressure unit"))
    data = _shipped()
    data["dbc"] = ["engine.dbc"]
    spoilt.append((data, "dbc: input DBC files do not apply"))
    data = _shipped()
    data["dronecan"]["node_id"] = 128
    spoilt.append((data, "dronecan.node_id: expected a node id 1..127"))
    data = _shipped()
    data["inputs"]["cht17_c"] = data["inputs"]["cht1_c"]
    spoilt.append((data, "inputs.cht17_c: unknown key 'cht17_c'"))
    data = yaml.safe_load((REPO / "ecu_monitor" / "data" / "configs" / "example.yaml").read_text(encoding="utf-8"))
    data["dronecan"] = {"node_id": 5}
    spoilt.append((data, "dronecan: applies to protocol dronecan only"))
    for data, message in spoilt:
        with pytest.raises(ConfigError, match=f"^{src}: {message}"):
            parse_config(data, src)


def test_the_pressure_altitude_of_a_float_is_numpys_of_that_one_value() -> None:
    """The decoder's per-message altitude (a float: Python's power) is bit for bit the numpy one of the value."""
    rng = np.random.default_rng(1021)
    pressures = [*rng.uniform(0.1, 120.0, 20000).tolist(), *rng.uniform(60.0, 105.0, 20000).astype(np.float32).tolist()]
    pressures += [101.325, 1e-300, 5e-324, 1e300, math.inf, 0.0, -0.0, -1.0, -math.inf, math.nan]
    for kpa in pressures:
        one, numpy_one = pressure_altitude_m(kpa), pressure_altitude_m(np.asarray(kpa))
        assert type(one) is float and (one == numpy_one or (math.isnan(one) and math.isnan(numpy_one))), kpa


def test_altitude_not_sent_is_the_pressure_altitude_of_the_static_pressure(tmp_path: Path) -> None:
    data = _shipped()
    del data["inputs"]["altitude_m"]
    config = parse_config(data, tmp_path / "x.yaml")
    spec = config.input("altitude_m")
    assert (spec.message, spec.signal, spec.unit) == (
        "uavcan.equipment.air_data.StaticPressure",
        "static_pressure",
        "Pa",
    )
    assert spec.stale_after_s == config.input("airspeed_mps").stale_after_s


# --------------------------------------------------------------------------------------------------
# A virtual flight over DroneCAN, recorded to .blf and replayed
# --------------------------------------------------------------------------------------------------

MISSION = {
    "name": "dronecan-short",
    "segments": [
        {"kind": "ground_run", "duration_s": 30, "throttle_pct": 35},
        {"kind": "takeoff", "duration_s": 20, "ground_roll_s": 8, "throttle_pct": 100, "airspeed_mps": 20,
         "climb_rate_mps": 3},
        {"kind": "cruise", "duration_s": 60, "airspeed_mps": 23, "throttle_pct": 60},
    ],
}  # fmt: skip


@pytest.fixture(scope="module")
def dronecan_flight(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    from virtual_bus.missions import mission_from_dict
    from virtual_bus.recorder import record

    root = tmp_path_factory.mktemp("dronecan")
    paths = {"blf": root / "flight.blf", "csv": root / "flight.csv"}
    record(mission_from_dict(MISSION), [paths["blf"], paths["csv"]], paper_table_a1(), seed=3, protocol="dronecan")
    return paths


def test_replay_of_a_dronecan_blf_follows_the_truth_and_batch_equals_live(dronecan_flight: dict[str, Path]) -> None:
    from ecu_monitor.flightlog import load_csv

    config = load_config("dronecan.yaml")
    params = config.load_params()
    frames = read_frames(dronecan_flight["blf"])
    assert looks_like_dronecan(frames.arbitration_id, frames.is_extended, frames.dlc, frames.data)
    batch = replay_frames(config, params, frames)
    assert batch.counters["malformed"] == 0 and batch.counters["ok"] == len(frames)
    states = batch.columns["state"]
    assert len(states) > 1000 and np.all(states[20:] == 0)  # NOMINAL once every input has come
    truth = load_csv(dronecan_flight["csv"])
    t = batch.columns["time_s"]
    true_c = np.interp(t, truth.time_s, truth["cht_true_c"])
    error = batch.columns["cht_est_c"][20:] - true_c[20:]
    assert float(np.sqrt(np.mean(error**2))) < 1.0
    live = replay_live(config, params, list(frames.take(slice(0, 12000)).messages()))
    n = len(live.columns["time_s"])
    assert n > 250
    for name in ("time_s", "cht_meas_c", "cht_est_c", "gamma_q"):
        assert np.allclose(batch.columns[name][:n], live.columns[name], rtol=0, atol=1e-9, equal_nan=True), name
    assert np.array_equal(batch.columns["state"][:n], live.columns["state"])


@pytest.mark.parametrize("nodes", [(), (77, 21)])
def test_receive_filters_pass_the_mapped_types_of_any_priority_from_the_accepted_nodes_only(
    nodes: tuple[int, ...],
) -> None:
    decoder = DroneCanDecoder(SPECS, source_node_ids=nodes)
    bus = can.Bus(interface="virtual", channel=f"dronecan-filters-{len(nodes)}", receive_own_messages=True)
    try:
        bus.set_filters(decoder.can_filters())
        wanted = _frames(_status(), node=77, priority=3)[0]
        air = _frames(dronecan.uavcan.equipment.air_data.StaticPressure(static_pressure=9e4), node=21, priority=30)[0]
        other_node = _frames(_status(), node=78)[0]
        foreign = _frames(dronecan.uavcan.protocol.NodeStatus(uptime_sec=1), node=20)[0]
        service = can.Message(arbitration_id=wanted.arbitration_id | 0x80, is_extended_id=True, data=b"\xc0")
        for msg in (foreign, service, other_node, wanted, air):
            bus.send(msg)
        got = [bus.recv(0.2) for _ in range(5)]
        passed = [m.arbitration_id for m in got if m is not None]
        expected = [other_node.arbitration_id] if not nodes else []
        assert passed == [*expected, wanted.arbitration_id, air.arbitration_id]
    finally:
        bus.shutdown()


# --------------------------------------------------------------------------------------------------
# The service as a DroneCAN node
# --------------------------------------------------------------------------------------------------


def _engine_frames(t0: float, seconds: float, cht_c: float = 120.0, node: int = 20) -> list[can.Message]:
    """Steady engine and air data at 10 Hz, built with the dronecan package's own types."""
    air = dronecan.uavcan.equipment.air_data
    out: list[can.Message] = []
    for i in range(round(seconds * 10)):
        t = t0 + 0.1 * i
        out += _frames(_status(rpm=5000, chts_k=(cht_c + 273.15,)), node=node, transfer_id=i % 32, time_s=t)
        out += _frames(air.StaticPressure(static_pressure=95000.0), node=node + 1, transfer_id=i % 32, time_s=t)
        out += _frames(air.IndicatedAirspeed(indicated_airspeed=22.0), node=node + 1, transfer_id=i % 32, time_s=t)
        out += _frames(air.StaticTemperature(static_temperature=290.0), node=node + 1, transfer_id=i % 32, time_s=t)
    return out


def _published(frames: list[can.Message]) -> list[tuple[float, str, Any]]:
    """(time, data type, payload) of every transfer in ``frames``, reassembled by the dronecan package."""
    manager = dronecan.transport.TransferManager()
    out = []
    for msg in frames:
        assert msg.is_extended_id and msg.arbitration_id & 0x7F == 100  # the configured node id
        done = manager.receive_frame(dronecan.transport.Frame(msg.arbitration_id, msg.data))
        if done:
            transfer = dronecan.transport.Transfer()
            transfer.from_frames(done)
            out.append((msg.timestamp, dronecan.get_dronecan_data_type(transfer.payload).full_name, transfer.payload))
    return out


def _run_pipeline(frames: list[can.Message], until_s: float) -> list[can.Message]:
    from ecu_monitor.runtime.publishers import LiveMonitor as Pipeline

    config = load_config("dronecan.yaml")
    pipeline = Pipeline(config, config.load_params())
    out: list[can.Message] = []
    for msg in frames:
        out += pipeline.advance_to(msg.timestamp)
        pipeline.feed(msg)
    out += pipeline.advance_to(until_s)
    assert pipeline.counters["dronecan_frames"] == len(out) and pipeline.counters["health_frames"] == 0
    return out


def test_node_status_follows_the_engine_state_and_state_changes_are_logged() -> None:
    out = _published(_run_pipeline(_engine_frames(0.0, 4.0), until_s=8.0))  # inputs stop at 4 s
    status = [(t, p.health, p.mode, p.uptime_sec, p.vendor_specific_status_code) for t, n, p in out
              if n == "uavcan.protocol.NodeStatus"]  # fmt: skip
    times = [s[0] for s in status]
    assert times[0] == pytest.approx(0.1) and max(np.diff(times)) <= 1.0 + 1e-6  # >= 1 Hz
    assert 8 <= len(status) <= 10
    assert all(s[3] == math.floor(s[0] - 0.1 + 1e-3) for s in status)  # uptime: whole seconds from the first step
    early = [s for s in status if 1.0 <= s[0] <= 4.0]
    assert early and all(s[1] == 0 and s[2] == 0 and s[4] == 0 for s in early)  # OK, OPERATIONAL, state NOMINAL
    late = [s for s in status if s[0] >= 6.0]
    assert late and all(s[1] == 1 and s[4] & 0x0F == 3 and s[4] >> 4 == 0b1111111 for s in late)  # WARNING, STALE
    logs = [(t, p.level.value, p.source.decode(), p.text.decode()) for t, n, p in out if n.endswith("LogMessage")]
    assert [(level, text.split(":")[0]) for _, level, _, text in logs] == [
        (1, "CHT NOMINAL"), (2, "CHT INPUT_STALE (was NOMINAL)")]  # fmt: skip
    assert all(source == "ecu-monitor" for _, _, source, _ in logs)
    warned = next(s for s in status if s[1] == 1)
    assert warned[0] == logs[1][0] and 4.0 < warned[0] < 6.0  # the change of health is published at once
    values = [(t, p.key.decode(), p.value) for t, n, p in out if n.endswith("KeyValue")]
    assert {key for _, key, _ in values} == {
        "cht_est",
        "cht_meas",
        "cht_dev",
        "gamma_q",
        "gamma_d",
        "headroom",
        "state",
        "not_iso",
        "det_armed",
    }
    # the set due at 3.1 s goes out one key a 20 ms step over the nine steps after it that carry no health status
    sent = [round(t, 6) for t, _, _ in values if 3.1 < t < 3.4]
    assert sent == [3.12, 3.14, 3.16, 3.18, 3.22, 3.24, 3.26, 3.28, 3.32]
    assert not any(abs(t * 10 - round(t * 10)) < 1e-6 for t, _, _ in values)
    at_3 = {key: value for t, key, value in values if 3.1 < t < 3.4}
    assert at_3["cht_meas"] == pytest.approx(120.0, abs=0.25) and at_3["state"] == 0.0
    assert abs(at_3["cht_est"] - 120.0) < 2.0


def test_node_health_mapping() -> None:
    from ecu_monitor.runtime.dronecan_node import node_health

    assert [node_health(s, 100.0, 150.0) for s in ("NOMINAL", "SUSPECT", "INPUT_STALE", "UNAVAILABLE")] == [0, 1, 1, 1]
    assert [node_health(s, 100.0, 150.0) for s in ("DEGRADED", "SENSOR_FAULT")] == [2, 2]
    assert node_health("NOMINAL", 150.0, 150.0) == 3 and node_health("DEGRADED", math.nan, 150.0) == 2
    out = _published(_run_pipeline(_engine_frames(0.0, 3.0, cht_c=155.0), until_s=3.0))  # above the 150 degC limit
    assert {p.health for t, n, p in out if n.endswith("NodeStatus") and t >= 1.0} == {3}


def test_key_values_of_an_engine_monitored_per_cylinder() -> None:
    from ecu_monitor.pipeline.outputs import CylinderSnapshot, HealthSnapshot
    from ecu_monitor.runtime.dronecan_node import key_values

    nominal = {"cht_meas_c": 120.0, "cht_est_c": 121.0, "deviation": 0.0, "state": "NOMINAL", "gamma_q": 1.0,
               "gamma_d": 1.0, "headroom_s": 6000.0}  # fmt: skip
    degraded = {**nominal, "cht_meas_c": 140.0, "cht_est_c": 141.0, "deviation": 0.3, "state": "DEGRADED",
                "gamma_q": 1.2, "headroom_s": 900.0}  # fmt: skip
    cylinders = (CylinderSnapshot(number=1, **nominal), CylinderSnapshot(number=2, **degraded))
    snap = HealthSnapshot(time_s=10.0, cylinders=cylinders, cht_spread_c=20.0, hottest_cylinder=2, **degraded)
    pairs = dict(key_values(snap))
    assert pairs["state"] == 2.0 and pairs["spread"] == 20.0 and pairs["hottest"] == 2.0
    assert (pairs["cyl1_st"], pairs["cyl2_st"], pairs["cyl2_gq"], pairs["cyl1_est"]) == (0.0, 2.0, 1.2, 121.0)
    assert all(len(key) <= 10 for key in pairs)


def test_the_mean_exhaust_temperature_feeds_a_model_with_the_mixture_index(tmp_path: Path) -> None:
    """egt_c mapped to the ICE status's mean exhaust gas temperature (kelvin): a model whose mixture_index
    effect reads the EGT gets it (degC) as an input of its own, reported stale like any other."""
    from ecu_monitor.model.effects import Effects, MixtureIndex
    from ecu_monitor.runtime.publishers import LiveMonitor as Pipeline

    data = _shipped()
    data["inputs"]["egt_c"] = {
        "field": f"{STATUS}.cylinder_status[mean].exhaust_gas_temperature",
        "unit": "K",
        "stale_after_s": 1.0,
    }
    config = parse_config(data, tmp_path / "x.yaml")
    params = paper_table_a1().replace(effects=Effects(mixture_index=MixtureIndex("egt_c", 0.001, 600.0)))
    pipeline = Pipeline(config, params)
    assert pipeline.model_inputs[-1] == "egt_c"
    air = dronecan.uavcan.equipment.air_data
    for t in (0.1, 0.2):
        frames = _frames(_status(), node=20, transfer_id=int(t * 10), time_s=t)
        frames += _frames(air.StaticPressure(static_pressure=70108.0), node=21, transfer_id=int(t * 10), time_s=t)
        frames += _frames(air.IndicatedAirspeed(indicated_airspeed=23.5), node=21, transfer_id=int(t * 10), time_s=t)
        frames += _frames(air.StaticTemperature(static_temperature=280.0), node=21, transfer_id=int(t * 10), time_s=t)
        for msg in frames:
            pipeline.feed(msg)
        pipeline.advance_to(t)
    assert pipeline.held_input("egt_c") == pytest.approx(900.0 - 273.15)
    pipeline.advance_to(1.5)  # no frame for 1.3 s: every input stale, the EGT named with them
    assert "egt_c" in pipeline.snapshot().stale_inputs


def test_field_readers_give_what_the_whole_payload_decode_gives(monkeypatch: pytest.MonkeyPatch) -> None:
    """The live decoder reads the mapped fields where the payload's length puts them (bit-aligned or not, an
    array element, a reduction); the same values and counts as decoding the whole payload and walking it, for
    transfers built by the dronecan package and for random payloads of every length, and a layout that
    depends on the content (a length-prefixed array before the field) falls back to the whole decode."""
    ice = dronecan.uavcan.equipment.ice.reciprocating
    ahrs = "uavcan.equipment.ahrs.Solution"
    fields = [
        "state", "flags", "engine_load_percent", "engine_speed_rpm", "spark_dwell_time_ms", "throttle_position_percent",
        "ecu_index", "fuel_consumption_rate_cm3pm", "cylinder_status[0].cylinder_head_temperature",
        "cylinder_status[2].ignition_timing_deg", "cylinder_status[15].exhaust_gas_temperature",
        "cylinder_status[mean].cylinder_head_temperature", "cylinder_status[max].exhaust_gas_temperature",
        "cylinder_status[min].injection_time_ms",
    ]  # fmt: skip
    specs = [SignalSpec(f"v{i}", STATUS, field, "raw") for i, field in enumerate(fields)]
    specs += [SignalSpec("rate_x", ahrs, "angular_velocity[0]", "raw")]
    rng = np.random.default_rng(14)
    special = np.array([math.nan, math.inf, -math.inf, 0.0, -0.0, 1e6, 6.1e-5])
    frames: list[can.Message] = []
    for i in range(160):
        n = i % 17
        values = np.where(rng.random(4 * n) < 0.2, rng.choice(special, 4 * n), rng.normal(400.0, 200.0, 4 * n))
        msg = ice.Status(
            state=int(rng.integers(0, 4)), flags=int(rng.integers(0, 2**30)),
            engine_load_percent=int(rng.integers(0, 128)), engine_speed_rpm=int(rng.integers(0, 2**17)),
            spark_dwell_time_ms=float(rng.normal(2.0, 1.0)),
            throttle_position_percent=int(rng.integers(0, 128)), ecu_index=int(rng.integers(0, 64)),
            fuel_consumption_rate_cm3pm=float(values[0]) if n else math.nan,
        )  # fmt: skip
        for k in range(n):
            msg.cylinder_status.append(
                ice.CylinderStatus(
                    cylinder_head_temperature=float(values[4 * k]), ignition_timing_deg=float(values[4 * k + 1]),
                    exhaust_gas_temperature=float(values[4 * k + 2]), injection_time_ms=float(values[4 * k + 3]),
                )
            )  # fmt: skip
        frames += _frames(msg, node=20, transfer_id=i % 32, time_s=0.01 * i)
        solution = dronecan.uavcan.equipment.ahrs.Solution(angular_velocity=[float(x) for x in rng.normal(0, 9, 3)])
        solution.orientation_covariance = [float(x) for x in rng.normal(0, 1, int(rng.integers(0, 10)))]
        frames += _frames(solution, node=21, transfer_id=i % 32, time_s=0.01 * i)
        body = rng.integers(0, 256, int(rng.integers(0, 80)), dtype=np.uint8).tobytes()  # random, CRC made good
        for data in transfer_frames(body, i % 32, message_codec(STATUS).base_crc or 0):
            frames.append(can.Message(timestamp=0.01 * i, arbitration_id=frames[0].arbitration_id, is_extended_id=True,
                                      data=data))  # fmt: skip
    read = DroneCanDecoder(specs)
    whole = DroneCanDecoder(specs)
    monkeypatch.setattr(whole, "_prepare_readers", lambda *args: ())  # every payload decoded whole
    for m in frames:
        assert repr(read.decode(m.arbitration_id, True, m.data, m.timestamp)) == repr(
            whole.decode(m.arbitration_id, True, m.data, m.timestamp)
        )
    assert read.counters == whole.counters
    assert read.counters["ok"] > 0 and read.counters["decode_error"] > 0 and read.counters["unknown_value"] > 0
    status_id = message_codec(STATUS).data_type_id
    assert all(read._readers[(status_id, 35 + 10 * n)] for n in range(17))  # 0-16 cylinders: read in place
    assert not any(r for (dtid, _), r in read._readers.items() if dtid == message_codec(ahrs).data_type_id)


def test_the_node_answers_get_node_info_as_the_package_reads_it() -> None:
    """A GetNodeInfo request built by the dronecan package, to the node (100) from node 42, is answered with
    the next step's frames: a response the package reassembles and decodes, to 42, at the request's priority
    and transfer id, with the node's status as it broadcasts it, the version and the name; a request to
    another node is not taken (it counts as a foreign frame)."""
    from ecu_monitor import __version__
    from ecu_monitor.runtime.dronecan_node import NODE_NAME
    from ecu_monitor.runtime.publishers import LiveMonitor as Pipeline

    def request(dest: int, transfer_id: int, time_s: float) -> can.Message:
        transfer = dronecan.transport.Transfer(
            transfer_id=transfer_id, source_node_id=42, dest_node_id=dest, transfer_priority=20,
            payload=dronecan.uavcan.protocol.GetNodeInfo.Request(), service_not_message=True,
            request_not_response=True,
        )  # fmt: skip
        (frame,) = transfer.to_frames()
        return can.Message(
            timestamp=time_s, arbitration_id=frame.message_id, is_extended_id=True, data=bytes(frame.bytes)
        )

    config = load_config("dronecan.yaml")
    pipeline = Pipeline(config, config.load_params())
    assert pipeline.receive_filters()[-1] == {"can_id": 1 << 16 | 1 << 15 | 100 << 8 | 0x80, "can_mask": 0x00FFFF80,
                                              "extended": True}  # fmt: skip
    frames = _engine_frames(0.0, 3.0)
    frames += [request(100, 7, 2.505), request(99, 8, 2.505)]
    frames.sort(key=lambda m: m.timestamp)
    out: list[can.Message] = []
    sent_by: dict[int, float] = {}  # frame -> the time of the advance_to that returned it
    ticks: list[tuple[float, can.Message | None]] = [(2.519, None), (2.52, None), (3.0, None)]  # a tick: no frame
    for t, msg in sorted([*((m.timestamp, m) for m in frames), *ticks], key=lambda item: item[0]):
        got = pipeline.advance_to(t)
        sent_by.update((id(m), t) for m in got)
        out += got
        if msg is not None:
            pipeline.feed(msg)
    assert pipeline.counters["dronecan_requests"] == 1
    replies = [m for m in out if m.arbitration_id & 0x80]
    assert replies and all(sent_by[id(m)] == 2.52 for m in replies)  # with the next 20 ms step (2.52 s)
    reply_id = replies[0].arbitration_id
    assert (reply_id >> 24, reply_id >> 16 & 0xFF, reply_id >> 15 & 1, reply_id >> 8 & 0x7F, reply_id & 0x7F) == (
        20, 1, 0, 42, 100)  # fmt: skip
    manager = dronecan.transport.TransferManager()
    done = None
    for msg in replies:
        assert msg.data[-1] & 0x1F == 7  # the request's transfer id
        done = manager.receive_frame(dronecan.transport.Frame(msg.arbitration_id, msg.data)) or done
    assert done is not None
    transfer = dronecan.transport.Transfer()
    transfer.from_frames(done)
    info = transfer.payload
    assert dronecan.get_dronecan_data_type(info).full_name == "uavcan.protocol.GetNodeInfo"
    assert bytes(info.name).decode() == NODE_NAME
    assert (info.software_version.major, info.software_version.minor) == tuple(
        int(v) for v in __version__.split(".")[:2]
    )
    status = [p for t, n, p in _published([m for m in out if not m.arbitration_id & 0x80]) if n.endswith("NodeStatus")]
    last = status[-1]  # the NodeStatus broadcast before the reply (OK, OPERATIONAL, 2 s up at 2.1 s)
    assert (info.status.health, info.status.mode, info.status.vendor_specific_status_code) == (
        last.health, last.mode, last.vendor_specific_status_code)  # fmt: skip
    assert info.status.uptime_sec == 2 and last.uptime_sec == 2
