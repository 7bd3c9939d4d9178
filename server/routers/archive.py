"""``/api/jobs/{id}/archive.zip`` and ``/api/jobs/{id}/outcome``: what a finished job gave its user.

- ``archive.zip``: every output file of the job in one zip, under plain names in one folder
  ``<job-name>-<id>/`` (``policy_export.onnx``, ``design.json``, ``evaluation.json``, ``curve.json``,
  ``spec.json``, ...) plus ``SHA256SUMS``; no checkpoint. It is streamed from the job store a chunk
  at a time (the server never holds a whole file), and refused (409) when the outputs together are
  larger than ``MODSAT_MAX_ARCHIVE_BYTES`` (default 1 GiB; the files stay downloadable one by one).
- ``outcome``: the few figures a user compares jobs by (the jobs list shows them): success at the
  mission's tolerance in the final evaluation, and for co-design the kept design's objective, or
  for a trade-off the kept design's mass and median settling time.

Routes stay short: the SQL is in worker/store/.
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Iterator
from typing import Any

from fastapi import APIRouter, HTTPException
from fastapi.responses import StreamingResponse
from pydantic import BaseModel, Field

from ..deps import SettingsDep, StoreDep
from ..schemas import JobId, safe_file_name

router = APIRouter(prefix="/api/jobs", tags=["jobs"])

#: Files that do not shrink (binary or already compressed) are stored, the rest deflated.
_STORED = (".pt", ".pt2", ".onnx", ".png", ".viser", ".zip")
_ERRORS: dict[int | str, dict[str, Any]] = {404: {"description": "Unknown job, or a job with no output files yet"}}


def archive_folder(job_id: int, name: str | None) -> str:
    """``<job-name>-<id>``: the name made safe for any file system (``modsat-job-<id>`` without one)."""
    stem = safe_file_name(name or "", limit=60) or "modsat-job"
    return f"{stem}-{job_id}"


class _Sink:
    """A write-only file for :class:`zipfile.ZipFile` that hands what was written to a generator."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []
        self.offset = 0

    def write(self, data: bytes) -> int:
        self.parts.append(bytes(data))
        self.offset += len(data)
        return len(data)

    def tell(self) -> int:
        return self.offset

    def flush(self) -> None:
        pass

    def take(self) -> bytes:
        out, self.parts = b"".join(self.parts), []
        return out


def _zip_stream(store, job_id: int, folder: str, files: list[dict[str, Any]]) -> Iterator[bytes]:
    sink = _Sink()
    with zipfile.ZipFile(sink, "w", allowZip64=True) as zf:  # type: ignore[call-overload]  # a non-seekable sink
        for f in files:
            method = zipfile.ZIP_STORED if f["name"].endswith(_STORED) else zipfile.ZIP_DEFLATED
            info = zipfile.ZipInfo(f"{folder}/{f['name']}", date_time=(2024, 1, 1, 0, 0, 0))
            info.compress_type = method
            info.external_attr = 0o644 << 16
            with zf.open(info, "w", force_zip64=int(f["size"]) > 0x7FFF0000) as out:
                sent = 0
                for chunk in store.iter_artifact(job_id, f["name"], int(f["size"]), f["sha256"]):
                    out.write(chunk)
                    sent += len(chunk)
                    yield sink.take()
                if sent != int(f["size"]):  # deleted or replaced while zipping: end the stream broken, never short
                    raise RuntimeError(f"{f['name']} changed while it was being zipped")
            yield sink.take()
        sums = "".join(f"{f['sha256']}  {f['name']}\n" for f in files)
        zf.writestr(f"{folder}/SHA256SUMS", sums, compress_type=zipfile.ZIP_DEFLATED)
    yield sink.take()


