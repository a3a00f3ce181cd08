"""The live tracking server (``mptrack serve``, docs/serve.md): phones and trackers report fixes in
the formats their apps already speak (OsmAnd / Traccar Client, OwnTracks, Overland, bulk NDJSON/CSV);
every device's fixes go through the tracking engine's gated filter as they arrive, are committed durably
with their estimates, and can be queried (current estimate, prediction, stored or smoothed track),
streamed (Server-Sent Events) and watched on a live map.  With a cell table (``--cells``) it answers
cell geolocation requests (``POST /v1/geolocate``, Google's and Ichnaea's format), and devices that
report cells instead of positions get tracks too; :func:`geolocate_requests` answers a file of such
requests offline, the same way.

Run it with ``mptrack serve``, or in Python with uvicorn::

    import uvicorn
    from mptrack.serve import ServeConfig, create_app
    uvicorn.run(create_app(ServeConfig(db="sqlite:///fleet.db")), port=5055)
"""

from ..errors import ParameterError
from ._app import ServeConfig, config_environment, create_app
from ._auth import digest, new_secret
from ._copy import copy_database
from ._database import open_store
from ._metrics import METRICS_ENV, create_metrics_file
from ._postgres import shown_url
from ._store import DEFAULT_DB

__all__ = ["ServeConfig", "create_app", "add_device", "add_api_key", "copy_database", "open_store", "shown_url",
           "worker_environment", "geolocate_requests", "WORKER_APP", "DEFAULT_DB"]

#: The most worker processes of one server (each holds its share of the devices' live state).
MAX_WORKERS = 256

#: The application factory uvicorn runs in each worker of ``mptrack serve --workers N``.
WORKER_APP = "mptrack.serve._app:app_from_environment"


def worker_environment(config: ServeConfig, directory: str, workers: int) -> dict[str, str]:
    """The environment that hands a configuration to the worker processes of :data:`WORKER_APP`.

    Parameters
    ----------
    config : ServeConfig
    directory : str
        Where the file of the workers' shared counters is created.
    workers : int
        How many worker processes.

    Returns
    -------
    dict
        Environment variables to set before uvicorn starts the workers.
    """
    import os

    from .._core.validation import check_int, check_path

    if not isinstance(config, ServeConfig):
        raise ParameterError(f"config: expected a ServeConfig, got {type(config).__name__}")
    workers = check_int("workers", workers, minimum=1, maximum=MAX_WORKERS)
    if not os.path.isdir(check_path("directory", directory)):
        raise ParameterError(f"directory: {directory} is not a directory")
    path = os.path.join(directory, "metrics")
    create_metrics_file(path, 2 * workers)   # room for restarted workers beside the dying ones
    return {**config_environment(config), METRICS_ENV: path}


def add_device(db: str, name: str) -> str:
    """Register a device in the server database and return its new token.

    Parameters
    ----------
    db : str
        The database URL.
    name : str
        The device's name.

    Returns
    -------
    str
        The token (only its SHA-256 is stored).
    """
    from ._fix import device_id

    token = new_secret()
    store = open_store(db)
    try:
        store.add_device(device_id(name, "name"), digest(token))
    finally:
        store.close()
    return token


def add_api_key(db: str, name: str) -> str:
    """Create an API key in the server database and return it.

    Parameters
    ----------
    db : str
        The database URL (``sqlite:///path`` or ``postgresql://...``).
    name : str
        A name for the key.

    Returns
    -------
    str
        The key (only its SHA-256 is stored).
    """
    if not isinstance(name, str) or not name.strip():
        from ..errors import ParameterError

        raise ParameterError(f"name: expected a non-empty name, got {name!r}")
    key = new_secret()
    store = open_store(db)
    try:
        store.add_api_key(name.strip(), digest(key))
    finally:
        store.close()
    return key


def geolocate_requests(requests, *, cells=None, db: str | None = None):
    """Answer a file of cell geolocation requests as ``POST /v1/geolocate`` of ``mptrack serve`` does.

    Parameters
    ----------
    requests : str or path-like
        An NDJSON file: one request body (Google's / Ichnaea's geolocate JSON) per line; empty lines are
        skipped.
    cells : str or path-like, optional
        A cell table (OpenCelliD layout, CSV or CSV.gz) to load into the database (again only when the
        file changed).
    db : str, optional
        The database holding the cell table (``sqlite:///PATH``, e.g. the server's); None: a temporary
        one, removed afterwards (then ``cells`` is needed).

    Yields
    ------
    line, status, answer : int, int, dict
        Per request: its line number, the HTTP status the server would answer (200, 400 or 404) and the
        answer's JSON object (the position, or the error in Google's format).

    Raises
    ------
    ParameterError
        A missing file, or neither ``cells`` nor a database holding a table.
    """
    import json
    import shutil
    import tempfile
    from pathlib import Path

    from .._core.validation import check_path
    from ..errors import ParameterError, RequestError
    from ._celltable import load_cell_table
    from ._geolocate import Geolocator, answer_body, error_body, parse_request

    path = check_path("requests", requests)
    if not path.is_file():
        raise ParameterError(f"requests: {path} is not a file")
    if cells is not None:
        check_path("cells", cells)
    tmp = None
    if db is None:
        if cells is None:
            raise ParameterError("cells: a cell table is needed (or db, a database that holds one)")
        tmp = tempfile.mkdtemp(prefix="mptrack-geolocate-")
        db = f"sqlite:///{Path(tmp) / 'cells.db'}"
    store = open_store(db)
    try:
        if cells is not None:
            load_cell_table(store, cells)
        elif store.cell_source() is None:
            raise ParameterError(f"db: {db} holds no cell table; give one with cells")
        geo = Geolocator(store)
        with open(path, "rb") as f:
            for number, raw in enumerate(f, 1):
                if not raw.strip():
                    continue
                try:
                    status, body = 200, answer_body(geo.locate(parse_request(raw)))
                except RequestError as exc:
                    status, body = exc.status, error_body(exc)
                yield number, status, json.loads(body)
    finally:
        store.close()
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
