"""Log lines at rcutils' price, not at the price of rclpy's caller lookup.

rclpy's ``RcutilsLogger.log`` names each line's call site (function, file, line: what
``/rosout``'s ``Log`` message and the log files carry) by walking the stack with
``inspect.getframeinfo`` — which reads the caller's source line through ``linecache`` — and
``os.path.realpath`` on every frame it passes. Measured on this project's VM: about 220 µs a
line from 25 frames deep, against about 6 µs for the rcutils call itself. An edge serving
fifty devices writes a line or more for each device every slot; py-spy on the edge process at
fifty devices put 7 % of its slot thread in that lookup (``CallerId``), which at that load
grows with the late slots' own warnings.

:class:`SiteLogger` writes the same record through the same rcutils call (the console, the
log file and ``/rosout`` all come from rcutils' output handlers, which rclpy installs at
``init``): severity, logger name, message, and the call site of whoever called the
:class:`SiteLogger` — its function, its file as an absolute path, its line. The file's path is
looked up once per code object. What it leaves out is rclpy's filters (``once``,
``throttle_duration_sec``, ``skip_first``): a line that needs one goes through the node's
logger as before. Where rclpy's binding lacks the call (a release that renamed it), every
line goes through the node's logger.
"""

from __future__ import annotations

import os
import sys
from types import CodeType
from typing import Any

from rclpy.impl.rcutils_logger import RcutilsLogger
from rclpy.logging import LoggingSeverity

try:
    from rclpy.impl.implementation_singleton import rclpy_implementation as _binding
    _RCUTILS_LOG: Any = getattr(_binding, "rclpy_logging_rcutils_log", None)
except ImportError:                                    # pragma: no cover - another rclpy
    _RCUTILS_LOG = None

#: code object → its file as an absolute path (rclpy writes ``os.path.abspath`` of it)
_FILES: dict[CodeType, str] = {}


def _file_of(code: CodeType) -> str:
    path = _FILES.get(code)
    if path is None:
        path = _FILES[code] = os.path.abspath(code.co_filename)
    return path


class SiteLogger:
    """A node logger's ``info``/``warning``/``error``, each line named by the call site
    ``depth`` frames above the method (1: the method's caller)."""

    def __init__(self, logger: RcutilsLogger, depth: int = 1) -> None:
        self.logger = logger
        self.depth = depth

    def info(self, message: str) -> None:
        self._emit(LoggingSeverity.INFO, message)

    def warning(self, message: str) -> None:
        self._emit(LoggingSeverity.WARN, message)

    def error(self, message: str) -> None:
        self._emit(LoggingSeverity.ERROR, message)

    def _emit(self, severity: LoggingSeverity, message: str) -> None:
        logger = self.logger
        if _RCUTILS_LOG is None:
            logger.log(message, severity)
            return
        if not logger.is_enabled_for(severity):
            return
        frame = sys._getframe(self.depth + 1)   # above _emit and the severity's method
        code = frame.f_code
        _RCUTILS_LOG(severity, logger.name, message, code.co_name, _file_of(code),
                     frame.f_lineno)