@router.get(
    "/{job_id}/archive.zip",
    responses={
        **_ERRORS,
        200: {"content": {"application/zip": {}}, "description": "The job's output files in one zip"},
        409: {"description": "The outputs are larger than MODSAT_MAX_ARCHIVE_BYTES: download them one by one"},
    },
)
def download_archive(job_id: JobId, store: StoreDep, settings: SettingsDep) -> StreamingResponse:
    """Every output file of the job (no checkpoint) in one zip, in a folder `<job-name>-<id>/` with the
    files' plain names and their `SHA256SUMS`. 404 for a job with no output files yet."""
    row = store.get_job(job_id)
    if row is None:
        raise HTTPException(404, f"no job with id {job_id}")
    files = [f for f in store.list_artifacts(job_id) if f["kind"] == "output"]
    if not files:
        raise HTTPException(
            404, f"job {job_id} has no output files yet ({row['status']}): the archive comes when the run has succeeded"
        )
    total, limit = sum(int(f["size"]) for f in files), settings.max_archive_bytes
    if total > limit:
        raise HTTPException(
            409,
            f"job {job_id}'s outputs are {total:,} bytes, more than this server zips ({limit:,}, "
            f"MODSAT_MAX_ARCHIVE_BYTES); download them one by one from /api/jobs/{job_id}/artifacts",
        )
    folder = archive_folder(job_id, row["name"])
    return StreamingResponse(
        _zip_stream(store, job_id, folder, files),
        media_type="application/zip",
        headers={"Content-Disposition": f'attachment; filename="{folder}.zip"', "Cache-Control": "no-cache"},
    )


class Outcome(BaseModel):
    """What a finished job gave: the figures the jobs list compares."""

    job_id: int
    tolerance_deg: float | None = Field(description="The mission's pointing tolerance.")
    success_rate: float | None = Field(description="Final evaluation: the policy's success at the tolerance, 0..1.")
    episodes: int | None = Field(description="Slews of the final evaluation.")
    objective_s: float | None = Field(
        None, description="diffsim-codesign: the kept design's objective on the validation slews (s, lower is better)."
    )
    mass_kg: float | None = Field(None, description="Trade-off: the kept design's mass.")
    median_settling_s: float | None = Field(None, description="Trade-off: the kept design's median settling time.")
    meets_requirements: bool | None = Field(None, description="Trade-off: whether the kept design meets them.")


def _json_file(store, job_id: int, name: str) -> Any:
    data = store.read_artifact(job_id, name)
    try:
        return None if data is None else json.loads(data)
    except ValueError:
        return None


def _kept_of(curve: dict[str, Any], grid: Any) -> dict[str, Any]:
    """The kept design's figures in ``curve.json``: a trade-off's front point, a co-design's candidate."""
    out: dict[str, Any] = {}
    kept = curve.get("kept") if isinstance(curve.get("kept"), dict) else None
    if kept is not None and isinstance(curve.get("front"), list):
        point = next((p for p in curve["front"] if isinstance(p, dict) and p.get("grid") == kept.get("grid")), None)
        if point is not None:
            out.update(mass_kg=point.get("mass_kg"), median_settling_s=point.get("median_settling_s"))
        out["meets_requirements"] = kept.get("meets_requirements")
        return out
    selection = [s for s in curve.get("selection") or [] if isinstance(s, dict) and "objective_s" in s]
    if selection:
        match = [s for s in selection if grid is not None and s.get("grid") == grid]
        out["objective_s"] = (match or [min(selection, key=lambda s: s["objective_s"])])[0]["objective_s"]
    return out


@router.get("/{job_id}/outcome", response_model=Outcome, responses={404: {"description": "Unknown job"}})
def job_outcome(job_id: JobId, store: StoreDep) -> Outcome:
    """Success at the mission's tolerance from the final evaluation (not a curve point's return), and the
    kept design's objective (co-design) or mass and settling (trade-off). Nulls before the run ends."""
    row = store.get_job(job_id)
    if row is None:
        raise HTTPException(404, f"no job with id {job_id}")
    spec = json.loads(row["spec"])
    summary = json.loads(row["summary"]) if row["summary"] else {}
    policy = (summary or {}).get("policy") or {}
    out: dict[str, Any] = {
        "job_id": job_id,
        "tolerance_deg": (spec.get("mission") or {}).get("tolerance_deg"),
        "success_rate": policy.get("success_rate"),
        "episodes": policy.get("episodes"),
    }
    if row["status"] == "succeeded" and str(row["algorithm"]).endswith("codesign"):
        curve = _json_file(store, job_id, "curve.json")
        design = _json_file(store, job_id, "design.json")
        if isinstance(curve, dict):
            out.update(_kept_of(curve, design.get("grid") if isinstance(design, dict) else None))
    return Outcome(**out)
