"""ecu-monitor: model-based thermal health monitoring of a UAV piston engine on CAN.

Layers (each imports only those below it):
    model -> estimation -> identify / gap -> bus -> service -> cli
See docs/architecture.md.
"""

from ecu_monitor.errors import EcuMonitorError, UserInputError

__all__ = ["EcuMonitorError", "UserInputError", "__version__"]
__version__ = "0.1.0"
