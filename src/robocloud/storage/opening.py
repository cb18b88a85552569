"""``open_store``: the request store a URL names; ``check_store_url``: the same, opening nothing.

The folder rule: robocloud never creates the folder of a SQLite file. A
mistyped path (``sqlite:////srv/robocloud/cluod-a.db``) is an error with a
sentence, not a new empty store in a folder tree nobody meant to make. (The
command line creates one folder itself, ``var/``, for the default store it
picks when none is given; see ``robocloud.cli.iaas_command``.)
"""

from __future__ import annotations

import re
from pathlib import Path

from robocloud.errors import InvalidInput
from robocloud.storage.engine import URL_HINT, database_url
from robocloud.storage.memory import MemoryRequestStore
from robocloud.storage.sql import SqlRequestStore
from robocloud.storage.store import RequestStore

MEMORY_URL = "memory://"

# user:password@ in a URL that may not even parse: the password is never echoed.
_PASSWORD = re.compile(r"(//[^/:@]*:)[^/@]*@")


def masked(url: str) -> str:
    """``url`` with any password replaced by ``***``."""
    return _PASSWORD.sub(r"\1***@", url)


def check_store_url(url: str) -> None:
    """Raise ``InvalidInput`` with a sentence for a URL ``open_store`` cannot open.

    Opens nothing and reaches no server: the form of the URL, and for SQLite
    that the file's folder exists and the path is not itself a folder.
    Whether a PostgreSQL server answers is only known by ``open_store``.
    """
    if url.strip() == MEMORY_URL:
        return
    try:
        parsed = database_url(url)
    except InvalidInput:
        raise InvalidInput(
            f"store URL {masked(url)!r} is not a supported database URL; "
            f"{URL_HINT}, or {MEMORY_URL} for a store in memory.",
            "store_url",
        ) from None
    if parsed.get_backend_name() != "sqlite":
        return
    path = Path(parsed.database or "")
    if not path.parent.is_dir():
        raise InvalidInput(
            f"the folder {path.parent} of the store {path} does not exist; "
            "create it first (robocloud does not create a store's folder).",
            "store_url",
        )
    if path.is_dir():
        raise InvalidInput(
            f"the store {path} is a folder; name a file in it, e.g. sqlite:///{path / 'cloud.db'}.",
            "store_url",
        )


def open_store(url: str) -> RequestStore:
    """``memory://`` (nothing kept), ``sqlite:///FILE`` or ``postgresql+psycopg://...``.

    Raises ``InvalidInput`` for an unsupported URL and ``StoreUnavailable``
    when the database cannot be reached or the SQLite file's folder is
    missing; the tables are created if missing. A command checks its store
    URL with ``check_store_url`` first, so a mistyped one is the user's error.
    """
    if url.strip() == MEMORY_URL:
        return MemoryRequestStore()
    return SqlRequestStore(url)
