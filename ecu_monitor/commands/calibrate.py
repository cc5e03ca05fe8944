"""``ecu-monitor calibrate FLIGHT [FLIGHT ...] [--config C] [--model M] [--rate 1] [--baseline-s S] [--out D.yaml]``.

Calibrates the detector on your own NOMINAL flights (healthy engine). First its adaptive baseline is
chosen, length among --candidates (default 120,300,600,1200 s) x delay 0 or 60 s x learning always
or frozen while a change is suspected (statistic above 0), by leave-one-flight-out:
for each candidate and each flight held out, h is calibrated on the other flights, the held-out flight
must raise no alarm, and a degradation overlaid on its recorded CHT (k (CHT - OAT)(1 - exp(-t/240 s)),
k = 0.2 and 0.1, three onsets over its airborne part) must be detected within 300 s (k = 0.2) and
600 s (k = 0.1). Chosen: the fewest false alarms (none when a candidate has none; else a warning),
then the most detections in time, then the most for k = 0.1, then the shorter baseline, then the
longer delay, then no freeze. A table per
candidate is printed. With fewer than 3 flights with at least 15 min airborne after the warm-up (or
too few hours per fold), the config's baseline is kept and the output says so; --baseline-s S skips
the choice. Then the threshold h: each flight is
replayed through the service's pipeline (as ``ecu-monitor replay``: same estimator, symptom, warm-up
and baseline), the CUSUM statistic is run without alarms, and a Gumbel law fitted to its hourly
maxima gives h for --rate false alarms per 100 flight hours (never below 1.1 x the largest statistic
seen, landings included, when the flights hold fewer hours than one expected alarm). Needs at least 2
whole hours of statistic (after each flight's warm-up).

Prints the table per candidate and the choice; per flight: hours, largest statistic, alarms the
current threshold would raise; then the new threshold. Writes --out: a ``detector:`` YAML fragment
to merge into the service config, or with --write-config a full copy of the config with the
threshold and baseline settings replaced (the input config is never overwritten). --plot draws the statistic
of each flight with both thresholds.

A config that monitors every cylinder (cht1_c .. chtN_c): each cylinder is calibrated as above on its own
CHT column of the same flights and its own model (--models, one per cylinder; default the config's
cylinders.models, else its model); --out gets ``cylinders: detectors:``, one detector per cylinder.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ecu_monitor.commands.names import CALIBRATE_RATE_PER_100H
from ecu_monitor.compile_cache import announce_compiles
from ecu_monitor.errors import ConfigError, FlightLogError, ParameterError
from ecu_monitor.shipped import DEFAULT_CONFIG, resolve_file
from ecu_monitor.userfiles import check_output_file, save_figure, write_output_bytes

__all__ = ["DEFAULT_OUT", "add_subparser", "candidate_table"]

#: The fragment written when --out is not given (in the current folder).
DEFAULT_OUT = "detector.yaml"


def add_subparser(subparsers: Any) -> None:
    """Register the ``calibrate`` subcommand."""
    parser = subparsers.add_parser(
        "calibrate",
        help="calibrate the detector threshold on your own nominal flights (per cylinder) -> detector.yaml",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument("flights", nargs="+", metavar="FLIGHT", help="nominal flight: canonical .csv or CAN log")
    parser.add_argument(
        "--config", metavar="CONFIG.yaml", help="service config (default: the shipped example.yaml, as replay)"
    )
    parser.add_argument("--model", metavar="MODEL.yaml", help="thermal model (default: the config's model)")
    parser.add_argument(
        "--models",
        nargs="+",
        metavar="MODEL.yaml",
        help="one model per cylinder, in cylinder order, for a config that monitors every cylinder"
        " (default: its cylinders.models, else its model)",
    )
    parser.add_argument(
        "--rate",
        type=float,
        default=CALIBRATE_RATE_PER_100H,
        help=f"false alarms per 100 flight hours to calibrate for (default {CALIBRATE_RATE_PER_100H:g})",
    )
    parser.add_argument(
        "--baseline-s",
        type=float,
        metavar="S",
        help="use this adaptive-baseline length, s, instead of choosing it by cross-validation",
    )
    parser.add_argument(
        "--candidates",
        metavar="S,S,...",
        help="baseline lengths, s, to cross-validate (default: calibration.BASELINE_CANDIDATES_S, 120,300,600,1200)",
    )
    parser.add_argument("--out", metavar="FILE.yaml", help=f"output YAML (default: ./{DEFAULT_OUT})")
    parser.add_argument(
        "--write-config",
        action="store_true",
        help="write a full copy of the config with the new threshold to --out (required then) instead of a fragment",
    )
    parser.add_argument("--plot", metavar="P.png", help="plot the statistic of each flight with both thresholds")
    parser.add_argument(
        "--cross",
        action="store_true",
        help="write the cross-cylinder detectors calibrated here (config with cylinders.cross_detector); without it"
        " they are calibrated and checked but written off (null): on N550ND a flight held out alarmed"
        " (docs/results/cylinders.md)",
    )
    parser.set_defaults(func=announce_compiles(_run))  # a first run says it compiles


def _run(args: argparse.Namespace) -> int:
    config_path = resolve_file(args.config, "config") if args.config else DEFAULT_CONFIG
    out = _check(args, config_path)
    from ecu_monitor.config import load_config
    from ecu_monitor.flightlog import require_distinct
    from ecu_monitor.model import load_model
    from ecu_monitor.offline.calibration import BASELINE_CANDIDATES_S

    candidates = _candidates(args.candidates) if args.candidates else list(BASELINE_CANDIDATES_S)
    config = load_config(config_path)
    if args.baseline_s is not None:
        _with_baseline(config.detector, args.baseline_s)  # bad value: one line before any work
    if args.model and len(config.cylinder_inputs) > 1:
        raise ParameterError("--model: the config monitors every cylinder; give one model per cylinder with --models")
    params = load_model(args.model) if args.model else config.load_params()
    require_distinct(args.flights, "calibrate")
    for flight in args.flights:
        if not Path(flight).is_file():
            raise FlightLogError(f"{flight}: {'not a file' if Path(flight).exists() else 'no such file'}")

    from ecu_monitor.offline.calibration import config_copy_yaml, detector_fragment_yaml, model_fingerprint

    sources = [str(Path(p).resolve()) for p in args.flights]
    if len(config.cylinder_inputs) > 1:
        return _run_cylinders(args, config, config_path, out, candidates, sources)
    if args.models:
        raise ParameterError("--models: the config monitors one CHT channel (cht_c); give its model with --model")
    result, flights, wear = _calibrate_channel(args, config, params, candidates)
    if args.write_config:
        text = config_copy_yaml(
            config_path, out, result, args.rate, sources, model_fingerprint(params), args.model, wear=wear
        )
    else:
        text = detector_fragment_yaml(
            result, config.detector_symptom, args.rate, sources, model_fingerprint(params), wear=wear
        )
    _write(out, text)
    print(f"wrote {out} ({'full config' if args.write_config else 'detector fragment'})")
    if args.plot:
        _plot(flights, config.detector.threshold, result.calibration.threshold, Path(args.plot))
        print(f"wrote {args.plot}")
    return 0


def _run_cylinders(
    args: argparse.Namespace, config: Any, config_path: Path, out: Path, candidates: list[float], sources: list[str]
) -> int:
    """Every cylinder of an engine monitored per cylinder calibrated on its own CHT (``cht<n>_c``) and
    model, the same procedure as one channel; writes ``cylinders.detectors``."""
    from ecu_monitor.model import load_model
    from ecu_monitor.offline.calibration import (
        config_copy_yaml,
        cylinder_config,
        cylinders_fragment_yaml,
        model_fingerprint,
    )

    count = len(config.cylinder_inputs)
    if args.models and len(args.models) != count:
        raise ParameterError(f"--models: the config monitors {count} cylinders, got {len(args.models)} models")
    if args.plot:
        raise ParameterError("--plot: draws one channel; not with a config that monitors every cylinder")
    models = [str(resolve_file(m, "model")) for m in args.models] if args.models else [None] * count
    views = [cylinder_config(config, n, m) for n, m in enumerate(models, start=1)]
    params = [load_model(m) if m else view.load_params() for m, view in zip(models, views, strict=True)]
    results = []
    for number, (view, model) in enumerate(zip(views, params, strict=True), start=1):
        print(f"== cylinder {number} of {count} ({config.cylinder_inputs[number - 1]}) ==")
        results.append(_calibrate_channel(args, view, model, candidates, cylinder=number)[0])
    fingerprints = [model_fingerprint(p) for p in params]
    cross = _calibrate_cross(args, config, params) if config.cross_detectors else []
    if args.write_config:
        text = config_copy_yaml(
            config_path,
            out,
            results[0],
            args.rate,
            sources,
            fingerprints[0],
            cylinders=list(zip(results, fingerprints, strict=True)),
            cylinder_models=list(args.models or ()),
            cross=list(zip(cross, fingerprints, strict=True)) if cross else [],
        )
    else:
        text = cylinders_fragment_yaml(results, args.rate, sources, fingerprints, cross)
    _write(out, text)
    what = "full config" if args.write_config else "cylinders.detectors fragment"
    print(f"wrote {out} ({what}: one detector per cylinder)")
    return 0


def _calibrate_cross(args: argparse.Namespace, config: Any, params: list[Any]) -> list[Any]:
    """The cross-cylinder detectors (cylinders.cross_detector): one replay of each flight with every
    cylinder, each cylinder's threshold from its cross-cylinder statistic, kept only where no held-out
    flight alarms (offline/calibration_cross.py); prints the per-flight maxima and that check."""
    from ecu_monitor.offline.calibration_cross import calibrate_cross, cross_feeds, leave_one_out

    print("== cross-cylinder detectors (each cylinder's symptom minus the median of the others') ==")
    feeds = cross_feeds(args.flights, config, params)
    checks = leave_one_out(feeds, config, args.rate)
    results = calibrate_cross(feeds, config, args.rate, checks)
    print(f"{'cylinder':>8}  {'h':>8}  per flight: max statistic / h without it / alarms when held out")
    for number, (result, check, flights) in enumerate(zip(results, checks, feeds, strict=True), start=1):
        settings = config.cross_detector(number)
        if settings is None:
            print(f"{number:8d}  {'-':>8}  (none in the config)")
            continue
        cells = [
            f"{f.name} {f.statistic_for(settings).max_statistic:.3f} / {h:.3f} / {a}"
            for f, h, a in zip(flights, check.thresholds, check.false_alarms, strict=True)
        ]
        h_text = f"{result.calibration.threshold:8.3f}" if result is not None else f"{'off':>8}"
        print(f"{number:8d}  {h_text}  " + "; ".join(cells))
    off = [n for n, r in enumerate(results, start=1) if r is None and config.cross_detector(n) is not None]
    if off:
        print(
            f"cylinder(s) {', '.join(map(str, off))}: a held-out flight alarmed; no cross-cylinder detector written"
            " there (null), its own-symptom detector keeps watching it"
        )
    if not args.cross:
        print(
            "cross-cylinder detectors written off (null) on every cylinder: give --cross to write the thresholds above"
            " (on N550ND a flight held out from the calibration alarmed: docs/results/cylinders.md)"
        )
        return [None] * len(results)
    return results


def _calibrate_channel(
    args: argparse.Namespace, config: Any, params: Any, candidates: list[float], cylinder: int | None = None
) -> tuple[Any, list[Any], Any]:
    """One CHT channel: the baseline choice and the threshold on the flights (offline/calibration_channel.py;
    prints the tables as it goes), and the nominal wear reference of the across-flight detector (None: fewer
    than 3 flights with a wear index); ``cylinder``: the flights' ``cht<cylinder>_c`` is the channel (``config``
    maps it as ``cht_c``)."""
    from ecu_monitor.offline.calibration import SettingsChoice
    from ecu_monitor.offline.calibration_channel import calibrate_channel, replay_and_choose

    given = None
    if args.baseline_s is not None:
        settings = _with_baseline(config.detector, args.baseline_s)
        given = SettingsChoice(settings, f"baseline_s {args.baseline_s:g} s given by --baseline-s", (), False)
    replayed = replay_and_choose(args.flights, config, params, args.rate, candidates, given=given, cylinder=cylinder,
                                 replay_map=_replay_with_progress_bar)  # fmt: skip
    choice = replayed.choice
    if given is None:
        for line in candidate_table(choice):
            print(line)
        print(f"chosen: {choice.reason}")
    else:
        print(f"detector settings: {choice.reason} (no cross-validation)")
    flights = list(replayed.statistics)
    for line in _table(flights, config.detector.threshold, choice.settings.block_s):
        print(line)
    calibrated = calibrate_channel(replayed, args.rate)
    _print_reference(calibrated, len(replayed.feeds))
    result = calibrated.result
    c = result.calibration
    print(
        f"threshold h = {c.threshold:.3f} for {args.rate:g} false alarm(s) per 100 h"
        f" (current {config.detector.threshold:g}); method: {result.method}"
    )
    print(
        f"  Gumbel quantile {c.gumbel_threshold:.3f} (location {c.gumbel_location:.3f}, scale {c.gumbel_scale:.3f}),"
        f" empirical bound {c.empirical_max:.3f}, {c.hours} whole hours of statistic"
    )
    if c.hours * args.rate / 100.0 < 1.0:
        print(
            f"  {c.hours} whole hours is fewer than the {100.0 / args.rate:g} h of one expected alarm: the rate cannot"
            f" be shown on these flights; h is kept at or above the empirical bound, 1.1 x the largest statistic"
            f" seen ({c.empirical_max:.3f})"
        )
    wear = replayed.wear
    shown = ", ".join("-" if i is None else f"{100.0 * i:+.2f} %" for i in replayed.wear_indices)
    if wear is None:
        print(f"wear index per flight: {shown}; no wear reference (fewer than 3 flights with one)")
    else:
        print(f"wear index per flight: {shown}; reference {100.0 * wear.mean:+.2f} % sd {100.0 * wear.sd:.2f} %"
              f" over {wear.flights} flights (the across-flight detector's, wear.reference)")  # fmt: skip
    return result, flights, wear


def _replay_with_progress_bar(replay: Any, flights: Any, what: str) -> list[Any]:
    """The flights replayed in turn under a progress bar on stderr named ``what`` (a calibration ReplayMap)."""
    from tqdm import tqdm

    return [replay(f) for f in tqdm(flights, desc=what, unit="flight", file=sys.stderr, leave=False, disable=None)]


def _print_reference(calibrated: Any, flight_count: int) -> None:
    """The engine's reference learned per region (per flight, mean, spread) and its test's h, or why none."""
    from ecu_monitor.estimation.detection import NOMINAL_SPREAD_Z
    from ecu_monitor.estimation.regions import REGION_NAMES

    ref = calibrated.reference
    if ref is None:
        print(f"engine reference: none ({calibrated.no_reference}); the detector tests against its in-flight"
              " baseline only")  # fmt: skip
        return
    print(f"engine reference (symptom per region over {flight_count} nominal flights; level = mean + "
          f"{NOMINAL_SPREAD_Z:g} x spread across flights):")  # fmt: skip
    print("  region         " + "".join(f"{n[:12]:>13}" for n in ref.flights) + "         mean       spread")
    for r, name in enumerate(REGION_NAMES):
        cells = "".join(f"{v:13.4f}" for v in ref.flight_means[:, r])
        print(f"  {name:<14} {cells} {ref.mean[r]:12.4f} {ref.spread[r]:12.4f}")
    c = ref.calibration
    worst = ", ".join(f"{n} {m:.2f}" for n, m in zip(ref.flights, ref.held_out_max, strict=True))
    print(f"reference test h = {c.threshold:.3f} ({c.hours} whole hours, each flight against the others' reference;"
          f" largest statistic per flight: {worst})")  # fmt: skip


def _write(out: Path, text: str) -> None:
    write_output_bytes(out, text.encode("utf-8"), ConfigError)


def _with_baseline(settings: Any, baseline_s: float) -> Any:
    """The settings with another baseline length; ParameterError naming --baseline-s when invalid."""
    import dataclasses

    try:
        return dataclasses.replace(settings, baseline_s=baseline_s)
    except ConfigError as exc:
        raise ParameterError(f"--baseline-s: {exc}") from None


def _candidates(text: str) -> list[float]:
    """Parse --candidates (comma-separated seconds, each 0 or >= the block)."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ParameterError(f"--candidates: expected comma-separated seconds, got {text!r}") from None
    if not values or any(not (v >= 0.0 and v < float("inf")) for v in values):
        raise ParameterError(f"--candidates: expected comma-separated seconds >= 0, got {text!r}")
    return values


