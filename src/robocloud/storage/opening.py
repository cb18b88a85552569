"""``open_store``: the request store a URL names."""

from __future__ import annotations

from robocloud.storage.memory import MemoryRequestStore
from robocloud.storage.sql import SqlRequestStore
from robocloud.storage.store import RequestStore

MEMORY_URL = "memory://"


def open_store(url: str) -> RequestStore:
    """``memory://`` (nothing kept), ``sqlite:///FILE`` or ``postgresql+psycopg://...``.

    Raises ``InvalidInput`` for any other URL and ``StoreUnavailable`` when the
    database cannot be reached; the tables are created if missing.
    """
    if url.strip() == MEMORY_URL:
        return MemoryRequestStore()
    return SqlRequestStore(url)
