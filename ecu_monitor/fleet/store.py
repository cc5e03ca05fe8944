"""The fleet's output folder: Parquet datasets a fleet can query (pyarrow writes, DuckDB and pandas read).

::

    DIR/engines.parquet                        one row per engine (fleet/engines.py)
    DIR/flights/serial=SERIAL/KEY.parquet      the flights of one log (fleet/summary.py FLIGHT_FIELDS)
    DIR/events/serial=SERIAL/KEY.parquet       the engine events of one log (pipeline/events.py)
    DIR/failures/KEY.parquet                   one row per log that could not be read: file, reason
    DIR/report.html                            fleet/report.py

Each log's files are named by its key (sha256 of its content and its engine's settings): a rerun skips the
logs whose flights file (or failure row) is there, so only unseen logs are processed. Every file is written
to a temporary name beside it and renamed when complete (:func:`ecu_monitor.userfiles.atomic_output`): a run
killed at any moment leaves whole files only (a leftover ``.*.part`` is ignored by DuckDB's and pyarrow's
readers and removed by the next run); a log's events are written before its flights, so a log counts as
done only with both. Files of keys no longer listed (a log removed, an engine's settings changed) are
removed at the end of a run.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from ecu_monitor.errors import ConfigError

__all__ = ["TABLES", "FleetStore"]

#: The tables ``fleet query`` names (DuckDB views).
TABLES = ("engines", "flights", "events", "failures")


def _schemas() -> dict[str, Any]:
    import pyarrow as pa

    flights = pa.schema([
        ("log", pa.string()), ("key", pa.string()), ("flight", pa.int64()), ("position", pa.int64()),
        ("start_utc", pa.float64()), ("duration_s", pa.float64()), ("ground_s", pa.float64()),
        ("low_power_s", pa.float64()), ("cruise_power_s", pa.float64()), ("high_power_s", pa.float64()),
        ("max_cht_c", pa.float64()), ("max_cht_cyl_c", pa.list_(pa.float64())),
        ("time_above_limit_s", pa.float64()), ("gamma_q_mean", pa.float64()), ("gamma_q_end", pa.float64()),
        ("gamma_d_mean", pa.float64()), ("gamma_d_end", pa.float64()), ("wear_index", pa.float64()),
        ("worst_state", pa.string()), ("degraded_s", pa.float64()), ("first_degraded_s", pa.float64()),
        ("events", pa.int64()),
    ])  # fmt: skip
    events = pa.schema([
        ("log", pa.string()), ("key", pa.string()), ("flight", pa.int64()), ("time_s", pa.float64()),
        ("kind", pa.string()), ("cylinder", pa.int64()), ("value", pa.float64()), ("limit", pa.float64()),
        ("duration_s", pa.float64()),
    ])  # fmt: skip
    failures = pa.schema([("serial", pa.string()), ("log", pa.string()), ("key", pa.string()),
                          ("reason", pa.string()), ("internal", pa.bool_())])  # fmt: skip
    return {"flights": flights, "events": events, "failures": failures}


class FleetStore:
    """The output folder ``root`` (module docstring)."""

    def __init__(self, root: str | os.PathLike[str]) -> None:
        self.root = Path(root)
        self.schemas = _schemas()

    # --- checks and set-up, before any work ---------------------------------------------------------------

    def prepare(self, inputs: Iterable[Path]) -> None:
        """Make the folder (its parent must exist), check it is writable and is not an input; remove the
        ``.*.part`` files a killed run left."""
        root = self.root
        if root.exists() and not root.is_dir():
            raise ConfigError(f"--out {root}: exists and is not a folder")
        if not root.parent.is_dir():
            raise ConfigError(f"--out {root}: no such folder {root.parent}")
        resolved = root.resolve()
        for path in inputs:
            if path.resolve() == resolved or resolved in path.resolve().parents:
                raise ConfigError(f"--out {root}: holds the input {path}: give another folder")
        try:
            for name in ("flights", "events", "failures"):
                (root / name).mkdir(parents=True, exist_ok=True)
            probe = root / ".write-probe"
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as exc:
            raise ConfigError(f"--out {root}: cannot write there ({exc.strerror or exc})") from None
        for part in root.rglob(".*.part"):
            with contextlib.suppress(OSError):
                part.unlink()

    # --- what is done ---------------------------------------------------------------------------------------

    def done_keys(self) -> set[str]:
        """Keys of the logs already summarised (their flights file is there)."""
        return {p.stem for p in (self.root / "flights").glob("serial=*/*.parquet")}

    def failed_keys(self, internal: bool | None = None) -> set[str]:
        """Keys of the logs with a failure row (``internal``: only those, or only the others)."""
        keys = set()
        for path in (self.root / "failures").glob("*.parquet"):
            if internal is None or self._read(path).column("internal")[0].as_py() == internal:
                keys.add(path.stem)
        return keys

    # --- writing ------------------------------------------------------------------------------------------

    def write_log(
        self, serial: str, key: str, flights: Sequence[dict[str, Any]], events: Sequence[dict[str, Any]]
    ) -> None:
        """One log's events, then its flights (which mark it done); any failure row of its key removed."""
        self._write(self.root / "events" / f"serial={serial}" / f"{key}.parquet", "events", events)
        self._write(self.root / "flights" / f"serial={serial}" / f"{key}.parquet", "flights", flights)
        with contextlib.suppress(FileNotFoundError):
            (self.root / "failures" / f"{key}.parquet").unlink()

    def write_failure(self, serial: str, log: str, key: str, reason: str, internal: bool) -> None:
        """One failure row (a bad log: ``internal`` False; a crash of our own: True, retried next run)."""
        row = {"serial": serial, "log": log, "key": key, "reason": reason, "internal": internal}
        self._write(self.root / "failures" / f"{key}.parquet", "failures", [row])

    def write_engines(self, rows: Sequence[dict[str, Any]]) -> None:
        """DIR/engines.parquet (fleet/engines.py ENGINE_FIELDS), whole."""
        import pyarrow as pa

        from ecu_monitor.fleet.engines import engines_schema

        self._write_table(self.root / "engines.parquet", pa.Table.from_pylist(list(rows), schema=engines_schema()))

    def _write(self, path: Path, table: str, rows: Sequence[dict[str, Any]]) -> None:
        import pyarrow as pa

        self._write_table(path, pa.Table.from_pylist(list(rows), schema=self.schemas[table]))

    def _write_table(self, path: Path, table: Any) -> None:
        import pyarrow.parquet as pq

        from ecu_monitor.userfiles import atomic_output

        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_output(path, ConfigError) as handle:
            pq.write_table(table, handle)

    def remove_stale(self, keys: set[str]) -> int:
        """Remove the files of keys not in ``keys`` (logs no longer listed, settings changed); how many."""
        removed = 0
        for path in [*self.root.glob("flights/serial=*/*.parquet"), *self.root.glob("events/serial=*/*.parquet"),
                     *self.root.glob("failures/*.parquet")]:  # fmt: skip
            if path.stem not in keys:
                path.unlink()
                removed += 1
        for folder in [*self.root.glob("flights/serial=*"), *self.root.glob("events/serial=*")]:
            with contextlib.suppress(OSError):
                folder.rmdir()  # only when empty
        return removed

    # --- reading ------------------------------------------------------------------------------------------

    def _read(self, path: Path) -> Any:
        import pyarrow.parquet as pq

        return pq.read_table(path)

    def table(self, name: str) -> Any:
        """The whole table ``name`` (flights, events, failures) as one pyarrow Table; ``serial`` first."""
        import pyarrow as pa
        import pyarrow.compute as pc

        schema = self.schemas[name]
        if name == "failures":
            parts = [self._read(p) for p in sorted((self.root / "failures").glob("*.parquet"))]
            return pa.concat_tables(parts) if parts else schema.empty_table()
        parts = []
        for path in sorted((self.root / name).glob("serial=*/*.parquet")):
            t = self._read(path)
            serial = path.parent.name.split("=", 1)[1]
            parts.append(t.add_column(0, "serial", pc.cast(pa.array([serial] * len(t)), pa.string())))
        full = pa.schema([("serial", pa.string()), *schema])
        return pa.concat_tables(parts) if parts else full.empty_table()

    def connect(self) -> Any:
        """A DuckDB connection with the views engines, flights, events and failures over the Parquet files."""
        import duckdb

        con = duckdb.connect()
        for name in TABLES:
            con.execute(f"CREATE VIEW {name} AS {self._select(name)}")
        return con

    def _select(self, name: str) -> str:
        """The SELECT of view ``name``: the Parquet files, or an empty table of the schema when there are none."""
        root = self.root
        if name == "engines":
            path = root / "engines.parquet"
            if not path.is_file():
                raise ConfigError(f"{root}: no engines.parquet: not a fleet folder (ecu-monitor fleet run writes it)")
            return f"SELECT * FROM read_parquet({_sql(path)})"
        if name == "failures":
            files = list((root / "failures").glob("*.parquet"))
            pattern = root / "failures" / "*.parquet"
            return f"SELECT * FROM read_parquet({_sql(pattern)})" if files else _empty(self.schemas[name])
        files = list((root / name).glob("serial=*/*.parquet"))
        pattern = root / name / "serial=*" / "*.parquet"
        if not files:
            return _empty(self.schemas[name], serial=True)
        return f"SELECT * FROM read_parquet({_sql(pattern)}, hive_partitioning = true)"


def _sql(path: Path) -> str:
    """A path as an SQL string literal."""
    return "'" + str(path).replace("'", "''") + "'"


def _empty(schema: Any, serial: bool = False) -> str:
    """SELECT of no rows with ``schema``'s columns (DuckDB types)."""
    types = {
        "string": "VARCHAR",
        "int64": "BIGINT",
        "double": "DOUBLE",
        "bool": "BOOLEAN",
        "list<item: double>": "DOUBLE[]",
    }
    columns = [("serial", "VARCHAR")] if serial else []
    columns += [(f.name, types[str(f.type)]) for f in schema]
    return "SELECT " + ", ".join(f'CAST(NULL AS {t}) AS "{n}"' for n, t in columns) + " WHERE false"
