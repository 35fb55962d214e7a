"""The client installed alone into a fresh venv (offline), and the daemon as `make run` starts it.

Both are expensive (a venv; a daemon that calibrates itself on the wall clock), so each is shared by
the tests of this folder: the daemon made once per test process while they run, the venv once per
checkout (kept in pytest's cache, keyed by what it is made of).
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import os
import shutil
import subprocess
import sys
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from email.parser import Parser
from pathlib import Path

import httpx
import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

from tests.client.wheelhouse import closure, pack
from tests.conftest import _locked
from tests.service.helpers import free_port, wait_for

ROOT = Path(__file__).resolve().parents[2]
# what a wheel does not need (the Containerfile copies the rest); the checkout's own build files stay out
NOT_SHIPPED = (".*", "__pycache__", "*.egg-info", "build", "tests", "bench", "docs", "examples", "deploy", "*.npz")
ANSWERS_S = 120.0  # a cold first start answers after ~25 s on a busy 2-core machine; CI may be slower


def build_wheel(source: Path, wheels: Path) -> Path:
    """graytrack's wheel in ``wheels``, as ``pip install .`` builds it, from a copy of the checkout in
    ``source`` (nothing is written into the checkout; the backend is this venv's setuptools, so
    nothing is downloaded)."""
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(*NOT_SHIPPED))
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation", "--no-index",
                    "--wheel-dir", str(wheels), str(source)], check=True, capture_output=True, text=True)
    (wheel,) = wheels.glob("graytrack-*.whl")
    return wheel


def base_requirements(wheel: Path) -> list[str]:
    """What installing ``wheel`` without an extra requires: its metadata's Requires-Dist, as pip reads it."""
    with zipfile.ZipFile(wheel) as archive:
        (name,) = [name for name in archive.namelist() if name.endswith(".dist-info/METADATA")]
        metadata = Parser().parsestr(archive.read(name).decode())
    return [text for text in metadata.get_all("Requires-Dist") or []
            if (req := Requirement(text)).marker is None or req.marker.evaluate({"extra": ""})]


@dataclass(frozen=True)
class Venv:
    python: Path
    installed: dict[str, str]  # canonical name: version, of every distribution in the venv

    @property
    def bin(self) -> Path:
        return self.python.parent

    def run(self, *args: str) -> subprocess.CompletedProcess[str]:
        """``args`` (a program of the venv's bin, or ``-c`` code for its python) outside the checkout,
        whose ``graytrack`` folder would otherwise shadow the installed package."""
        program = [str(self.bin / args[0]), *args[1:]] if not args[0].startswith("-") else [str(self.python), *args]
        return subprocess.run(program, cwd=self.bin, capture_output=True, text=True, timeout=60)


def shipped_files(root: Path = ROOT) -> Iterator[Path]:
    """The files :func:`build_wheel` copies from the checkout (the same ignore rules, in a stable order)."""
    ignore = shutil.ignore_patterns(*NOT_SHIPPED)
    for folder, subfolders, names in os.walk(root):
        skipped = ignore(folder, subfolders + names)
        subfolders[:] = sorted(name for name in subfolders if name not in skipped)
        for name in sorted(names):
            if name not in skipped:
                yield Path(folder) / name


def client_venv_key() -> str:
    """What the client's venv is made of: every file of the checkout that goes into the wheel, this fixture's own
    code, the interpreter, and the version of every distribution installed here (the wheelhouse is packed from
    them). Any change to one of them makes another venv; an unchanged checkout installs the same files again."""
    digest = hashlib.sha256()
    for path in [*shipped_files(), Path(__file__), Path(__file__).with_name("wheelhouse.py")]:
        digest.update(str(path.relative_to(ROOT)).encode() + b"\0" + hashlib.sha256(path.read_bytes()).digest())
    installed = sorted(f"{d.metadata['Name']}=={d.version}" for d in importlib.metadata.distributions())
    digest.update("\n".join([sys.version, sys.executable, *installed]).encode())
    return digest.hexdigest()[:24]


