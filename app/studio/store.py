"""The studio's records in SQLite: designs (one row each, with its job's state) and uploads.

Every change of a design's row takes the next *revision* number, so that a reader can ask for
whatever changed since the revision it last saw (the page's event stream).  One connection,
used under a lock, from any thread; the database is in WAL mode, so a server or job that
crashes leaves it whole.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

SCHEMA = """
CREATE TABLE IF NOT EXISTS designs (
    id TEXT PRIMARY KEY,
    seq INTEGER NOT NULL,
    name TEXT NOT NULL,
    target TEXT NOT NULL,
    options TEXT NOT NULL,
    spec TEXT NOT NULL,
    status TEXT NOT NULL,
    stage TEXT NOT NULL DEFAULT '',
    progress REAL NOT NULL DEFAULT 0,
    exit_status INTEGER,
    message TEXT NOT NULL DEFAULT '',
    created REAL NOT NULL,
    started REAL,
    finished REAL,
    rev INTEGER NOT NULL
);
CREATE INDEX IF NOT EXISTS designs_rev ON designs (rev);
CREATE TABLE IF NOT EXISTS uploads (
    id TEXT PRIMARY KEY,
    kind TEXT NOT NULL,
    name TEXT NOT NULL,
    file TEXT NOT NULL,
    info TEXT NOT NULL,
    created REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS removed (
    id TEXT NOT NULL,
    rev INTEGER NOT NULL
);
"""

#: The columns a design's record shows, in the order of the API's JSON (``rev``: the
#: revision of the record's latest change).
RECORD_FIELDS = (
    "id", "name", "target", "status", "stage", "progress", "exit_status", "message", "options",
    "created", "started", "finished", "rev",
)  # fmt: skip


@dataclass(frozen=True)
class Upload:
    id: str
    kind: str
    name: str
    file: str
    info: dict[str, Any]


class Store:
    """The designs and uploads of one studio data folder."""

    def __init__(self, path: Path) -> None:
        self._lock = threading.Lock()
        self._db = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
        self._db.row_factory = sqlite3.Row
        with self._lock:
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.executescript(SCHEMA)
            row = self._db.execute(
                "SELECT MAX(r) FROM (SELECT MAX(rev) AS r FROM designs "
                "UNION ALL SELECT MAX(rev) FROM removed)"
            ).fetchone()
            self._rev = int(row[0] or 0)

    def close(self) -> None:
        with self._lock:
            self._db.close()

    @property
    def revision(self) -> int:
        """The revision of the latest change."""
        with self._lock:
            return self._rev

    @contextmanager
    def _write(self) -> Iterator[int]:
        """A transaction under the lock; yields the revision its change takes."""
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                yield self._rev + 1
            except BaseException:
                self._db.execute("ROLLBACK")
                raise
            self._db.execute("COMMIT")
            self._rev += 1

    # -- designs ---------------------------------------------------------------------------

    def add(self, id: str, name: str, target: str, options: dict[str, Any], spec: dict) -> None:
        with self._write() as rev:
            seq = self._db.execute("SELECT COALESCE(MAX(seq), 0) + 1 FROM designs").fetchone()[0]
            self._db.execute(
                "INSERT INTO designs (id, seq, name, target, options, spec, status, created, rev)"
                " VALUES (?, ?, ?, ?, ?, ?, 'queued', ?, ?)",
                (id, seq, name, target, json.dumps(options), json.dumps(spec), time.time(), rev),
            )

    def update(self, id: str, **values: Any) -> bool:
        """Set columns of a design's row; False when there is no such design."""
        return self._set(id, None, values)

    def update_if(self, id: str, statuses: tuple[str, ...], **values: Any) -> bool:
        """Set columns of a design's row only while its status is one of ``statuses``."""
        return self._set(id, statuses, values)

    def _set(self, id: str, statuses: tuple[str, ...] | None, values: dict[str, Any]) -> bool:
        columns = ", ".join(f"{key} = ?" for key in values)
        where = "id = ?"
        if statuses is not None:
            where += f" AND status IN ({', '.join('?' for _ in statuses)})"
        try:
            with self._write() as rev:
                done = self._db.execute(
                    f"UPDATE designs SET {columns}, rev = ? WHERE {where}",
                    (*values.values(), rev, id, *(statuses or ())),
                )
                if done.rowcount == 0:
                    raise _Unchanged
        except _Unchanged:
            return False
        return True

    def remove(self, id: str) -> bool:
        try:
            with self._write() as rev:
                done = self._db.execute("DELETE FROM designs WHERE id = ?", (id,))
                if done.rowcount == 0:
                    raise _Unchanged
                self._db.execute("INSERT INTO removed (id, rev) VALUES (?, ?)", (id, rev))
        except _Unchanged:
            return False
        return True

    def get(self, id: str) -> dict[str, Any] | None:
        with self._lock:
            row = self._db.execute("SELECT * FROM designs WHERE id = ?", (id,)).fetchone()
        return _record(row) if row is not None else None

    def spec(self, id: str) -> dict[str, Any] | None:
        with self._lock:
            row = self._db.execute("SELECT spec FROM designs WHERE id = ?", (id,)).fetchone()
        return json.loads(row[0]) if row is not None else None

    def all(self) -> list[dict[str, Any]]:
        """Every design, newest first."""
        with self._lock:
            rows = self._db.execute("SELECT * FROM designs ORDER BY seq DESC").fetchall()
        return [_record(row) for row in rows]

    def with_status(self, *statuses: str) -> list[dict[str, Any]]:
        """Designs with one of these statuses, oldest first."""
        marks = ", ".join("?" for _ in statuses)
        with self._lock:
            rows = self._db.execute(
                f"SELECT * FROM designs WHERE status IN ({marks}) ORDER BY seq", statuses
            ).fetchall()
        return [_record(row) for row in rows]

    def changed_since(self, rev: int) -> tuple[list[dict[str, Any]], list[str], int]:
        """The designs changed and the ids removed after revision ``rev``, and the revision
        they bring the reader to."""
        with self._lock:
            rows = self._db.execute(
                "SELECT * FROM designs WHERE rev > ? ORDER BY rev", (rev,)
            ).fetchall()
            gone = self._db.execute(
                "SELECT id FROM removed WHERE rev > ? ORDER BY rev", (rev,)
            ).fetchall()
            now = self._rev
        return [_record(row) for row in rows], [row[0] for row in gone], now

    # -- uploads ---------------------------------------------------------------------------

    def add_upload(self, upload: Upload) -> None:
        with self._lock:
            self._db.execute(
                "INSERT OR REPLACE INTO uploads (id, kind, name, file, info, created) "
                "VALUES (?, ?, ?, ?, ?, ?)",
                (upload.id, upload.kind, upload.name, upload.file, json.dumps(upload.info),
                 time.time()),
            )  # fmt: skip

    def upload(self, id: str) -> Upload | None:
        with self._lock:
            row = self._db.execute("SELECT * FROM uploads WHERE id = ?", (id,)).fetchone()
        if row is None:
            return None
        return Upload(row["id"], row["kind"], row["name"], row["file"], json.loads(row["info"]))

    def uploads(self, kind: str) -> list[Upload]:
        with self._lock:
            rows = self._db.execute(
                "SELECT * FROM uploads WHERE kind = ? ORDER BY created", (kind,)
            ).fetchall()
        return [
            Upload(row["id"], row["kind"], row["name"], row["file"], json.loads(row["info"]))
            for row in rows
        ]


class _Unchanged(Exception):
    """No row matched: the transaction is rolled back and takes no revision."""


def _record(row: sqlite3.Row) -> dict[str, Any]:
    record = {key: row[key] for key in RECORD_FIELDS}
    record["options"] = json.loads(record["options"])
    return record
