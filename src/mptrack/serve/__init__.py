"""The live tracking server (``mptrack serve``, docs/serve.md): phones and trackers report fixes in
the formats their apps already speak (OsmAnd / Traccar Client, OwnTracks, bulk NDJSON/CSV); every
device's fixes go through the tracking engine's gated filter as they arrive, are committed durably
with their estimates, and can be queried (current estimate, prediction, stored or smoothed track),
streamed (Server-Sent Events) and watched on a live map.

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
           "worker_environment", "WORKER_APP", "DEFAULT_DB"]

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
