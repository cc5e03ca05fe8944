"""The daemon on a MAVLink link as a separate process, inside a network namespace (issue 27 item 5).

Each test makes its own namespace (tests/runtime/test_netns.py's :class:`Namespace`: loopback only) and runs every
process in it with ``ip netns exec``: the daemon (``ecu-monitor run`` on a copy of the shipped mavlink.yaml
with the namespace's ports), the virtual autopilot (``virtual-ecu run --protocol mavlink --realtime``, a
second process), and a reader of what the daemon sends: pymavlink in a third process, or MAVProxy, the
ground station users run, headless (``--non-interactive``, its console on stdout and its telemetry log in a
file). The link drops when the virtual autopilot is killed, and comes back when a new one starts. Needs root
and ``ip netns`` (skipped with the reason otherwise); the MAVProxy test also needs MAVProxy (the ``test``
extra installs it).
"""

from __future__ import annotations

import importlib.util
import json
import math
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import pytest
import yaml

from tests.helpers import REPO
from tests.helpers.netns import Lines, Namespace

pytestmark = [pytest.mark.netns, pytest.mark.process, pytest.mark.slow]

#: The service's ids (the shipped mavlink.yaml: the vehicle's system, MAV_COMP_ID_ONBOARD_COMPUTER).
SERVICE = [1, 191]
#: HEARTBEAT of the service: MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID; MAV_STATE_ACTIVE.
ONBOARD_CONTROLLER, AUTOPILOT_INVALID, STATE_ACTIVE = 18, 8, 4
#: MAV_SEVERITY of the texts checked here (docs/contracts.md section 4).
NOTICE, WARNING, INFO = 5, 4, 6
#: codes of Health_Status.DegradationState (ENG_ST, HEARTBEAT.custom_mode bits 0-3)
NOMINAL, INPUT_STALE = 0, 3
#: the first daemon of a run may compile the step (numba's cache cold): its first HEARTBEAT can take long
START_S = 120.0

_READER = textwrap.dedent(
    """
    import json, sys, time
    from pymavlink import mavutil
    link = mavutil.mavlink_connection(sys.argv[1])
    chunks = {}  # STATUSTEXT id -> the chunks so far (a chunk shorter than 50 is the last, as MAVProxy joins them)
    print("listening", flush=True)
    while True:
        msg = link.recv_match(blocking=True, timeout=0.5)
        if msg is None or msg.get_type() == "BAD_DATA":
            continue
        row = {"t": time.monotonic(), "src": [msg.get_srcSystem(), msg.get_srcComponent()],
               "type": msg.get_type(), "v2": msg.get_msgbuf()[0] == 0xFD}
        if row["type"] == "HEARTBEAT":
            row.update(kind=msg.type, autopilot=msg.autopilot, status=msg.system_status, mode=msg.custom_mode)
        elif row["type"] == "STATUSTEXT":
            parts = chunks.setdefault(msg.id, []) if msg.id else []
            parts.append(msg.text)
            if len(msg.text) == 50 and msg.id:
                continue
            chunks.pop(msg.id, None)
            row.update(severity=msg.severity, text="".join(parts), chunks=len(parts))
        elif row["type"] == "NAMED_VALUE_FLOAT":
            row.update(name=msg.name, value=msg.value)
        print(json.dumps(row), flush=True)
    """
)


def _config(ns: Namespace, port: int, output: str = "") -> Path:
    """The shipped mavlink.yaml listening on ``port`` in the namespace, state in its temp dir."""
    data = yaml.safe_load((REPO / "ecu_monitor" / "data" / "configs" / "mavlink.yaml").read_text(encoding="utf-8"))
    data["mavlink"]["connection"] = f"udpin:127.0.0.1:{port}"
    data["mavlink"]["output"] = output
    data["state_dir"] = str(ns.tmp / "state")
    path = ns.tmp / "mavlink.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def _daemon(ns: Namespace, config: Path) -> subprocess.Popen[str]:
    return ns.popen([sys.executable, "-m", "ecu_monitor.cli", "run", "--config", str(config)])


def _autopilot(ns: Namespace, port: int) -> subprocess.Popen[str]:
    """The virtual autopilot's stream (virtual-ecu run --protocol mavlink) to the daemon, in real time."""
    return ns.popen([sys.executable, "-m", "virtual_bus.cli", "run", "--protocol", "mavlink", "--mission", "short_hop",
                     "--connection", f"udpout:127.0.0.1:{port}", "--realtime"])  # fmt: skip


def _rows(reader: Lines, kind: str | None = None, since_s: float = 0.0) -> list[dict[str, Any]]:
    out = []
    for line in list(reader.lines):
        if not line.startswith("{"):
            continue
        row = json.loads(line)
        if row["t"] >= since_s and (kind is None or row["type"] == kind):
            out.append(row)
    return out


def _texts(reader: Lines, since_s: float = 0.0) -> list[dict[str, Any]]:
    return _rows(reader, "STATUSTEXT", since_s)


def _text_after(reader: Lines, fragment: str, since_s: float) -> dict[str, Any] | None:
    return next((row for row in _texts(reader, since_s) if fragment in row["text"]), None)


