"""Node loggers that print like ROS 2's console output: ``[INFO] [stamp] [node]: message``."""

from __future__ import annotations

import logging as _pylogging
import sys
import time

LEVELS = {"debug": _pylogging.DEBUG, "info": _pylogging.INFO, "warn": _pylogging.WARNING,
          "warning": _pylogging.WARNING, "error": _pylogging.ERROR, "fatal": _pylogging.CRITICAL}
_NAMES = {_pylogging.DEBUG: "DEBUG", _pylogging.INFO: "INFO", _pylogging.WARNING: "WARN",
          _pylogging.ERROR: "ERROR", _pylogging.CRITICAL: "FATAL"}


class _RosFormatter(_pylogging.Formatter):
    def format(self, record: _pylogging.LogRecord) -> str:
        stamp = f"{record.created:.9f}" if record.created else f"{time.time():.9f}"
        return f"[{_NAMES.get(record.levelno, record.levelname)}] [{stamp}] [{record.name}]: " \
               f"{record.getMessage()}"


_handler = _pylogging.StreamHandler(sys.stderr)
_handler.setFormatter(_RosFormatter())


class RcutilsLogger:
    """The object ``node.get_logger()`` returns; method names follow rclpy (``warn`` too)."""

    def __init__(self, name: str, level: str = "info") -> None:
        self.name = name
        self._log = _pylogging.getLogger(f"ros.{name}")
        self._log.name = name
        if _handler not in self._log.handlers:
            self._log.addHandler(_handler)
        self._log.propagate = False
        self.set_level(level)

    def set_level(self, level: str) -> None:
        if level.lower() not in LEVELS:
            raise ValueError(f"unknown log level {level!r}; use one of {sorted(LEVELS)}")
        self._log.setLevel(LEVELS[level.lower()])

    def debug(self, msg: str) -> None:
        self._log.debug(msg)

    def info(self, msg: str) -> None:
        self._log.info(msg)

    def warning(self, msg: str) -> None:
        self._log.warning(msg)

    warn = warning

    def error(self, msg: str) -> None:
        self._log.error(msg)

    def fatal(self, msg: str) -> None:
        self._log.critical(msg)
