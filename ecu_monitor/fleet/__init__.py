"""The fleet: every flight of every engine, one Dask task per log, ranked engines and a report (docs/fleet.md).

``spec`` (FLEET.yaml), ``summary`` (one log -> its flights and events), ``store`` (the Parquet datasets),
``engines`` (per engine: flight order, the across-flight detector, the ranking), ``report`` (report.html),
``run`` (the Dask run), ``demo`` (a virtual fleet from nothing). Dask, pyarrow and DuckDB (the ``fleet``
extra) are imported inside the functions that use them.
"""

__all__: list[str] = []
