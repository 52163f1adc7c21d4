"""The dashboard server: FastAPI (REST, WebSocket, the page in web/) plus viser (3-D pose view
and gain panel) in the same process. Start it with `gcs serve` or `gcs demo`; embed it with
`gcs.server.dashboard.DashboardServer`."""
