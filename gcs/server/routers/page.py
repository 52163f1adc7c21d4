"""GET /: the dashboard page. The start-up URL `/?token=...` trades the token for an HttpOnly,
SameSite=Strict cookie and redirects to `/` (keeping the other parameters, such as `vehicle`): the
page's scripts never see the token, other sites' requests never carry it, and it leaves the address
bar and the browser's history at once."""

from __future__ import annotations

from urllib.parse import urlencode

from fastapi import APIRouter, Request
from fastapi.responses import FileResponse, RedirectResponse, Response

from gcs.server.deps import ClientDep, StationDep, cookie_name, token_matches

router = APIRouter(include_in_schema=False)


@router.get("/")
async def page(request: Request, station: StationDep, client: ClientDep) -> Response:
    token = request.query_params.get("token")
    if token is None:
        return FileResponse(request.app.state.assets.page / "index.html")
    # the page's other parameters stay (?vehicle=2 went, and the page showed the first vehicle)
    rest = urlencode([(k, v) for k, v in request.query_params.multi_items() if k != "token"])
    response = RedirectResponse(f"/?{rest}" if rest else "/", status_code=303, headers={"Cache-Control": "no-store"})
    if token_matches(token, request.app.state.token):
        response.set_cookie(cookie_name(request), token, httponly=True, samesite="strict", path="/")
    else:  # opens read-only, and the wrong token is in the audit log
        station.events.record("refused", client, reason="token", path="/")
    return response
