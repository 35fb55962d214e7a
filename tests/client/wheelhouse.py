"""Wheels of distributions installed here, so a fresh venv can install offline what a requirement pulls.

A test that proves what ``pip install graytrack`` brings needs pip to resolve and install from
wheels, without the network (CI may be offline; the pip cache is not a wheel directory). pip wrote
each installed distribution's files and metadata into ``*.dist-info`` (RECORD lists the files,
WHEEL its tag), so a wheel of it is those files zipped again with a fresh RECORD. Only the
distributions a requirement needs are packed (:func:`closure`), found by the same metadata and
markers pip evaluates.
"""

from __future__ import annotations

import base64
import hashlib
import sysconfig
import zipfile
from importlib.metadata import Distribution
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

DROPPED = {"RECORD", "INSTALLER", "REQUESTED", "direct_url.json"}  # pip writes these at install time


def installed(name: str) -> Distribution:
    """``name`` as pip installed it in this environment (not an ``*.egg-info`` a checkout on sys.path has)."""
    paths = sorted({sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]})
    found = list(Distribution.discover(name=name, path=paths))
    assert found, f"{name} is not installed in {paths}"
    return found[0]


def closure(requirements: list[str]) -> dict[str, Distribution]:
    """The installed distributions ``requirements`` need, transitively, by canonical name."""
    found: dict[str, Distribution] = {}
    expanded: set[tuple[str, str]] = set()  # (distribution, extra) whose requirements are queued
    pending = [(Requirement(text), "") for text in requirements]
    while pending:
        requirement, extra = pending.pop()
        if requirement.marker is not None and not requirement.marker.evaluate({"extra": extra}):
            continue
        name = canonicalize_name(requirement.name)
        found.setdefault(name, installed(requirement.name))
        for wanted in {"", *requirement.extras} - {e for n, e in expanded if n == name}:
            expanded.add((name, wanted))
            pending.extend((Requirement(text), wanted) for text in found[name].requires or [])
    return found


def _tag(dist: Distribution) -> str:
    wheel = dist.read_text("WHEEL") or ""
    tags = [line.split(":", 1)[1].strip() for line in wheel.splitlines() if line.startswith("Tag:")]
    return tags[0] if tags else "py3-none-any"


def _record_line(name: str, data: bytes) -> str:
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"{name},sha256={digest},{len(data)}"


def pack(dist: Distribution, folder: Path) -> Path:
    """``dist`` as a wheel in ``folder``: its files under site-packages, its dist-info, a new RECORD."""
    name = dist.metadata["Name"].replace("-", "_")
    path = folder / f"{name}-{dist.version}-{_tag(dist)}.whl"
    info = None
    records = []
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as wheel:
        for file in dist.files or []:
            parts = Path(file).parts
            if parts[0] == ".." or "__pycache__" in parts:  # scripts (pip makes them again), bytecode
                continue
            if parts[0].endswith(".dist-info"):
                info = parts[0]
                if parts[-1] in DROPPED:
                    continue
            data = Path(dist.locate_file(file)).read_bytes()
            wheel.writestr(str(file), data)
            records.append(_record_line(str(file), data))
        assert info is not None, f"{dist.metadata['Name']}: no dist-info in its RECORD"
        wheel.writestr(f"{info}/RECORD", "\n".join(records + [f"{info}/RECORD,,"]) + "\n")
    return path