def contract_names(cylinders: int = 1) -> set[str]:
    """The NAMED_VALUE_FLOAT names docs/contracts.md lists, for an engine of ``cylinders`` CHT channels."""
    text = (REPO / "docs" / "contracts.md").read_text(encoding="utf-8")
    table = text.split("`NAMED_VALUE_FLOAT` at", 1)[1].split("- `STATUSTEXT`", 1)[0]
    names: set[str] = set()
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 3 or not cells[0].startswith("`"):
            continue
        if cells[1].startswith("several cylinders") and cylinders == 1:
            continue
        listed = re.findall(r"`([A-Z0-9_]+)`", cells[0])
        first = listed[0]
        if "1" in first and ".." in cells[0]:  # `CHT1_EST` .. `CHTn_EST`
            names |= {first.replace("1", str(n), 1) for n in range(1, cylinders + 1)}
        else:
            names |= set(listed)  # `GAMMA_Q_SD`, `GAMMA_D_SD`: a row may name several
    return names


def test_contract_names_are_read_from_the_docs() -> None:
    assert contract_names() == {
        "CHT1_EST", "HDRM1", "GAMMA_Q", "GAMMA_D", "ENG_DEV", "ENG_ST",
        "GAMMA_Q_SD", "GAMMA_D_SD", "NOT_ISO", "DET_ARMED",
    }  # fmt: skip
    assert {"CHT4_EST", "HDRM4", "CHT_SPRD", "CHT_HOT"} <= contract_names(4)


def test_daemon_on_udp_heard_by_pymavlink_link_drops_and_returns(ns: Namespace) -> None:
    """HEARTBEAT from the service's ids, the NAMED_VALUE_FLOAT set of docs/contracts.md, STATUSTEXT at start,
    on NOMINAL, on INPUT_STALE when the autopilot's process is killed, and NOMINAL again from a new one."""
    port_in, port_out = 14650, 14660
    reader = Lines(ns.popen([sys.executable, "-c", _READER, f"udpin:127.0.0.1:{port_out}"]))
    assert reader.wait_for(lambda lines: "listening\n" in lines, 30), "reader did not start"
    daemon = _daemon(ns, _config(ns, port_in, output=f"udpout:127.0.0.1:{port_out}"))
    heard = lambda _: any(r["src"] == SERVICE for r in _rows(reader, "HEARTBEAT"))  # noqa: E731
    assert reader.wait_for(heard, START_S), f"no HEARTBEAT from the daemon: {daemon.poll()}"
    # the text goes out right after the HEARTBEAT of the same health row: the reader may print it a moment later
    assert reader.wait_for(lambda _: _text_after(reader, "started", 0.0) is not None, 5), _texts(reader)
    started = _text_after(reader, "started", 0.0)
    assert started is not None and started["severity"] == NOTICE, _texts(reader)
    assert started["text"] == "ENGINE monitor: started, UNAVAILABLE" and started["src"] == SERVICE

    first = _autopilot(ns, port_in)
    assert reader.wait_for(lambda _: _text_after(reader, "NOMINAL", 0.0) is not None, 30), _texts(reader)
    nominal = _text_after(reader, "NOMINAL", 0.0)
    assert nominal is not None and nominal["severity"] == INFO
    assert re.fullmatch(r"ENGINE: normal, NOMINAL, CHT \d+ C", nominal["text"]), nominal
    window = time.monotonic()
    time.sleep(3.2)
    beats = [r for r in _rows(reader, "HEARTBEAT", window) if r["src"] == SERVICE]
    assert 3 <= len(beats) <= 5, beats  # 1 Hz
    assert all((b["kind"], b["autopilot"], b["status"], b["mode"], b["v2"]) ==
               (ONBOARD_CONTROLLER, AUTOPILOT_INVALID, STATE_ACTIVE, NOMINAL, True) for b in beats), beats  # fmt: skip
    values = _rows(reader, "NAMED_VALUE_FLOAT", window)
    assert {r["name"] for r in values} == contract_names()
    for name in contract_names():  # 2 Hz each
        assert 5 <= sum(r["name"] == name for r in values) <= 8, name
    latest = {r["name"]: r["value"] for r in values}
    # nothing declared at engine start: the gammas are not isolable, so NaN with NOT_ISO 1
    assert latest["ENG_ST"] == NOMINAL and 0.0 < latest["CHT1_EST"] < 150.0
    assert latest["NOT_ISO"] == 1.0 and math.isnan(latest["GAMMA_Q"])
    assert all(r["src"] == SERVICE for r in values)

    first.send_signal(signal.SIGKILL)  # the link drops
    killed = time.monotonic()
    assert reader.wait_for(lambda _: _text_after(reader, "INPUT_STALE", killed) is not None, 10), _texts(reader)
    stale = _text_after(reader, "INPUT_STALE", killed)
    assert stale is not None and stale["severity"] == WARNING
    assert re.fullmatch(r"ENGINE monitor: .+ lost, INPUT_STALE", stale["text"]), stale
    assert 2.5 < stale["t"] - killed < 5.0  # the shipped stale_after_s is 3 s
    every = ("rpm", "throttle", "CHT", "OAT", "altitude", "airspeed", "fuel flow")  # the shipped inputs, as worded
    lost_all = lambda _: any(all(w in r["text"] for w in every) for r in _texts(reader, killed))  # noqa: E731
    assert reader.wait_for(lost_all, 3.0), _texts(reader, killed)  # at once, or in a second text
    time.sleep(1.2)
    modes = [r["mode"] & 0x0F for r in _rows(reader, "HEARTBEAT", stale["t"] + 0.05) if r["src"] == SERVICE]
    assert modes and set(modes) == {INPUT_STALE}, modes

    second = _autopilot(ns, port_in)  # a new sender (another process, another source port) on the same link
    resumed = time.monotonic()
    assert reader.wait_for(lambda _: _text_after(reader, "NOMINAL", resumed) is not None, 30), _texts(reader, killed)
    back = _text_after(reader, "NOMINAL", resumed)
    assert back is not None and back["severity"] == INFO
    time.sleep(1.2)
    modes = [r["mode"] & 0x0F for r in _rows(reader, "HEARTBEAT", back["t"] + 0.05) if r["src"] == SERVICE]
    assert modes and set(modes) == {NOMINAL}, modes
    second.send_signal(signal.SIGKILL)
    assert daemon.poll() is None
    daemon.send_signal(signal.SIGTERM)
    _, stderr = daemon.communicate(timeout=20)
    assert daemon.returncode == 0, stderr
    assert "Traceback" not in stderr
    assert f"engine UAV-ENG-0001, MAVLink udpin:127.0.0.1:{port_in} -> udpout:127.0.0.1:{port_out}, state" in stderr
    states = re.findall(r"engine state (\w+) \(was (\w+)\) at t = ([\d.]+) s", stderr)  # the daemon's log
    assert [s[:2] for s in states] == [("UNAVAILABLE", "none"), ("NOMINAL", "UNAVAILABLE"), ("INPUT_STALE", "NOMINAL"),
                                       ("NOMINAL", "INPUT_STALE")], states  # fmt: skip
    told = float(states[2][2])  # the daemon's clock is CLOCK_MONOTONIC, as the reader's stamps
    assert 0.0 <= stale["t"] - told < 0.5, (stale["t"], told)


