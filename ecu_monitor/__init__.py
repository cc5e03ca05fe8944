"""ecu-monitor: model-based thermal health monitoring of a UAV piston engine on CAN.

Its rooms and their layers (each imports only those below it): docs/architecture.md.
"""

from ecu_monitor.errors import EcuMonitorError, UserInputError

__all__ = ["EcuMonitorError", "UserInputError", "__version__"]
#: The package version (pyproject.toml reads it from here).
__version__ = "0.1.0"
