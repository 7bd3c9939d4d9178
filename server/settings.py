"""Settings of the API server (env prefix ``MODSAT_``); the queue settings come from
:class:`worker.settings.WorkerSettings`. docs/service.md has the table."""

from __future__ import annotations

from pydantic import Field, SecretStr, field_validator

from web.viewer.origin import host_names
from worker.settings import WorkerSettings


class ServerSettings(WorkerSettings):
    """Everything ``modsat serve`` reads; workers ignore the API fields."""

    api_token: SecretStr | None = Field(
        None, description="If set, POST requests need `Authorization: Bearer <token>`. Reads stay open."
    )
    max_body_bytes: int = Field(
        1_048_576, ge=1024, le=1 << 30, description="Largest request body accepted (413 above it)."
    )
    host: str = Field("127.0.0.1", description="Address `modsat serve` listens on.")
    port: int = Field(8000, ge=0, le=65535, description="Port `modsat serve` listens on.")
    sse_poll_s: float = Field(0.5, gt=0, le=60, description="How often an event stream looks for news.")
    sse_keepalive_s: float = Field(15.0, gt=0, le=600, description="Comment line sent on a quiet event stream.")
    sse_max_s: float = Field(
        3600.0, gt=0, le=86_400, description="An event stream ends after this long (clients reconnect)."
    )
    viewer: bool = Field(True, description="Run the live 3D viewer (viser) inside the API process.")
    viewer_port: int = Field(
        8080,
        ge=0,
        le=65535,
        description="Port of the live 3D viewer; 0 = any free port. A busy port moves it up (see GET /api/viewer).",
    )
    allowed_hosts: str = Field(
        "",
        description="Comma-separated extra host names (or IP addresses) the server answers to, besides "
        "localhost, 127.0.0.1, ::1 and `host`; `*` = any. Other `Host` headers get 400 (DNS rebinding).",
    )
    allowed_origins: str = Field(
        "",
        description="Comma-separated extra origins (e.g. `https://ops.example.org`) whose pages may write "
        "(POST, DELETE). A browser write from any other origin is 403; the page itself is same-origin.",
    )
    max_active_jobs: int = Field(
        100, ge=1, le=1_000_000, description="Queued plus running jobs; a submission beyond it is 429."
    )
    max_archive_bytes: int = Field(
        1 << 30,
        ge=1,
        le=1 << 40,
        description="Largest job archive served (`archive.zip`), bytes of its files before compression; larger "
        "is 409 (the files stay downloadable one by one).",
    )
    web_dir: str | None = Field(
        None, description="Directory of the web UI's files (default: web/static/, installed with the package)."
    )

    @field_validator("api_token")
    @classmethod
    def _token_not_empty(cls, v: SecretStr | None) -> SecretStr | None:
        if v is not None and not v.get_secret_value().strip():
            raise ValueError("MODSAT_API_TOKEN is set but empty: unset it for an open server, or give a token")
        return v

    def host_names(self) -> set[str] | None:
        """Host names the server answers to (lower case, no port), or None for any."""
        return host_names(self.host, self.allowed_hosts)

    def origin_list(self) -> set[str]:
        return {o.strip().rstrip("/").lower() for o in self.allowed_origins.split(",") if o.strip()}
