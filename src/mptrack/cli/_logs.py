"""Log lines of the server's processes: text, or one JSON object a line (``mptrack serve --log-format
json``) for log collectors."""

from __future__ import annotations

import json
import logging
import time

__all__ = ["JsonFormatter", "log_config_of"]


class JsonFormatter(logging.Formatter):
    """Log records as one JSON object a line: time (ISO 8601 UTC), level, logger, message, pid, and
    the record's extra fields."""

    _PLAIN = set(vars(logging.LogRecord("", 0, "", 0, "", (), None))) | {"message", "asctime", "color_message"}

    def format(self, record: logging.LogRecord) -> str:
        out = {"time": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created)) + f".{int(record.msecs):03d}Z",
               "level": record.levelname.lower(), "logger": record.name, "message": record.getMessage(),
               "pid": record.process}
        out.update({k: v for k, v in vars(record).items() if k not in self._PLAIN})
        if record.exc_info:
            out["exception"] = self.formatException(record.exc_info)
        return json.dumps(out, default=str)


def log_config_of(fmt: str, level: str) -> dict:
    """logging's dictConfig of the server's processes (uvicorn applies it in each worker)."""
    formatter = ({"()": "mptrack.cli._logs.JsonFormatter"} if fmt == "json"
                 else {"format": "%(asctime)s %(levelname)s %(name)s: %(message)s"})
    handler = {"class": "logging.StreamHandler", "formatter": "main", "stream": "ext://sys.stderr"}
    loggers = {name: {"handlers": ["main"], "level": level, "propagate": False}
               for name in ("mptrack", "uvicorn", "uvicorn.error")}
    loggers["uvicorn.access"] = {"handlers": ["main"], "level": "WARNING", "propagate": False}
    return {"version": 1, "disable_existing_loggers": False, "formatters": {"main": formatter},
            "handlers": {"main": handler}, "loggers": loggers}
