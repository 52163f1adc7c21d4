"""The API routers: `create_app` includes every module listed in ROUTERS (each exposes
`router`, a fastapi.APIRouter). Add yours with one line."""

ROUTERS: list[str] = [
    "gcs.server.routers.page",
    "gcs.server.routers.status",
    "gcs.server.routers.estimates",
    "gcs.server.routers.gains",
    "gcs.server.routers.stream",
    "gcs.server.routers.params",
    "gcs.server.routers.sessions",
    "gcs.server.routers.protocol",
    "gcs.server.routers.logs",
]