def candidate_table(choice: Any) -> list[str]:
    """Per candidate baseline: h per held-out flight, false alarms, detections within target, median delays."""
    if not choice.scores:
        return []
    first = choice.scores[0]
    lines = [
        f"cross-validation, leave one flight out over {len(first.flights)} flights"
        f" ({first.total(0.2)} overlays per gain): h calibrated on the others, held-out flight replayed nominal"
        " and with k = 0.2 / 0.1 overlaid",
        f"{'baseline_s':>10}  {'delay_s':>7}  {'freeze':>6}  {'h per held-out flight':<28}  {'false alarms':>12}"
        f"  {'k=0.2 <=300 s':>18}  {'k=0.1 <=600 s':>18}",
    ]
    for s in choice.scores:
        hs = " ".join(f"{h:.1f}" for h in s.thresholds)
        cells = [f"{s.hits(g)}/{s.total(g)} med {s.median_delay(g):.0f} s" for g in (0.2, 0.1)]
        mark = "  <- chosen" if choice.cross_validated and s.settings == choice.settings else ""
        lines.append(
            f"{s.settings.baseline_s:10g}  {s.settings.baseline_delay_s:7g}"
            f"  {'yes' if s.settings.baseline_freeze else 'no':>6}  {hs:<28}  {s.false_alarms:12d}"
            f"  {cells[0]:>18}  {cells[1]:>18}{mark}"
        )
    return lines