@pytest.mark.skipif(importlib.util.find_spec("MAVProxy") is None, reason="MAVProxy not installed (the test extra)")
def test_mavproxy_shows_the_services_statustext(ns: Namespace) -> None:
    """MAVProxy, headless, as a ground station on the shipped config's link (the service answers over the link
    it listens on, to every sender): it detects the service's component and prints its texts ('AP: ...'),
    and its telemetry log holds them."""
    from pymavlink import mavutil

    port = 14550
    daemon = _daemon(ns, _config(ns, port))
    log = ns.tmp / "mavproxy.tlog"
    # flushlogs: MAVProxy writes its .tlog as messages come (else every 10 s, and a kill loses the rest)
    ground = ns.popen([sys.executable, "-m", "MAVProxy.mavproxy", f"--master=udpout:127.0.0.1:{port}",
                       "--non-interactive", f"--state-basedir={ns.tmp}", f"--logfile={log}",
                       "--cmd=set flushlogs True"])  # fmt: skip
    mavproxy = Lines(ground)
    detected = lambda lines: any("Detected vehicle 1:191" in line for line in lines)  # noqa: E731
    assert mavproxy.wait_for(detected, START_S), (mavproxy.lines, daemon.poll())
    autopilot = _autopilot(ns, port)
    said = lambda text: lambda lines: any(line.startswith("AP: ") and text in line for line in lines)  # noqa: E731
    assert mavproxy.wait_for(said("NOMINAL"), 30), mavproxy.lines
    assert any(re.fullmatch(r"AP: ENGINE: normal, NOMINAL, CHT \d+ C\n", line) for line in mavproxy.lines)
    autopilot.send_signal(signal.SIGKILL)
    assert mavproxy.wait_for(said("lost, INPUT_STALE"), 10), mavproxy.lines
    daemon.send_signal(signal.SIGTERM)
    _, stderr = daemon.communicate(timeout=20)
    assert daemon.returncode == 0, stderr
    ground.send_signal(signal.SIGTERM)
    ground.wait(timeout=20)
    logged = mavutil.mavlink_connection(str(log))
    texts, chunks = [], []  # the .tlog holds the chunks as sent: joined here as MAVProxy joins them
    while (msg := logged.recv_match(type="STATUSTEXT")) is not None:
        chunks.append(msg.text)
        if msg.id == 0 or len(msg.text) < 50:
            texts.append(((msg.get_srcSystem(), msg.get_srcComponent()), "".join(chunks)))
            chunks = []
    logged.close()
    assert any(src == tuple(SERVICE) and "NOMINAL" in text for src, text in texts), texts
    assert any(src == tuple(SERVICE) and "INPUT_STALE" in text for src, text in texts), texts
