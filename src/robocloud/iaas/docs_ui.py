"""The API's docs page, Swagger UI at ``/docs``, from files the IaaS serves itself.

FastAPI's own ``/docs`` loads Swagger UI's script and style from a CDN, so on a
field network without the Internet the page is blank. Here they come from the
``swagger-ui-bundle-v2`` package (Swagger UI 5, which reads the OpenAPI 3.1
FastAPI writes), served under ``/docs/assets/``; the page names no other host.
ReDoc has no such package, so ``/redoc`` stays off.

``create_app`` turns FastAPI's pages off (``docs_url=None, redoc_url=None``)
and calls ``install_docs(app)``.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import FastAPI
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse
from swagger_ui_bundle import swagger_ui_path

from robocloud.errors import NotFound

DOCS_URL = "/docs"
ASSETS_URL = "/docs/assets"
# The only files of the bundle the page uses; the bundle's own index.html and
# swagger-initializer.js (which points at a demo API on the Internet) are not served.
ASSETS = {
    "swagger-ui-bundle.js": "text/javascript; charset=utf-8",
    "swagger-ui.css": "text/css; charset=utf-8",
    "favicon-32x32.png": "image/png",
}


def install_docs(app: FastAPI) -> None:
    """Serve Swagger UI for ``app``'s OpenAPI document at ``/docs``, assets included."""
    folder = Path(str(swagger_ui_path))
    openapi_url = app.openapi_url or "/openapi.json"

    @app.get(DOCS_URL, include_in_schema=False)
    async def docs() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url=openapi_url,
            title=f"{app.title}: API docs",
            swagger_js_url=f"{ASSETS_URL}/swagger-ui-bundle.js",
            swagger_css_url=f"{ASSETS_URL}/swagger-ui.css",
            swagger_favicon_url=f"{ASSETS_URL}/favicon-32x32.png",
            # No badge from the online validator: that would be a request off this host.
            swagger_ui_parameters={"validatorUrl": None},
        )

    @app.get(ASSETS_URL + "/{name}", include_in_schema=False)
    async def asset(name: str) -> FileResponse:
        if name not in ASSETS:
            raise NotFound(f"there is no docs asset {name!r}.", key=name)
        return FileResponse(folder / name, media_type=ASSETS[name])
