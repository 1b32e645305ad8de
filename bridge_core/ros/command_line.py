"""rclpy.init from a command line, refused on one line: what rcl cannot parse (an
unknown ROS argument, a bad remap or parameter rule, a params file it cannot read) is one
``error:`` line and exit code 2 in every console script, never rcl's own lines or a
traceback."""

from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
from collections.abc import Iterator, Sequence
from typing import Any

import rclpy
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

# A refused command line or configuration (argparse's code for a command line it refuses).
EXIT_CONFIGURATION_ERROR = 2

# The places in rcl's C sources an rcl error names (", at /project/src/rcl/arguments.c:352").
_RCL_SOURCE_PLACE = re.compile(r", at /\S+:\d+")


@contextlib.contextmanager
def _rcl_log_held() -> Iterator[None]:
    """Hold what rcl writes to stderr (file descriptor 2) inside the block; written out
    after it, unless the block raised: a refused command line is then one line (ours), not
    rcl's "Failed to parse global arguments" as well."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        held.seek(0)
        text = held.read()
    if text:
        sys.stderr.buffer.write(text)
        sys.stderr.flush()


def init_from_command_line(args: Sequence[str] | None, **options: Any) -> str | None:
    """``rclpy.init`` with a command line's ROS arguments: None when it started, else
    what rcl refused, on one line (and nothing of rcl's own on stderr)."""
    try:
        with _rcl_log_held():
            rclpy.init(args=list(args) if args is not None else None, **options)
    except (_rclpy.UnknownROSArgsError, _rclpy.RCLError) as err:
        return command_line_error(err)
    return None


def command_line_error(err: Exception) -> str:
    """What rclpy.init refused on the command line, on one line: an unknown ROS argument,
    a remap or parameter rule rcl cannot parse, a params file it cannot open or parse."""
    if isinstance(err, _rclpy.UnknownROSArgsError):
        return f"unknown ROS arguments: {err}"
    return " ".join(_RCL_SOURCE_PLACE.sub("", str(err)).split())


__all__ = ["EXIT_CONFIGURATION_ERROR", "command_line_error", "init_from_command_line"]
