"""``/api/viewer``: where the live 3D viewer listens (it runs in the app's lifespan, server/hosting.py)."""

from __future__ import annotations

from fastapi import APIRouter, Request

from ..schemas import ViewerInfo


def viewer_router() -> APIRouter:
    """A new router of ``GET /api/viewer`` (one per app)."""
    r = APIRouter(prefix="/api")

    @r.get("/viewer", response_model=ViewerInfo, tags=["service"])
    def viewer_info(request: Request) -> ViewerInfo:
        """Where the live 3D viewer listens. Open `/viser-client/?websocket=ws://HOST:PORT/?run=JOB_ID`
        (or `http://HOST:PORT/`); a recording plays at `/viser-client/?playbackPath=URL`."""
        from web.viewer.recording import RECORDING_NAME

        v = getattr(request.app.state, "viewer", None)
        return ViewerInfo(
            enabled=v is not None,
            port=v.port if v is not None else None,
            client="/viser-client/",
            recording=RECORDING_NAME,
        )

    return r