def make_client_venv(folder: Path, work: Path) -> None:
    """``folder / "venv"``: a fresh venv where ``pip install --no-index --find-links WHEELS graytrack`` installed the
    client, and ``folder / "installed.json"``: what is installed in it. WHEELS (in ``work``) holds graytrack's wheel,
    built from this checkout, and what its requirements need, packed from this venv (tests/client/wheelhouse.py):
    nothing is downloaded."""
    wheels = work / "wheels"
    wheels.mkdir()
    for dist in closure(base_requirements(build_wheel(work / "source", wheels))).values():
        pack(dist, wheels)
    venv = folder / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--quiet", "--no-index",
                    "--find-links", str(wheels), "graytrack"], check=True, capture_output=True, text=True)
    listing = subprocess.run([str(python), "-c", "import importlib.metadata as m, json; print(json.dumps("
                              "{d.metadata['Name']: d.version for d in m.distributions()}))"],
                             cwd=work, check=True, capture_output=True, text=True).stdout
    (folder / "installed.json").write_text(listing)


@pytest.fixture(scope="session")
def client_venv(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Venv:
    """A fresh venv where ``pip install --no-index --find-links WHEELS graytrack`` installed the client
    (:func:`make_client_venv`).

    Kept in pytest's cache under :func:`client_venv_key` (a venv cannot be moved: its scripts name its path), so a
    run on the checkout a previous run installed from uses that venv, which the tests only read, rather than
    building the wheel and installing it all again (~7 s on a quiet 2-core machine, 20 s in a busy suite). Another
    checkout makes its own, and the older ones are removed. Without pytest's cache (``-p no:cacheprovider``) it is
    made for this run alone."""
    cache = getattr(request.config, "cache", None)
    if cache is None:
        folder = tmp_path_factory.mktemp("client-alone")
        make_client_venv(folder, folder)
    else:
        root = cache.mkdir("client-venv")
        folder = root / client_venv_key()
        with _locked(root / "lock"):  # another test process of this run, or another run, may be making it
            if not (folder / "done").exists():
                for old in root.iterdir():
                    if old.is_dir():
                        shutil.rmtree(old)
                folder.mkdir()
                make_client_venv(folder, tmp_path_factory.mktemp("client-alone"))
                (folder / "done").touch()
    installed = json.loads((folder / "installed.json").read_text())
    return Venv(folder / "venv" / "bin" / "python",
                {canonicalize_name(name): version for name, version in installed.items()})


@dataclass(frozen=True)
class MakeRun:
    url: str
    home: Path  # HOME of the daemon and of the examples: the data directory is HOME/.local/state/graytrack
    pid: int = 0  # the daemon's process

    def env(self) -> dict[str, str]:
        env = {key: value for key, value in os.environ.items() if key not in ("STATE_DIRECTORY", "XDG_STATE_HOME")}
        return {**env, "HOME": str(self.home)}


# package scope: the daemon is stopped once this folder's tests are done. Left to the session's end it kept
# tracking (~0.08 s of CPU a second, and a calibration the README's block starts) beside every later test of
# its worker, minutes of a busy suite.
@pytest.fixture(scope="package")
def make_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[MakeRun]:
    """``python -m graytrack serve --host 127.0.0.1 --port P``, the command `make run` runs, with its
    defaults (the virtual rig; the data directory ``~/.local/state/graytrack``, under a HOME of its
    own); P is a free port instead of 8000, so a daemon the developer runs is left alone."""
    port = free_port()
    home = tmp_path_factory.mktemp("home")
    log = home / "serve.log"  # a file, not a pipe: nobody reads the daemon's log while it runs
    with log.open("w") as sink:
        process = subprocess.Popen([sys.executable, "-m", "graytrack", "serve", "--host", "127.0.0.1", "--port",
                                    str(port)], cwd=ROOT, env=MakeRun("", home).env(), stdout=sink, stderr=sink)
    daemon = MakeRun(f"http://127.0.0.1:{port}", home, process.pid)

    def answers() -> bool:
        assert process.poll() is None, f"the daemon exited: {log.read_text()[-2000:]}"
        try:
            return httpx.get(f"{daemon.url}/healthz", timeout=2.0).status_code in (200, 503)
        except httpx.TransportError:
            return False

    try:
        wait_for(answers, ANSWERS_S, "the daemon to answer")
        yield daemon
    finally:
        process.terminate()
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
