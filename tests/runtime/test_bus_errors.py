"""Bus errors at start-up: an interface the host cannot have ends the daemon (exit 2, one line); a bus
that merely is not up yet is left to the daemon's backoff (tests/runtime/test_daemon_process.py covers reopening).
A silent bus: when the daemon warns (SilenceWatch; the daemon's log in tests/runtime/test_daemon_process.py), and
the shipped multicast.yaml that both the daemon and the virtual ECU read.
"""

from __future__ import annotations

import errno
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import can
import pytest
import yaml

from ecu_monitor.commands.run import bus_opener, unsupported_on_host
from ecu_monitor.config import load_config
from ecu_monitor.errors import ConfigError
from ecu_monitor.runtime.daemon import SilenceWatch
from ecu_monitor.shipped import resolve_file
from tests.helpers import REPO
from virtual_bus.busconfig import load_bus_config

CONFIGS = REPO / "ecu_monitor" / "data" / "configs"


def _shipped_config(tmp_path: Path, name: str, **changes: Any) -> Path:
    """A copy of a shipped config with its state_dir under tmp_path (bare DBC names still find the shipped files)."""
    data = yaml.safe_load((CONFIGS / name).read_text())
    data["state_dir"] = str(tmp_path / "state")
    data.update(changes)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _host_has_af_can() -> bool:
    family = getattr(socket, "AF_CAN", None)
    if family is None:
        return False
    try:
        socket.socket(family, socket.SOCK_RAW, socket.CAN_RAW).close()
    except OSError:
        return False
    return True


def _raising(exc: BaseException) -> Any:
    def open_bus(**_options: Any) -> can.BusABC:
        raise exc

    return open_bus


def test_unsupported_on_host_tells_a_missing_family_from_a_missing_device() -> None:
    assert unsupported_on_host(OSError(errno.EAFNOSUPPORT, "Address family not supported by protocol"))
    try:  # python-can wrapping the socket error: the cause is followed
        raise can.CanInitializationError("cannot open") from OSError(errno.EAFNOSUPPORT, "no AF_CAN")
    except can.CanInitializationError as exc:
        assert unsupported_on_host(exc)
    assert not unsupported_on_host(OSError(errno.ENODEV, "No such device"))  # can0 not plugged in yet
    assert not unsupported_on_host(OSError(errno.ENETDOWN, "Network is down"))
    assert not unsupported_on_host(can.CanInitializationError("device busy"))


@pytest.mark.parametrize(
    "exc",
    [
        OSError(errno.EAFNOSUPPORT, "Address family not supported by protocol"),
        can.CanInterfaceNotImplementedError("the interface's module failed to import"),
        ModuleNotFoundError("No module named 'some_vendor_driver'"),
    ],
    ids=["no-af-can", "not-implemented", "missing-module"],
)
def test_first_open_on_an_impossible_interface_is_a_config_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, exc: BaseException
) -> None:
    config = load_config(_shipped_config(tmp_path, "rusefi.yaml"))
    monkeypatch.setattr(can, "Bus", _raising(exc))
    with pytest.raises(ConfigError) as raised:
        bus_opener(config)
    message = str(raised.value)
    assert "\n" not in message
    assert str(config.source) in message and "socketcan" in message


@pytest.mark.parametrize(
    "exc",
    [OSError(errno.ENODEV, "No such device"), can.CanInitializationError("device not up")],
    ids=["no-device-yet", "init-failed"],
)
def test_first_open_of_a_device_not_up_yet_is_left_to_the_backoff(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, exc: BaseException
) -> None:
    config = load_config(_shipped_config(tmp_path, "rusefi.yaml"))
    monkeypatch.setattr(can, "Bus", _raising(exc))
    reopen = bus_opener(config)  # no ConfigError: the daemon retries
    with pytest.raises(type(exc)):
        reopen()  # and each retry opens the bus again (a later transient failure stays transient)


@pytest.mark.process
@pytest.mark.skipif(_host_has_af_can(), reason="this host has AF_CAN: socketcan cannot fail for want of it")
def test_run_on_a_host_without_can_exits_2_with_one_line(tmp_path: Path) -> None:
    detector = yaml.safe_load((CONFIGS / "rusefi.yaml").read_text()).get("detector") or {}
    # a test bench: the shipped detector is not calibrated for this engine, which run would refuse first
    config = _shipped_config(tmp_path, "rusefi.yaml", detector={**detector, "uncalibrated": "accept"})
    proc = subprocess.run(
        [sys.executable, "-m", "ecu_monitor.cli", "run", "--config", str(config)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "socketcan" in lines[0] and str(config) in lines[0]


# --- a bus that carries nothing: the warning, and a pair of processes that can reach each other -------


def test_silence_watch_warns_once_per_silence() -> None:
    watch = SilenceWatch(limit_s=10.0, start_s=100.0)
    assert watch.check(109.9) is None
    assert watch.check(110.0) == "silent"
    assert [watch.check(t) for t in (111.0, 500.0)] == [None, None]  # the same silence: warned once
    watch.frame(501.0)
    assert watch.check(501.1) == "resumed"
    watch.frame(505.0)
    assert [watch.check(t) for t in (505.1, 514.9)] == [None, None]
    assert watch.check(515.0) == "silent"  # frames stopped again


def test_no_frames_warning_s_is_read_and_checked(tmp_path: Path) -> None:
    assert load_config(_shipped_config(tmp_path, "example.yaml")).no_frames_warning_s == 10.0
    assert load_config(_shipped_config(tmp_path, "example.yaml", no_frames_warning_s=3)).no_frames_warning_s == 3.0
    with pytest.raises(ConfigError, match="no_frames_warning_s"):
        load_config(_shipped_config(tmp_path, "example.yaml", no_frames_warning_s=0))


def test_multicast_yaml_is_one_bus_for_both_commands() -> None:
    """The shipped pair across processes: both commands read the same udp_multicast bus from it."""
    service = load_config(resolve_file("multicast.yaml", "config"))
    emulator = load_bus_config("multicast.yaml")
    assert service.bus["interface"] == emulator.interface == "udp_multicast"
    assert service.bus["channel"] == emulator.channel
    assert service.bus["port"] == emulator.options["port"]
    assert emulator.options["hop_limit"] == 1  # never routed off the host


def test_the_bus_is_named_by_its_interface_and_channel_where_python_can_says_unknown(tmp_path: Path) -> None:
    """Issue 31: the daemon on the shipped multicast pair logged "bus open: unknown"."""
    config = load_config(_shipped_config(tmp_path, "example.yaml", bus={"interface": "udp_multicast",
                                                                        "channel": "239.74.163.2"}))  # fmt: skip
    try:
        bus = bus_opener(config)()
    except OSError as exc:  # a host without multicast routes
        pytest.skip(f"udp_multicast cannot open here: {exc}")
    try:
        assert bus.channel_info == "udp_multicast 239.74.163.2"
    finally:
        bus.shutdown()
