"""Named columns, the least a start rule reads from a flight (ecu_monitor.model.effects.Columns)."""

from __future__ import annotations

import numpy as np


class NamedColumns:
    """What a start rule reads: named columns."""

    def __init__(self, columns: dict[str, np.ndarray]) -> None:
        self.columns = columns

    def has(self, name: str) -> bool:
        return name in self.columns

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]
