"""Bus errors at start-up: an interface the host cannot have ends the daemon (exit 2, one line); a bus
that merely is not up yet is left to the daemon's backoff (tests/test_daemon_process.py covers reopening).
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
from ecu_monitor.errors import ConfigError
from ecu_monitor.service.config import load_config

REPO = Path(__file__).resolve().parent.parent
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


@pytest.mark.skipif(_host_has_af_can(), reason="this host has AF_CAN: socketcan cannot fail for want of it")
def test_run_on_a_host_without_can_exits_2_with_one_line(tmp_path: Path) -> None:
    config = _shipped_config(tmp_path, "rusefi.yaml")
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
