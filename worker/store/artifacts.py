"""Artefacts of jobs, stored in the database (outputs of a run and its latest checkpoint)."""

from __future__ import annotations

import hashlib
import mimetypes
from collections.abc import Iterator
from typing import Any

from sqlalchemy import Connection, LargeBinary, delete, func, insert, select, update

from .base import Claim, StoreBase, valid_id
from .schema import artifacts, db_now, jobs

CHECKPOINT_NAME = "checkpoint.pt"
_READ_CHUNK = 1 << 20


def content_type_for(name: str) -> str:
    if name.endswith(".json"):
        return "application/json"
    if name.endswith((".pt", ".pt2", ".onnx")):  # torch files and ONNX: binary, whatever mime.types says
        return "application/octet-stream"
    return mimetypes.guess_type(name)[0] or "application/octet-stream"


class ArtifactQueries(StoreBase):
    """Listing and reading artefacts (written by the queue protocol, fenced)."""

    def list_artifacts(self, job_id: int) -> list[dict[str, Any]]:
        cols = [c for c in artifacts.c if c.name != "data"]
        with self._read() as conn:
            rows = (
                conn.execute(
                    select(*cols)
                    .where(artifacts.c.job_id == job_id)
                    .order_by(artifacts.c.kind.desc(), artifacts.c.name)
                )
                .mappings()
                .all()
            )
        return [dict(r) for r in rows]

    def artifact_info(self, job_id: int, name: str) -> dict[str, Any] | None:
        if not valid_id(job_id) or "\x00" in name:  # no stored name has a NUL (PostgreSQL rejects it)
            return None
        cols = [c for c in artifacts.c if c.name != "data"]
        with self._read() as conn:
            row = (
                conn.execute(select(*cols).where(artifacts.c.job_id == job_id, artifacts.c.name == name))
                .mappings()
                .first()
            )
        return dict(row) if row else None

    def read_artifact(self, job_id: int, name: str) -> bytes | None:
        with self._read() as conn:
            return conn.execute(
                select(artifacts.c.data).where(artifacts.c.job_id == job_id, artifacts.c.name == name)
            ).scalar_one_or_none()

    def iter_artifact(
        self, job_id: int, name: str, size: int, sha256: str, chunk: int = _READ_CHUNK
    ) -> Iterator[bytes]:
        """The artefact's bytes in chunks, so a large file never sits whole in the server's memory.

        If the file is replaced meanwhile (a newer checkpoint), the stream stops short rather
        than mix two versions; the client sees fewer bytes than Content-Length."""
        for start in range(0, size, chunk):
            part = func.substr(artifacts.c.data, start + 1, chunk, type_=LargeBinary)
            with self._read() as conn:
                data = conn.execute(
                    select(part).where(
                        artifacts.c.job_id == job_id, artifacts.c.name == name, artifacts.c.sha256 == sha256
                    )
                ).scalar_one_or_none()
            if not data:
                return
            yield bytes(data)

    def load_checkpoint(self, job_id: int) -> bytes | None:
        return self.read_artifact(job_id, CHECKPOINT_NAME)


def put_artifact(conn: Connection, c: Claim, name: str, data: bytes, kind: str) -> None:
    conn.execute(delete(artifacts).where(artifacts.c.job_id == c.job_id, artifacts.c.name == name))
    conn.execute(
        insert(artifacts).values(
            job_id=c.job_id,
            name=name,
            kind=kind,
            attempt=c.attempt,
            size=len(data),
            sha256=hashlib.sha256(data).hexdigest(),
            content_type=content_type_for(name),
            created_at=db_now(),
            data=data,
        )
    )


def drop_checkpoint(conn: Connection, job_id: int) -> None:
    """A job that has ended without success will not resume: its checkpoint (often the largest
    file, replay buffer included) is deleted."""
    conn.execute(delete(artifacts).where(artifacts.c.job_id == job_id, artifacts.c.kind == "checkpoint"))
    conn.execute(update(jobs).where(jobs.c.id == job_id).values(checkpoint_env_steps=None))
