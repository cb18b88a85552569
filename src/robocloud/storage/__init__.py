"""The request store of one cloud's IaaS: requests, their history, robot reservations.

::

    RequestStore            the seam (a Protocol); every method sync and thread-safe
    ├── SqlRequestStore     SQLite file (default) or PostgreSQL, SQLAlchemy Core
    └── MemoryRequestStore  for fast tests
    open_store(url)         memory://, sqlite:///FILE, postgresql+psycopg://...

    RequestRecord, StateChange   what the store gives back (frozen dataclasses)
    Loan                         a robot lent to another cloud's request (robocloud.federation.home)
    StoreUnavailable             the database cannot be reached (a RoboCloudError)

Layer 3: imports ``robocloud.domain`` and ``robocloud.errors`` only.
"""

from robocloud.storage.memory import MemoryRequestStore
from robocloud.storage.opening import MEMORY_URL, open_store
from robocloud.storage.records import Loan, MissionRow, RequestRecord, StateChange
from robocloud.storage.sql import SqlRequestStore
from robocloud.storage.store import RequestStore, StoreUnavailable

__all__ = [
    "MEMORY_URL",
    "Loan",
    "MemoryRequestStore",
    "MissionRow",
    "RequestRecord",
    "RequestStore",
    "SqlRequestStore",
    "StateChange",
    "StoreUnavailable",
    "open_store",
]
