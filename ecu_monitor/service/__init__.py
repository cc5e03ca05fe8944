"""The companion service: configuration, the frame-to-health pipeline (live and replay), the daemon.

Start with :func:`~ecu_monitor.service.config.load_config` and
:class:`~ecu_monitor.service.pipeline.Pipeline` (docs/service.md). Submodules are imported where
they are used (the daemon does not need the replay's batch path, and the other way round).
"""

__all__: list[str] = []
