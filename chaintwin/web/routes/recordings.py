"""Recordings: one stored result with its channels; uploads, ingested as ``chaintwin ingest``
would."""

from __future__ import annotations

import hashlib
import math
import re
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import Depends, Form, Request, Response, UploadFile
from fastapi.concurrency import run_in_threadpool

from chaintwin.store.queries import recording_by_hash
from chaintwin.web.access import audit
from chaintwin.web.deps import require_role, web_of
from chaintwin.web.models import RecordingDetail, UploadedFile, UploadForm, UploadResult
from chaintwin.web.security import ApiError, Principal

from .common import fast_json, make_router

__all__ = [
    "PLOT_POINTS",
    "Staged",
    "ingest_uploads",
    "router",
    "stage_uploads",
    "take_uploads",
]

router = make_router("recordings")

PLOT_POINTS = 1000
"""Most samples of a channel returned for plotting (evenly thinned)."""

_upload_lock = threading.Lock()


@router.get("/recordings/{recording_id}", response_model=RecordingDetail)
def recording(
    request: Request,
    recording_id: str,
    _who: Annotated[Principal, Depends(require_role("viewer"))],
) -> Response:
    """A stored result with its measured and model torque and speed, thinned for plotting."""
    if not re.fullmatch(r"[0-9a-f]{64}", recording_id):
        raise ApiError(404, "not_found", f"no recording '{recording_id[:80]}'")
    store = web_of(request).store
    found = recording_by_hash(store, recording_id)
    if found is None:
        raise ApiError(404, "not_found", f"no recording '{recording_id}'")
    result, rec = found
    step = max(1, math.ceil(rec.samples / PLOT_POINTS))
    series: dict[str, Any] = {
        "time_s": rec.time[::step].tolist(),
        "speed_rpm": (rec.speed[::step] * 60.0 / (2.0 * math.pi)).tolist(),
        "torque_nm": rec.torque[::step].tolist(),
        "model_torque_nm": None,
    }
    cal = store.calibration(result["conveyor"])
    payload = result.get("payload_kg")
    if cal is not None and payload is not None:
        from chaintwin.model.rigid import model_torque

        model = model_torque(rec, cal.id_profile, cal.parameters, float(payload))
        series["model_torque_nm"] = np.asarray(model)[::step].tolist()
    return fast_json({"result": result, "series": series})


_SAFE_NAME = re.compile(r"[^A-Za-z0-9._-]+")


@dataclass(frozen=True, slots=True)
class Staged:
    """An uploaded file copied to the upload's folder: its name as sent, path and SHA-256."""

    name: str
    path: str
    sha256: str


def ingest_uploads(web: Any, staged: list[Staged], who_name: str) -> list[UploadedFile]:
    """Store staged uploads exactly as ``chaintwin ingest`` would; what became of each."""
    from chaintwin.ingest.pipeline import ingest

    profiles = {cid: p for cid in web.store.conveyors() if (p := web.store.profile(cid))}
    live = web.extra.get("live")
    # the live service follows --profiles and reads a changed folder again
    profiles |= live.profiles_now if live is not None else web.profiles
    out: list[UploadedFile] = []
    with _upload_lock:
        known = web.store.known(f.sha256 for f in staged)
        summary = ingest([f.path for f in staged], profiles, web.store, workers=1)
    refused = {r["file"]: r["error"] for r in summary.refusals}
    for f in staged:
        if f.path in refused:
            reason = refused[f.path].replace(f.path, f.name)
            out.append(
                UploadedFile(file=f.name, status="refused", reason=reason, recording_id=None)
            )
        else:
            status: Literal["stored", "already_stored"] = (
                "already_stored" if f.sha256 in known else "stored"
            )
            out.append(UploadedFile(file=f.name, status=status, reason=None, recording_id=f.sha256))
    audit(
        web.store,
        who_name,
        "upload",
        {"files": [f.file for f in out], "stored": sum(f.status == "stored" for f in out)},
    )
    return out


_COPY_CHUNK = 1024 * 1024
"""Bytes copied at a time from an upload to its file (never a whole file in memory)."""


def stage_uploads(web: Any, files: list[UploadFile], folder: Path) -> list[Staged]:
    """Copy the uploaded files into ``folder`` chunk by chunk; ApiError 413 beyond the limit.

    The files arrive spooled by the multipart parser (in memory up to 1 MB,
    then in a temporary file), their total already bounded by the guard
    (:mod:`chaintwin.web.guard`); this copies them under their own names for
    ingest, hashing as it goes.
    """
    staged: list[Staged] = []
    total = 0
    for k, f in enumerate(files):
        name = f.filename or "upload.csv"
        base = _SAFE_NAME.sub("_", Path(name).name)[-120:] or "upload.csv"
        path = folder / f"{k:03d}-{base}"
        digest = hashlib.sha256()
        f.file.seek(0)
        with path.open("xb") as out:
            while chunk := f.file.read(_COPY_CHUNK):
                total += len(chunk)
                if total > web.max_upload_bytes:
                    raise ApiError(
                        413,
                        "too_large",
                        f"the upload is larger than {web.max_upload_bytes / (1024 * 1024):g} "
                        "MB; send fewer files at once",
                    )
                digest.update(chunk)
                out.write(chunk)
        staged.append(Staged(name, str(path), digest.hexdigest()))
    return staged


async def take_uploads(
    request: Request, files: list[UploadFile], who_name: str, fields: frozenset[str]
) -> list[UploadedFile]:
    """Check an upload's parts, copy its files aside, ingest them; what became of each.

    Every part must be a file named ``files``, or one of ``fields`` (the
    page's ``csrf``): anything else is refused (422) before a byte is stored.
    """
    web = web_of(request)
    form = await request.form()  # parsed already for the handler's parameters
    for key, value in form.multi_items():
        if key == "files" and isinstance(value, str):
            raise ApiError(
                422, "invalid", "files: a part named 'files' is not a file; send files only"
            )
        if key != "files" and key not in fields:
            raise ApiError(
                422,
                "invalid",
                f"{key[:80]}: not a part of an upload; send the files as 'files' only",
            )
    with tempfile.TemporaryDirectory(prefix="chaintwin-upload-") as folder:
        staged = await run_in_threadpool(stage_uploads, web, files, Path(folder))
        done: list[UploadedFile] = await run_in_threadpool(ingest_uploads, web, staged, who_name)
    return done


@router.post("/recordings", response_model=UploadResult)
async def upload(
    request: Request,
    form: Annotated[UploadForm, Form(media_type="multipart/form-data")],
    who: Annotated[Principal, Depends(require_role("maintainer", changes=True))],
) -> dict[str, Any]:
    """Upload recordings (maintainer), ingested as ``chaintwin ingest`` would.

    Each file's answer says whether it was ``stored``, ``already_stored`` or
    ``refused``, with its ``recording_id`` (null when refused) and the
    ``reason`` of a refusal. A request without a valid token is refused
    before its body is read; one larger than the upload limit as soon as it
    passes it (413), whether it declared its length or not; a part that is
    not a file named ``files`` 422.
    """
    done = await take_uploads(request, form.files, who.name, frozenset())
    return {"files": [f.model_dump() for f in done]}
