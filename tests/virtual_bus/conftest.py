"""Fixtures the virtual-bus tests share."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import can
import pytest


@pytest.fixture
def make_bus() -> Iterator[Any]:
    """Opens virtual buses on demand and always shuts every one down after the test."""
    opened: list[can.BusABC] = []

    def factory(channel: str, **kwargs: Any) -> can.BusABC:
        bus = can.Bus(interface="virtual", channel=channel, **kwargs)
        opened.append(bus)
        return bus

    yield factory
    for bus in opened:
        bus.shutdown()
