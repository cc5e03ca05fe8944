"""The input table: every input the service reads, once. Its order is the bit order of the stale-input
bit field (Health_Diag.StaleInputs, then StaleInputsHigh; health.csv's stale_inputs), its quantity the
kind of unit a config or a log may give it in (ecu_monitor/units.py). From it the config knows which
inputs it may map, the decoder's values are named, the pipeline's stale checks are made and the model's
heat-map axes are allowed. Adding an input is one row here (and, for a new quantity, one in units.py).
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import NamedTuple

from ecu_monitor.units import QUANTITY_OF_COLUMN

__all__ = ["INPUTS", "INPUT_NAMES", "INPUT_QUANTITIES", "Input", "stale_bit"]


class Input(NamedTuple):
    """One input: its name (the canonical flight-CSV column, canonical unit in the name) and what it is."""

    name: str
    meaning: str

    @property
    def quantity(self) -> str:
        """The kind of unit it comes in (ecu_monitor/units.py)."""
        return QUANTITY_OF_COLUMN[self.name]


#: Every input, in stale-bit order (bit i of the stale field is INPUTS[i]).
INPUTS: tuple[Input, ...] = (
    Input("rpm", "engine speed, rev/min"),
    Input("throttle_pct", "throttle position, 0-100"),
    Input("cht_c", "cylinder head temperature, degC (a cylinder's cht<N>_c is reported as cht_c)"),
    Input("oat_c", "outside air temperature, degC"),
    Input("altitude_m", "pressure altitude, m"),
    Input("airspeed_mps", "calibrated airspeed, m/s"),
    Input("fuel_flow_lph", "fuel flow, L/h"),
    Input("egt_c", "exhaust gas temperature, degC (the mixture index of a model with mixture_index)"),
    Input("manifold_pressure_kpa", "intake manifold absolute pressure, kPa (constant-speed-propeller engines)"),
)
#: The input names, in stale-bit order.
INPUT_NAMES: tuple[str, ...] = tuple(i.name for i in INPUTS)
#: Quantity of each input (its unit must be of this quantity).
INPUT_QUANTITIES: Mapping[str, str] = MappingProxyType({i.name: i.quantity for i in INPUTS})


def stale_bit(name: str) -> int:
    """The bit of input ``name`` in the stale-input bit field (a cylinder's CHT: cht_c's)."""
    return 1 << INPUT_NAMES.index(name)
