"""Shared command-line helpers: argument types and one-line errors (exit code 2, no traceback)."""

from __future__ import annotations

import argparse
import os
import sys


class UsageError(Exception):
    """Bad user input: reported as one line, exit code 2."""


def write_json_atomic(path: str, data, **dump_kwargs) -> None:
    """``json.dump(data)`` to ``path`` through a temporary file renamed into place (a kill leaves
    the old file or the new one, never half of one)."""
    import json

    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(data, f, **dump_kwargs)
    os.replace(tmp, path)


def fail(message: str) -> "None":
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def nonnegative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}")
    return value


def check_writable(path: str, what: str) -> None:
    """UsageError unless ``path`` (a file or directory to create) can be created: its nearest
    existing ancestor must be a writable directory. ``what`` names it in the message."""
    parent = os.path.dirname(os.path.abspath(path))
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise UsageError(f"cannot create {what} {path}: {parent} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UsageError(f"cannot write {what} {path}: {parent} is not writable")


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors and exit code 2."""

    def error(self, message):  # noqa: D401
        fail(message)


def main_guard(fn):
    """Run ``fn()``; UsageError / ValueError from user input become a one-line error, exit 2."""
    try:
        return fn()
    except (UsageError, ValueError, FileNotFoundError, PermissionError) as e:
        fail(str(e).splitlines()[0] if str(e) else type(e).__name__)
