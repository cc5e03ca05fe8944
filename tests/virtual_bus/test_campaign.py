"""virtual-ecu campaign: the per-flight degradation schedule, the flights' seeds and clocks, bad input."""

from __future__ import annotations

import pytest

from ecu_monitor.errors import ConfigError
from virtual_bus.campaign import WearSchedule, campaign_flights
from virtual_bus.cli import main


def test_schedule_grows_from_one_on_the_first_flight() -> None:
    schedule = WearSchedule.parse("gamma_q+0.005")
    assert [schedule.value(n) for n in (1, 2, 21)] == pytest.approx([1.0, 1.005, 1.1])
    assert schedule.degradation(1) == ()
    (event,) = schedule.degradation(21)
    assert (event.factor, event.start_s, event.ramp_s) == ("gamma_q", 0.0, 0.0)  # from engine start
    assert event.value == pytest.approx(1.1)
    assert WearSchedule.parse("gamma_d+0.01").degradation(3)[0].factor == "gamma_d"
    for bad in ("gamma_x+0.1", "gamma_q=1.1", "gamma_q+abc", "gamma_q+0.5"):
        with pytest.raises(ConfigError, match="--wear"):
            WearSchedule.parse(bad)


def test_each_flight_has_its_own_mission_a_day_apart() -> None:
    flights = list(campaign_flights(3, WearSchedule("gamma_q", 0.01), seed=4, duration_s=900.0, start_time_s=1e9))
    assert [f.number for f in flights] == [1, 2, 3]
    assert len({f.seed for f in flights}) == 3
    assert [f.start_time_s - 1e9 for f in flights] == [0.0, 86400.0, 172800.0]
    assert [f.degradation[0].value if f.degradation else 1.0 for f in flights] == pytest.approx([1.0, 1.01, 1.02])
    again = list(campaign_flights(3, WearSchedule("gamma_q", 0.01), seed=4, duration_s=900.0, start_time_s=1e9))
    assert [f.mission for f in again] == [f.mission for f in flights]  # deterministic for a seed


def test_bad_campaign_options_are_one_line_exit_2(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["campaign", "--flights", "2", "--out-dir", str(tmp_path), "--wear", "gamma_q*2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--wear" in err[0]
    assert main(["campaign", "--flights", "0", "--out-dir", str(tmp_path)]) == 2
