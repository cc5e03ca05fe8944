"""``fleet demo`` at a small scale: the engine type commissioned as ``ecu-monitor calibrate`` does, and what the
per-flight detector then says of the healthy engines' flights.

Six engines of six short flights each, one of them wearing, every flight with residual unmodelled effects, and
the demo's eight hour-long reference flights of a sister engine; two local Dask workers. The same logs are run
again with the shipped detector (the virtual ECU's reference, learned on flights without residual effects)
beside the demo's wear reference: that control turns many healthy flights DEGRADED, so the few the calibrated
detector turns DEGRADED are its doing, not flights that cannot go DEGRADED.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import yaml

from ecu_monitor.cli import main
from ecu_monitor.fleet.run import run_fleet
from ecu_monitor.model import paper_table_a1
from ecu_monitor.offline.calibration import model_fingerprint

pytestmark = [pytest.mark.slow, pytest.mark.process, pytest.mark.timeout(600)]

_ENGINES = 6
_FLIGHTS = 36


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """The demo's folder and what the command printed."""
    root = tmp_path_factory.mktemp("demo") / "fleet"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = main(["fleet", "demo", str(root), "--engines", str(_ENGINES), "--flights", str(_FLIGHTS),
                     "--degrading", "1", "--workers", "2"])  # fmt: skip
    assert code == 0, printed.getvalue()
    return root, printed.getvalue()


def _healthy_degraded(out: Path, wearing: set[str]) -> tuple[int, int]:
    """Healthy engines' flights that went DEGRADED, and their number."""
    flights = pq.read_table(out / "flights").to_pylist()
    healthy = [f for f in flights if str(f["serial"]) not in wearing]
    return sum(f["worst_state"] == "DEGRADED" for f in healthy), len(healthy)


def test_the_detector_file_is_calibrate_s_on_the_reference_flights(demo: tuple[Path, str]) -> None:
    root, printed = demo
    text = (root / "detector.yaml").read_text()
    assert text.startswith("# detector threshold calibrated by `ecu-monitor calibrate` on ")
    section = yaml.safe_load(text)
    detector, wear = section["detector"], section["wear"]["reference"]
    references = sorted(p.name for p in (root / "reference").iterdir())
    assert len(references) == 8 and all(f"#   reference/{name}" in text for name in references)
    assert detector["calibrated_for"] == model_fingerprint(paper_table_a1())
    assert len(detector["nominal_mean"]) == len(detector["nominal_spread"]) == 5
    assert detector["nominal_threshold"] >= 1.0 and detector["threshold"] > 0.0
    assert wear["flights"] == 8 and wear["sd"] > 0.0
    assert "fleet demo: calibration: 8/8 reference flights replayed with the degradations overlaid" in printed
    assert "fleet demo: detector calibrated on " in printed


def test_healthy_flights_rarely_go_degraded_where_the_shipped_detector_fails(demo: tuple[Path, str]) -> None:
    root, printed = demo
    wearing = set(json.loads((root / "truth.json").read_text())["degrading"])
    fleet = yaml.safe_load((root / "FLEET.yaml").read_text())
    wear_only = {"wear": yaml.safe_load((root / "detector.yaml").read_text())["wear"]}
    (root / "shipped_detector.yaml").write_text(yaml.safe_dump(wear_only))
    fleet["defaults"]["detector"] = "shipped_detector.yaml"
    (root / "FLEET_shipped.yaml").write_text(yaml.safe_dump(fleet))
    run_fleet(root / "FLEET_shipped.yaml", root / "out_shipped", workers=2, say=lambda _: None)
    calibrated, healthy = _healthy_degraded(root / "out", wearing)
    shipped, _ = _healthy_degraded(root / "out_shipped", wearing)
    assert healthy == _FLIGHTS - _FLIGHTS // _ENGINES
    assert calibrated <= healthy // 4, f"{calibrated} of {healthy} healthy flights DEGRADED (shipped: {shipped})"
    assert shipped >= 5 and shipped >= 2 * calibrated, f"the control: {shipped} of {healthy} (calibrated {calibrated})"
    engines = pq.read_table(root / "out" / "engines.parquet").to_pylist()
    assert {e["serial"] for e in engines if e["alert"]} == wearing
    assert f"ALERT #1 {next(iter(wearing))}:" in printed
