"""The daemon on a DroneCAN bus as a separate process (python-can udp_multicast inside a network namespace,
as tests/runtime/test_netns.py): DroneCAN in from the virtual ECU (``virtual-ecu run`` with the config's
``protocol: dronecan``), NodeStatus, KeyValue and LogMessage out, read by a listener that reassembles
them with the ``dronecan`` package, and a GetNodeInfo request of the listener's answered. Skipped without
root and ``ip netns`` (the reason is given)."""

from __future__ import annotations

import math
import random
import signal
import sys
import textwrap
import time

import pytest
import yaml

from tests.helpers import REPO
from tests.helpers.netns import Lines, Namespace

pytestmark = [pytest.mark.netns, pytest.mark.process, pytest.mark.slow]

GROUP = "239.74.163.2"
NODE_ID = 100

_LISTENER = textwrap.dedent(
    """
    import sys, time, can, dronecan
    bus = can.Bus(interface="udp_multicast", channel=sys.argv[1], port=int(sys.argv[2]))
    manager = dronecan.transport.TransferManager()
    asked = False  # a GetNodeInfo request sent (as node 42) once the node is operational
    print("listening", flush=True)
    while True:
        msg = bus.recv(0.5)
        if msg is None or not msg.is_extended_id or msg.arbitration_id & 0x7F != int(sys.argv[3]):
            continue
        frames = manager.receive_frame(dronecan.transport.Frame(msg.arbitration_id, msg.data))
        if not frames:
            continue
        transfer = dronecan.transport.Transfer()
        transfer.from_frames(frames)
        p = transfer.payload
        name = dronecan.get_dronecan_data_type(p).full_name.rsplit(".", 1)[1]
        if name == "NodeStatus":
            fields = f"{p.health} {p.mode} {p.uptime_sec} {p.vendor_specific_status_code}"
            if p.mode == 0 and not asked:
                asked = True
                request = dronecan.transport.Transfer(
                    transfer_id=9, source_node_id=42, dest_node_id=int(sys.argv[3]), transfer_priority=30,
                    payload=dronecan.uavcan.protocol.GetNodeInfo.Request(), service_not_message=True,
                    request_not_response=True)
                for f in request.to_frames():
                    bus.send(can.Message(arbitration_id=f.message_id, is_extended_id=True, data=bytes(f.bytes)))
        elif name == "GetNodeInfo":
            fields = f"{bytes(p.name).decode()} {p.status.mode} {p.software_version.major}.{p.software_version.minor}"
        elif name == "KeyValue":
            fields = f"{p.key.decode()} {p.value}"
        else:
            fields = f"{p.level.value} {p.text.decode().replace(' ', '_')}"
        print(f"{time.monotonic():.6f} {name} {fields}", flush=True)
    """
)


def _lines(listener: Lines, kind: str, since_s: float = 0.0) -> list[list[str]]:
    out = []
    for line in list(listener.lines):
        parts = line.split()
        if len(parts) >= 2 and parts[1] == kind and float(parts[0]) >= since_s:
            out.append(parts)
    return out


def test_dronecan_in_node_status_out_across_processes(ns: Namespace) -> None:
    port = random.Random(ns.name).randrange(40000, 50000)
    config = ns.tmp / "dronecan.yaml"
    data = yaml.safe_load((REPO / "ecu_monitor" / "data" / "configs" / "dronecan.yaml").read_text(encoding="utf-8"))
    data["bus"] = {"interface": "udp_multicast", "channel": GROUP, "port": port}
    data["state_dir"] = str(ns.tmp / "state")
    config.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    listener = Lines(ns.popen([sys.executable, "-c", _LISTENER, GROUP, str(port), str(NODE_ID)]))
    assert listener.wait_for(lambda lines: "listening\n" in lines, 20), "listener did not start"
    daemon = ns.popen([sys.executable, "-m", "ecu_monitor.cli", "run", "--config", str(config)])
    # before any input the node is up, initialising, with a warning (no engine data: UNAVAILABLE)
    assert listener.wait_for(lambda _: len(_lines(listener, "NodeStatus")) >= 1, 30), daemon.stderr
    first = _lines(listener, "NodeStatus")[0]
    assert first[2:4] == ["1", "1"] and int(first[5]) & 0x0F == 5
    emulator = ns.popen([sys.executable, "-m", "virtual_bus.cli", "run", "--config", str(config), "--mission",
                         "default", "--realtime"])  # fmt: skip
    assert listener.wait_for(lambda _: any(p[2:4] == ["0", "0"] for p in _lines(listener, "NodeStatus")), 20)
    running = time.monotonic()
    time.sleep(3.2)
    status = _lines(listener, "NodeStatus", since_s=running)
    assert 3 <= len(status) <= 5 and all(p[2:4] == ["0", "0"] and p[5] == "0" for p in status)  # OK, OPERATIONAL, 1 Hz
    values = {p[2]: float(p[3]) for p in _lines(listener, "KeyValue", since_s=running)}
    assert 0.0 < values["cht_est"] < 150.0 and values["state"] == 0.0
    # nothing declared, engine start: the gammas cannot be told apart, so they are not given (NaN)
    assert values["not_iso"] == 1.0 and math.isnan(values["gamma_q"])
    assert any(p[3].startswith("CHT_NOMINAL") for p in _lines(listener, "LogMessage"))
    # the GetNodeInfo request sent by the listener once the node was operational, through the daemon's filters
    assert [p[2:4] for p in _lines(listener, "GetNodeInfo")] == [["org.ecu-monitor.cht", "0"]]
    emulator.send_signal(signal.SIGKILL)
    killed = time.monotonic()
    stale_told = lambda _: any(p[3].startswith("CHT_INPUT_STALE") for p in _lines(listener, "LogMessage", killed))  # noqa: E731
    assert listener.wait_for(stale_told, 10)
    assert listener.wait_for(lambda _: any(p[2] == "1" for p in _lines(listener, "NodeStatus", since_s=killed)), 5)
    assert daemon.poll() is None
    daemon.send_signal(signal.SIGTERM)
    _, stderr = daemon.communicate(timeout=20)
    assert daemon.returncode == 0, stderr
    assert "Traceback" not in stderr
