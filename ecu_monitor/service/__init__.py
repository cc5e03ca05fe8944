"""The companion service: configuration, the frame-to-health pipeline (live and replay), the daemon.

Start with :func:`load_config` and :class:`Pipeline` (docs/service.md).
"""
