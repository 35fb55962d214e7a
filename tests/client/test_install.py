"""The client installs alone: no numerical stack is pulled in by ``pip install graytrack`` or loaded by
``import graytrack.client`` (issue 39, item 5), and the commands that need it say which extra."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from tests.client.conftest import ROOT, Venv

HEAVY = ("numpy", "scipy", "numba", "llvmlite", "opencv-python-headless", "opencv-python", "matplotlib",
         "fastapi", "uvicorn")  # the daemon extra's numerics and server, and what they bring
CLIENT = ("pydantic", "httpx", "websockets")


def test_importing_the_client_loads_no_numerics_and_no_daemon() -> None:
    # the acceptance's command, here where numpy is installed (before: True, 529 modules)
    code = ("import graytrack.client, sys; print('numpy' in sys.modules); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('scipy', 'numba', 'cv2', 'fastapi') "
            "or m.startswith('graytrack.service')))")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    assert out.splitlines() == ["False", "[]"]


def test_pip_install_graytrack_brings_the_client_and_no_numerical_stack(client_venv: Venv) -> None:
    installed = set(client_venv.installed)
    assert not installed & set(HEAVY), f"pulled in: {sorted(installed & set(HEAVY))}"
    assert {"graytrack", *CLIENT} <= installed
    # pydantic, httpx and websockets with theirs: nothing else (versions as packed from this venv)
    assert len(installed) <= 14, sorted(installed)


def test_the_client_alone_imports_and_each_command_names_its_extra(client_venv: Venv) -> None:
    imported = client_venv.run("-c", "import graytrack.client, graytrack.wire, sys; "
                               "print('numpy' in sys.modules, graytrack.client.__file__.startswith(sys.prefix))")
    assert imported.stdout.split() == ["False", "True"], imported.stderr  # the installed copy, not the checkout's
    missing = client_venv.run("-c", "import numpy")
    assert missing.returncode == 1 and "No module named 'numpy'" in missing.stderr
    serve = client_venv.run("graytrack", "serve")
    assert serve.returncode == 2 and serve.stdout == ""
    lines = serve.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("graytrack serve: error: ") and lines[0].endswith(
        "is not installed; the daemon and the commands need the numerical stack: pip install 'graytrack[daemon]'"
    ), serve.stderr
    # the EPICS bridge is a client: only caproto is missing
    epics = client_venv.run("graytrack", "epics", "--url", "http://127.0.0.1:9", "--prefix", "X")
    assert (epics.returncode, epics.stderr.strip()) == (
        2, "graytrack epics: error: caproto is not installed: pip install 'graytrack[epics]'")


def test_make_run_and_the_service_venv_install_the_daemon_extra(tmp_path: Path) -> None:
    # `pip install .` alone is the client now: what runs the daemon must name the extra
    for target, variable in (("run", f"VENV={tmp_path / 'venv'}"), ("service-venv", f"PREFIX={tmp_path / 'opt'}")):
        dry = subprocess.run(["make", "-n", target, variable], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout
        installs = [line for line in dry.splitlines() if "pip install" in line and "--upgrade pip" not in line]
        extras = [re.search(r"\[([^\]]*)\]", line) for line in installs]
        assert len(installs) == 1 and extras[0] and "daemon" in extras[0].group(1).split(","), dry
