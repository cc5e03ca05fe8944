"""Offline tools that drive the pipeline's one step over recorded logs: replay (a log -> health.csv)
and calibrate (the detector's threshold and baseline from nominal flights). Identification and the gap
diagnosis are their siblings (ecu_monitor.identify, ecu_monitor.gap)."""

__all__: list[str] = []