def _check(args: argparse.Namespace, config_path: Path) -> Path:
    """Validate the options before any work; returns the output path."""
    if not 0.0 < args.rate < 100.0:  # also rejects nan
        raise ParameterError(f"--rate: expected false alarms per 100 h in (0, 100), got {args.rate!r}")
    if args.write_config and not args.out:
        raise ParameterError(
            "--write-config: name the new config file with --out (the input config is never overwritten)"
        )
    out = Path(args.out) if args.out else Path(DEFAULT_OUT)
    if args.write_config and out.resolve() == config_path.resolve():
        raise ParameterError(f"--out: {out} is the input config; write the copy to a new file")
    check_output_file(out, "--out", ParameterError)
    if args.plot:
        check_output_file(args.plot, "--plot", ParameterError)
    return out


def _table(flights: list[Any], threshold: float, block_s: float) -> list[str]:
    """Per flight: name, hours, whole hours of statistic, max statistic, alarms at the current threshold."""
    width = max([len("flight"), *(len(f.name) for f in flights)])
    head = f"alarms at h={threshold:g}"
    lines = [f"{'flight':<{width}}  {'hours':>6}  {'whole h':>7}  {'max stat':>8}  {head:>15}  first alarm"]
    for f in flights:
        first = f"t={f.alarm_times_s[0] - f.start_s:.1f} s" if f.alarm_times_s.size else "-"
        lines.append(
            f"{f.name:<{width}}  {f.hours:6.2f}  {f.whole_hours(block_s):7d}  {f.max_statistic:8.3f}"
            f"  {f.alarm_times_s.size:15d}  {first}"
        )
    total_alarms = sum(f.alarm_times_s.size for f in flights)
    hours = sum(f.hours for f in flights)
    whole = sum(f.whole_hours(block_s) for f in flights)
    peak = max(f.max_statistic for f in flights)
    lines.append(f"{'total':<{width}}  {hours:6.2f}  {whole:7d}  {peak:8.3f}  {total_alarms:15d}")
    return lines


def _plot(flights: list[Any], current: float, calibrated: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 5))
    for f in flights:
        for i, (ends, stat) in enumerate(f.paths):
            ax.plot((ends - f.start_s) / 60.0, stat, lw=0.8, label=f.name if i == 0 else None)
    ax.axhline(current, color="tab:red", ls="--", lw=1.2, label=f"current h = {current:g}")
    ax.axhline(calibrated, color="black", ls="-", lw=1.2, label=f"calibrated h = {calibrated:.2f}")
    ax.set_xlabel("time since the start of the flight (min)")
    ax.set_ylabel("CUSUM statistic (degC)")
    ax.set_title("detector statistic on the nominal flights (no alarm, no restart)")
    peak = max([current, calibrated, *(f.max_statistic for f in flights)])
    ax.set_ylim(0.0, 1.35 * peak)  # room for the legend above the lines
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=120, error=ParameterError)
    finally:
        plt.close(fig)
