"""The REST API's routes, one module per resource: jobs (``/api/jobs``), archive
(``/api/jobs/{id}/archive.zip`` and ``/outcome``), studies (``/api/studies``),
service (``/api/presets``, ``/api/schema``, ``/api/health``) and viewer (``/api/viewer``).
server/app.py includes them in this order (the OpenAPI document lists them so)."""
