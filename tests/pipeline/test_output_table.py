"""The output table: every name it gives is unique and fits its publisher, every health.dbc signal has a
source, and the records made from it hold its rows."""

from __future__ import annotations

import math
import re
from pathlib import Path

import cantools
import pytest

from ecu_monitor.pipeline.output_table import (
    HEALTH_VALUES,
    CylinderSnapshot,
    HealthSnapshot,
    bus_number,
    cylinder_values,
)
from ecu_monitor.pipeline.outputs import health_columns
from ecu_monitor.pipeline.step import CYLINDER_OUTPUT
from ecu_monitor.runtime.dronecan_node import key_values
from ecu_monitor.runtime.mavlink_publisher import MAX_NAME, named_values
from ecu_monitor.runtime.publishers import EVENT_FRAME, EVENT_SIGNALS, health_signal_sources

ROOT = Path(__file__).resolve().parents[2]
HEALTH_DBC = ROOT / "ecu_monitor" / "data" / "dbc" / "health.dbc"


def test_names_are_unique_and_fit_their_publishers() -> None:
    names = [v.name for v in HEALTH_VALUES]
    assert len(set(names)) == len(names)
    for column in ("dbc", "cylinder_dbc", "dronecan", "dronecan_cylinder", "mavlink"):
        given = [getattr(v, column) for v in HEALTH_VALUES if getattr(v, column)]
        assert len(set(given)) == len(given), column
    for v in HEALTH_VALUES:
        for name in (v.dronecan, v.dronecan_cylinder, v.mavlink):
            assert len(name.format(n=16)) <= MAX_NAME, name
        assert not v.history or v.scope == "cylinder", v.name


def test_every_health_dbc_signal_has_one_source_and_every_source_a_signal() -> None:
    db = cantools.database.load_file(str(HEALTH_DBC))
    data = {f"{m.name}.{s.name}" for m in db.messages for s in m.signals
            if not re.search(r"(Counter|Checksum)$", s.name)}  # fmt: skip
    events = {f"{EVENT_FRAME}.{name}" for name in EVENT_SIGNALS}  # made from the event record, not a row
    assert set(health_signal_sources()) | events == data and not events & set(health_signal_sources())


def test_the_step_record_and_the_snapshots_hold_the_cylinder_rows() -> None:
    fields = [name for name in CYLINDER_OUTPUT.names if name not in ("code", "fed", "cross_fed", "region", "start_fit")]
    assert fields == [v.name for v in cylinder_values()]
    snap = HealthSnapshot()
    for v in HEALTH_VALUES:
        assert getattr(snap, v.name) == v.default() or (v.kind == "float" and math.isnan(getattr(snap, v.name)))
    cyl = CylinderSnapshot(number=2, state="SENSOR_FAULT")
    assert cyl.sensor_fault and cyl.number == 2
    with pytest.raises(TypeError, match="no field"):
        HealthSnapshot(no_such_value=1.0)
    with pytest.raises(AttributeError):
        snap.no_such_value  # noqa: B018
    assert snap.replace(cht_est_c=100.0).cht_est_c == 100.0


def test_idle_values_stand_in_for_nan_on_the_bus() -> None:
    rows = {v.name: v for v in HEALTH_VALUES}
    assert bus_number(rows["cht_est_c"], math.nan) == -40.0
    assert bus_number(rows["headroom_s"], math.nan) == 6000.0
    assert bus_number(rows["headroom_s"], math.nan, estimated=False) == 0.0
    assert bus_number(rows["state"], "DEGRADED") == 2.0
    assert bus_number(rows["gamma_q"], 1.2) == 1.2


def test_health_csv_and_the_publishers_follow_the_table() -> None:
    one = health_columns(1)
    assert one == tuple(v.name for v in HEALTH_VALUES if v.csv and v.scope != "cylinders")
    four = health_columns(4)
    assert four[: len(one)] == one and four[-1] == "spread_alarm" and "cyl4_cht_rate_c_per_min" in four
    cylinders = tuple(CylinderSnapshot(number=n, cht_est_c=150.0 + n, state="NOMINAL") for n in (1, 2))
    snap = HealthSnapshot(state="NOMINAL", cylinders=cylinders, cht_spread_c=1.0, hottest_cylinder=2)
    keys = dict(key_values(snap))
    assert {v.dronecan for v in HEALTH_VALUES if v.dronecan} <= set(keys)
    assert keys["cyl2_est"] == 152.0 and keys["hottest"] == 2.0
    names = dict(named_values(snap))
    assert names["CHT2_EST"] == 152.0 and names["CHT_HOT"] == 2.0 and names["ENG_ST"] == 0.0
    single = dict(named_values(HealthSnapshot(cht_est_c=140.0)))
    assert single["CHT1_EST"] == 140.0 and "CHT_SPRD" not in single
