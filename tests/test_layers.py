"""The layers of docs/design.md, held by the imports themselves: core/ imports nothing above it, a driver
takes of core only the recording format and the JPEG tables it shares with the model's stream bound, and
the clients (graytrack/client, graytrack/bluesky, graytrack/wire.py) import nothing of the daemon, so
they install and run without it. Read from the source (every ``import``, top level or inside a function)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit
REPO = Path(__file__).resolve().parent.parent


def imports(*places: str) -> dict[str, set[str]]:
    """Every ``graytrack.*`` module imported under ``places`` (folders or files), and by which files."""
    found: dict[str, set[str]] = {}
    for place in places:
        path = REPO / place
        for source in ([path] if path.is_file() else sorted(path.rglob("*.py"))):
            for node in ast.walk(ast.parse(source.read_text(), str(source))):
                if isinstance(node, ast.ImportFrom) and node.level == 0:  # what is taken: module.name
                    names = [f"{node.module}.{alias.name}" for alias in node.names]
                else:
                    names = [alias.name for alias in node.names] if isinstance(node, ast.Import) else []
                for name in names:
                    if name.startswith("graytrack"):
                        found.setdefault(name, set()).add(str(source.relative_to(REPO)))
    return found


def outside(found: dict[str, set[str]], *allowed: str) -> dict[str, set[str]]:
    return {name: files for name, files in found.items()
            if not any(name == a or name.startswith(a + ".") for a in allowed)}


def test_core_imports_nothing_above_it() -> None:
    assert outside(imports("core"), "graytrack.core") == {}


def test_a_driver_takes_of_core_only_the_recording_format_and_the_shared_jpeg_tables() -> None:
    assert outside(imports("drivers"), "graytrack.drivers", "graytrack.core.recording", "graytrack.core.compression",
                   "graytrack.__version__") == {}


def test_the_clients_import_nothing_of_the_daemon_nor_of_core_beyond_the_frame_records_table() -> None:
    found = imports("graytrack/client", "graytrack/bluesky", "graytrack/wire.py")
    assert outside(found, "graytrack.client", "graytrack.bluesky", "graytrack.wire", "graytrack.core.frame_record",
                   "graytrack.drivers.stage.gcs_protocol") == {}
