"""An older flight database, to check that opening it migrates it without loss."""

from __future__ import annotations

import sqlite3
from pathlib import Path


def write_old_flight_database(path: Path, version: int) -> None:
    """A flight database of an older schema at ``path`` (a file): version 1 (no cylinders_json) or 2 (no wear
    columns, no maintenance_alerts), with engine 'OLD' and one finished flight (gamma_Q mean 1.02, max CHT
    150 degC, 3 cycles), to check that opening it migrates it without loss."""
    cylinders = " cylinders_json TEXT," if version >= 2 else ""
    cylinders_value = " NULL," if version >= 2 else ""
    with sqlite3.connect(path) as conn:
        conn.executescript(
            "CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);"
            f"INSERT INTO meta VALUES ('schema_version', '{version}');"
            "CREATE TABLE engines (serial TEXT PRIMARY KEY, first_seen_utc REAL NOT NULL);"
            "CREATE TABLE flights (id INTEGER PRIMARY KEY, engine_serial TEXT NOT NULL, status TEXT NOT NULL,"
            " end_reason TEXT, start_utc REAL NOT NULL, end_utc REAL NOT NULL, duration_s REAL NOT NULL,"
            " max_cht_c REAL, cht_limit_c REAL NOT NULL, time_above_limit_s REAL NOT NULL, gamma_q_start REAL,"
            " gamma_q_end REAL, gamma_q_mean REAL, gamma_q_max REAL, gamma_q_slope_per_h REAL, gamma_d_start REAL,"
            " gamma_d_end REAL, gamma_d_mean REAL, gamma_d_max REAL, gamma_d_slope_per_h REAL,"
            " worst_state TEXT NOT NULL, time_degraded_s REAL NOT NULL, cycles_total REAL NOT NULL,"
            f" cycles_json TEXT NOT NULL,{cylinders} reversals BLOB, updated_utc REAL NOT NULL);"
            "INSERT INTO engines VALUES ('OLD', 1.7e9);"
            "INSERT INTO flights VALUES (1, 'OLD', 'finished', 'engine_stopped', 1.7e9, 1.7e9 + 600, 600, 150, 200,"
            f" 0, 1, 1, 1.02, 1, 0, 1, 1, 1, 1, 0, 'NOMINAL', 0, 3, '{{}}',{cylinders_value} NULL, 1.7e9);"
        )
