"""identify --type and --base TYPE.yaml: a type model over two airframes and the adaptation to a third.

Synthetic airframes: flights of throttle steps whose CHT comes from one model (the paper's) with each
airframe's heat map scaled by its own known factor, sampled at 1 Hz with noise and a 1 degC quantiser.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ecu_monitor.errors import ConfigError, UserInputError
from ecu_monitor.flightlog import FlightLog, log_airframe
from ecu_monitor.identify import PsoSettings
from ecu_monitor.identify.type_model import (
    HEAT_VALUE_SIGMAS,
    adapt,
    adapt_choosing,
    airframe_model,
    first_minutes,
    fit_type,
)
from ecu_monitor.model import (
    AirframeTerms,
    InputSeries,
    airframe_warning,
    coefficients,
    load_model,
    paper_table_a1,
    save_model,
)
from ecu_monitor.model.compiled import simulate_compiled

SETTINGS = PsoSettings(particles=12, iterations=10, dt_s=1.0, polish_evaluations=40)


def _flight(seed: int, heat_scale: float | np.ndarray, duration_s: int = 2400) -> FlightLog:
    """Throttle steps in a random order (rpm following), CHT of the paper's model with the heat map times
    ``heat_scale`` (a number, or one per heat-map value), at 1 Hz with 0.3 degC noise and a 1 degC quantiser."""
    rng = np.random.default_rng(seed)
    levels = rng.permutation([25.0, 40.0, 55.0, 70.0, 85.0, 100.0, 35.0, 60.0])
    t = np.arange(0.0, duration_s + 0.5, 1.0)
    throttle = levels[np.minimum((t // (duration_s / levels.size)).astype(int), levels.size - 1)]
    rpm = 2000.0 + 70.0 * throttle
    altitude = 300.0 + 0.2 * t
    airspeed = np.full_like(t, 23.0)
    oat = 15.0 - 0.0065 * altitude
    truth = paper_table_a1()
    truth = truth.replace(heat_map=truth.heat_map.with_values(truth.heat_map.values_array() * heat_scale))
    fine = InputSeries(*(np.repeat(v, 5) for v in (throttle, rpm, altitude, airspeed, oat)))  # held over 0.2 s steps
    probe = simulate_compiled(fine, coefficients(truth), 0.2, 60.0, record_every=5).probe_c
    measured = np.round(probe + 0.3 * rng.standard_normal(probe.size))
    columns = {"time_s": t, "throttle_pct": throttle, "rpm": rpm, "altitude_m": altitude, "airspeed_mps": airspeed,
               "oat_c": oat, "cht_c": measured, "fuel_flow_lph": 0.4 * throttle}  # fmt: skip
    return FlightLog(columns, source=f"airframe-{np.mean(heat_scale):g}-{seed}")


def _scale(terms: AirframeTerms) -> float:
    return 1.0 if terms.heat_scale is None else terms.heat_scale


@pytest.fixture(scope="module")
def type_fit():
    """A type model over airframe A (heat scale 1, two flights) and airframe B (1.15, one flight)."""
    flights = [_flight(1, 1.0), _flight(2, 1.0), _flight(3, 1.15)]
    return fit_type(
        flights, ["A", "A", "B"], engine_type="test", base=paper_table_a1(), heat_axes=("throttle_pct", "rpm"),
        grid=None, settings=SETTINGS, free=("c_w", "heat_map"), candidates=("heat_scale",),
    )  # fmt: skip


def test_the_type_model_recovers_each_airframes_heat_scale(type_fit):
    terms = {t.id: t for t in type_fit.params.airframes}
    assert set(terms) == {"A", "B"} and type_fit.params.engine_type == "test"
    assert terms["B"].heat_scale is not None  # B's data show it needs its own scale
    assert _scale(terms["B"]) / _scale(terms["A"]) == pytest.approx(1.15, rel=0.03)
    for fit in type_fit.airframes.values():  # each airframe's model fits its flights far better than the type
        assert max(e.rms_c for e in fit.errors) < 2.0
    assert type_fit.airframes["B"].as_type[0].rms_c > 2.0 * type_fit.airframes["B"].errors[0].rms_c


def test_base_adapts_a_new_airframe_from_its_first_20_minutes(type_fit):
    terms = {t.id: t for t in type_fit.params.airframes}
    new = _flight(4, 0.9, duration_s=3600)  # airframe C: heat scale 0.9
    result = adapt(type_fit.params, [first_minutes(new, 20)], "C", SETTINGS, candidates=("heat_scale",))
    assert result.elapsed_s < 60.0
    assert result.fit.terms.heat_scale is not None
    assert _scale(result.fit.terms) / _scale(terms["A"]) == pytest.approx(0.9, rel=0.04)
    later = new.select(1200.0, 3600.0)  # the rest of the flight, never seen by the adaptation
    from ecu_monitor.identify import flight_errors

    adapted = flight_errors(result.params, later).rms_c
    as_type = flight_errors(type_fit.params.replace(engine_type="", airframes=()), later).rms_c
    assert adapted < 0.5 * as_type
    assert result.params.airframes == (result.fit.terms,) and not result.params.engine_type


def test_base_refits_the_heat_map_where_the_halves_show_the_head_differs(type_fit):
    """Airframe C runs 20 % hotter at high power only (the heat map's top two throttle rows): no one scale
    carries that; its flight's halves choose to refit the heat-map values it visits, which predicts
    another flight of C far better than its terms alone."""
    shape = paper_table_a1().heat_map.shape
    hotter = np.where(np.arange(shape[0])[:, None] >= 3, 1.2, 1.0) * np.ones(shape)
    result = adapt(type_fit.params, [_flight(8, hotter, 4800)], "C", SETTINGS, candidates=("heat_scale",))
    assert result.fit.heat_values > 0 and result.fit.heat_map_prior > 0.0
    assert set(result.fit.heat_map_held_out) == set(HEAT_VALUE_SIGMAS)
    from ecu_monitor.identify import flight_errors

    shared = type_fit.params.replace(engine_type="", airframes=())
    terms_only = airframe_model(shared, result.fit.terms)
    later = _flight(9, hotter, 2400)  # another flight of C, never seen by the adaptation
    assert flight_errors(result.params, later).rms_c < 0.7 * flight_errors(terms_only, later).rms_c


def _misshapen(type_params):
    """The type model with its heat map reversed along throttle (the heat falling as the throttle opens):
    a form no heat scale, cooling scale or probe lag can bring back."""
    values = type_params.heat_map.values_array()
    return type_params.replace(heat_map=type_params.heat_map.with_values(values[::-1, :].copy()))


def test_the_new_airframes_halves_choose_between_type_models(type_fit):
    new = first_minutes(_flight(4, 0.9, duration_s=3600), 40)  # airframe C: halves of 20 min each
    wrong = _misshapen(type_fit.params)
    for offered, right in (([type_fit.params, wrong], 0), ([wrong, type_fit.params], 1)):
        result = adapt_choosing(offered, [new], "C", SETTINGS, candidates=("heat_scale",))
        assert result.chosen == right
        assert result.held_out_by_type[right] < 0.5 * result.held_out_by_type[1 - right]
        alone = adapt(type_fit.params, [new], "C", SETTINGS, candidates=("heat_scale",))
        assert result.params == alone.params and result.fit.terms == alone.fit.terms
    nearly_the_same = type_fit.params.replace(c_w=type_fit.params.c_w * 0.999)  # within FORM_MIN_GAIN: no switch
    result = adapt_choosing([type_fit.params, nearly_the_same], [new], "C", SETTINGS, candidates=("heat_scale",))
    assert result.chosen == 0
    short = first_minutes(new, 8)  # too short to halve: no choice, the first model offered
    result = adapt_choosing([wrong, type_fit.params], [short], "C", SETTINGS, candidates=("heat_scale",))
    assert result.chosen == 0 and all(np.isnan(result.held_out_by_type))


def test_airframe_model_applies_the_terms_and_round_trips(tmp_path: Path):
    terms = AirframeTerms("X", heat_scale=1.1, cooling_scale=0.8, probe_lag_s=20.0, head_offset_c=-3.5)
    type_params = paper_table_a1().replace(engine_type="c172", airframes=(terms,))
    path = tmp_path / "type.yaml"
    save_model(type_params, path)
    assert load_model(path) == type_params
    model = airframe_model(type_params, type_params.airframes[0])
    assert np.allclose(model.heat_map.values_array(), 1.1 * type_params.heat_map.values_array())
    assert model.r_ce == pytest.approx(type_params.r_ce / 0.8)  # 20 % less cooling; the head's offset a record only
    assert model.effects.sensor_lag is not None and model.effects.sensor_lag.time_constant_s == 20.0
    (tmp_path / "bad.yaml").write_text(path.read_text().replace("heat_scale: 1.1", "heat_scale: 9.0"))
    with pytest.raises(ConfigError, match="heat_scale"):
        load_model(tmp_path / "bad.yaml")


def test_a_model_of_another_airframe_is_named_in_one_line(tmp_path: Path):
    log = tmp_path / "g1000.csv"
    log.write_text(
        '#airframe_info, log_version="1.00", airframe_name="Cessna 172S", system_id="25BA2E6F4", mode=NORMAL\n'
    )
    assert log_airframe(log) == "25BA2E6F4"
    (tmp_path / "plain.csv").write_text("time_s,cht_c\n0,1\n")
    assert log_airframe(tmp_path / "plain.csv") is None
    model = paper_table_a1().replace(airframes=(AirframeTerms("2E90B4BED"),))
    line = airframe_warning(model, log_airframe(log), "n550nd.yaml", log.name)
    assert line is not None and "25BA2E6F4" in line and "2E90B4BED" in line and "\n" not in line
    assert airframe_warning(model, "2E90B4BED", "n550nd.yaml", log.name) is None
    assert airframe_warning(paper_table_a1(), "25BA2E6F4", "paper", log.name) is None  # made for no airframe
    made_for = (AirframeTerms("2E90B4BED", head_offset_c=4.9), AirframeTerms("24B6FD7AC", head_offset_c=-12.0))
    type_line = airframe_warning(model.replace(engine_type="c172", airframes=made_for), "25BA2E6F4", "c172.yaml", "f")
    assert type_line is not None and "-12.0 to +4.9 degC" in type_line and "--first-minutes 20" in type_line
    assert "\n" not in type_line


def test_fleet_options_fail_before_the_work(tmp_path: Path):
    from ecu_monitor.commands.identify_type import airframe_names, flight_airframes

    with pytest.raises(UserInputError, match="NAME=GLOB"):
        airframe_names(["N550ND"])
    assert flight_airframes(["a/f1.csv", "b/f2.csv"], ["N1=*f1.csv", "N2=b/*"]) == ["N1", "N2"]
    with pytest.raises(UserInputError, match="names no airframe"):
        flight_airframes([str(tmp_path / "x.csv")], [])


def test_identify_type_and_base_on_the_command_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    from ecu_monitor.cli import main
    from ecu_monitor.flightlog import write_csv

    paths = []
    for seed, scale in ((5, 1.0), (6, 1.15), (7, 0.9)):
        path = tmp_path / f"f{seed}.csv"
        write_csv(_flight(seed, scale, duration_s=1500), path)
        paths.append(str(path))
    quick = ["--particles", "8", "--iterations", "3", "--dt", "2", "--free", "c_w,heat_map", "--quiet"]
    out = tmp_path / "type.yaml"
    assert main(["identify", "--type", *paths[:2], "--airframe", "A=*f5.csv", "--airframe", "B=*f6.csv",
                 "--out", str(out), *quick]) == 0  # fmt: skip
    type_params = load_model(out)
    assert type_params.engine_type == "type" and [a.id for a in type_params.airframes] == ["A", "B"]
    offsets = [a.head_offset_c for a in type_params.airframes]  # B's heat map 15 % above A's: its head hotter
    assert offsets[0] is not None and offsets[1] is not None and offsets[1] > 5.0 and offsets[0] < -5.0
    printed = capsys.readouterr().out
    assert "airframe B:" in printed
    b_line = printed.split("airframe B:")[1]  # B (heat scale 1.15) against A at the same inputs: hotter
    assert "at the steady operating points it shares with the others" in b_line and "its head +" in b_line
    assert "a new airframe with no flight of its own can be as far from the type as" in b_line
    adapted = tmp_path / "c.yaml"
    args = ["identify", "--base", str(out), paths[2], "--airframe", "C=*", "--first-minutes", "20"]
    assert main([*args, "--out", str(adapted), *quick]) == 0
    assert "by prior width: 0 % " in capsys.readouterr().out  # the heat-map refit's choice, printed
    model = load_model(adapted)
    assert [a.id for a in model.airframes] == ["C"] and not model.engine_type
    assert main([*args, "--or-base", str(out), "--out", str(adapted), *quick]) == 0  # the same form twice
    assert "by type model:" in capsys.readouterr().out
    assert main([*args, "--or-base", str(adapted), "--out", str(tmp_path / "y.yaml"), *quick]) == 2
    assert "not a type model" in capsys.readouterr().err
    assert main(["identify", paths[2], "--first-minutes", "20", "--out", str(tmp_path / "x.yaml"), *quick]) == 2
    assert "--first-minutes" in capsys.readouterr().err


def test_replay_warns_when_the_model_was_made_for_another_airframe(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    """A G1000 export of airframe 25BA2E6F4 replayed with a model made for 2E90B4BED: one warning line."""
    from ecu_monitor.cli import main
    from ecu_monitor.model import HeatMap

    lines = [
        '#airframe_info, log_version="1.01", airframe_name="Cessna 172S", system_id="25BA2E6F4"',
        "#yyy-mm-dd, hh:mm:ss, hh:mm, ft, deg C, kt, gph, rpm, deg F, deg F, deg F, deg F, deg F, fpm",
        "  Lcl Date, Lcl Time, UTCOfst, AltB, OAT, IAS, E1 FFlow, E1 RPM, E1 CHT1, E1 CHT2, E1 EGT1, E1 EGT2,"
        " E1 OilT, VSpd",
    ]
    for k in range(300):
        lines.append(f"2023-04-24, 10:{k // 60:02d}:{k % 60:02d}, +08:00, 1000, 15.0, 60.0, 10.0, 2400, 300, 320,"
                     " 1300, 1400, 180, 0")  # fmt: skip
    log = tmp_path / "g1000.csv"
    log.write_text("\n".join(lines) + "\n")
    heat = HeatMap("fuel_flow_lph", "rpm", (0.0, 60.0), (0.0, 3000.0), ((0.0, 0.0), (900.0, 900.0)))
    model = tmp_path / "n550nd.yaml"
    save_model(paper_table_a1().replace(heat_map=heat, airframes=(AirframeTerms("2E90B4BED"),)), model)
    assert main(["replay", str(log), "--model", str(model), "--out", str(tmp_path / "h.csv")]) == 0
    warned = [line for line in capsys.readouterr().out.splitlines() if "airframe 25BA2E6F4" in line]
    assert len(warned) == 1 and "2E90B4BED" in warned[0] and warned[0].startswith("warning:")
    made_for = (AirframeTerms("2E90B4BED", head_offset_c=4.9), AirframeTerms("24B6FD7AC", head_offset_c=-12.0))
    save_model(load_model(model).replace(engine_type="c172", airframes=made_for), tmp_path / "c172.yaml")
    assert main(["replay", str(log), "--model", str(tmp_path / "c172.yaml"), "--out", str(tmp_path / "h.csv")]) == 0
    warned = [line for line in capsys.readouterr().out.splitlines() if "airframe 25BA2E6F4" in line]
    assert len(warned) == 1 and "-12.0 to +4.9 degC" in warned[0] and "--first-minutes 20" in warned[0]
