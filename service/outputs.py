"""Checks on where a command will write, made before any work starts.

A command that computes for minutes and then fails to write has wasted the minutes; one that
creates missing folders on its own (even at the root, after a typo) leaves litter nobody asked
for. So an output file must name a file (not an existing folder) in a folder that exists, and an
output folder may be created, but only its last component: its parent must exist.
"""

from __future__ import annotations

import os
from pathlib import Path

from graytrack.service.errors import CliError


def output_file(value: str, flag: str = "--out") -> Path:
    """``value`` as a file to (over)write; refuses folders and missing or unwritable parents."""
    path = Path(value)
    if not value or path.is_dir() or value.endswith(os.sep):
        raise CliError(f"{flag} {value}: is a folder; name the file to write")
    _parent_exists(path, flag)
    if path.exists() and not os.access(path, os.W_OK):
        raise CliError(f"{flag} {value}: exists and cannot be overwritten (permission denied)")
    return path


def output_folder(value: str, flag: str = "--out") -> Path:
    """``value`` as a folder to write into; created if missing, but never its parents."""
    path = Path(value)
    if path.exists() and not path.is_dir():
        raise CliError(f"{flag} {value}: exists and is not a folder")
    if not path.exists():
        _parent_exists(path, flag)
    elif not os.access(path, os.W_OK | os.X_OK):
        raise CliError(f"{flag} {value}: folder is not writable")
    return path


def _parent_exists(path: Path, flag: str) -> None:
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise CliError(f"{flag} {path}: folder {parent} does not exist (create it first; nothing is created for you)")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise CliError(f"{flag} {path}: folder {parent} is not writable")
