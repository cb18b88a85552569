"""``/docs``: Swagger UI from files the IaaS serves itself, naming no other host."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from swagger_ui_bundle import swagger_ui_path

from robocloud.fleet import MemoryRobotLink
from robocloud.iaas.app import create_app
from robocloud.iaas.config import Settings
from robocloud.iaas.docs_ui import ASSETS, ASSETS_URL
from robocloud.storage import MemoryRequestStore

LINK = re.compile(r"""(?:src|href)\s*=\s*["']([^"']+)["']""")


@pytest.fixture
def client() -> Iterator[TestClient]:
    app = create_app(
        Settings(cloud="cloud-a", selection_workers=0),
        store=MemoryRequestStore(),
        link=MemoryRobotLink("cloud-a", []),
    )
    with TestClient(app) as c:
        yield c


def test_the_page_names_no_other_host_and_every_asset_loads(client: TestClient) -> None:
    page = client.get("/docs")
    assert page.status_code == 200
    assert page.headers["content-type"].startswith("text/html")
    html = page.text
    assert "http://" not in html and "https://" not in html and "//cdn" not in html
    links = LINK.findall(html)
    assert sorted(links) == sorted(f"{ASSETS_URL}/{name}" for name in ASSETS)
    for link in links:
        asset = client.get(link)
        assert asset.status_code == 200, link
        assert asset.headers["content-type"] == ASSETS[link.rsplit("/", 1)[1]]
        assert asset.content == (Path(str(swagger_ui_path)) / link.rsplit("/", 1)[1]).read_bytes()
    assert "url: '/openapi.json'" in html
    assert '"validatorUrl": null' in html  # no badge fetched from the online validator


def test_the_openapi_document_the_page_reads_is_served(client: TestClient) -> None:
    document = client.get("/openapi.json").json()
    assert document["openapi"].startswith("3.1")  # what Swagger UI 5 reads
    assert "/v1/requests" in document["paths"]
    assert "/docs" not in document["paths"]


@pytest.mark.parametrize(
    "path",
    [
        f"{ASSETS_URL}/swagger-initializer.js",  # in the bundle, points at a demo API online
        f"{ASSETS_URL}/index.html",
        f"{ASSETS_URL}/..%2F__init__.py",
        f"{ASSETS_URL}/nothing.js",
    ],
)
def test_only_the_page_s_assets_are_served(client: TestClient, path: str) -> None:
    answer = client.get(path)
    assert answer.status_code == 404
    assert answer.json()["detail"].endswith(".")


def test_redoc_is_off_rather_than_blank(client: TestClient) -> None:
    assert client.get("/redoc").status_code == 404
