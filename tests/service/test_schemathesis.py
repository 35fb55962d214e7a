"""Hostile input at scale: schemathesis generates requests for every operation of the daemon's own
OpenAPI document, with the token (so the mutating routes are reached, not only refused), against a
real ``serve`` process on the virtual rig. Bounded and deterministic: a fixed number of examples
per operation. No 500 and no response outside its documented schema."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from tests.service.helpers import ServeProcess

EXAMPLES_PER_OPERATION = 40
CHECKS = "not_a_server_error,response_schema_conformance,content_type_conformance"
# /healthz answers 503 by design while the rig is not tracking or its model is stale (the fuzzed
# moves can make it so on a busy machine): it gets its own run, its body and content type checked
# against the schema, not its status. (A per-operation setting in schemathesis.toml does not do it:
# the command line's --checks outranks it, and a stale model's 503 failed the whole run.)
HEALTH = "/healthz"
HEALTH_CHECKS = "response_schema_conformance,content_type_conformance"


def _schemathesis(daemon: ServeProcess, token: str, cwd: Path, checks: str, *selection: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(Path(sys.executable).parent / "schemathesis"), "run", f"{daemon.base}/api/openapi.json",
         "--header", f"Authorization: {token}", "--max-examples", str(EXAMPLES_PER_OPERATION),
         "--checks", checks, "--generation-deterministic", "--phases", "examples,coverage,fuzzing",
         "--request-timeout", "20", "--no-color", *selection],
        capture_output=True, text=True, timeout=600, cwd=cwd)  # its example database stays there


def test_generated_requests_get_no_server_error_and_match_the_schema(tmp_path: Path) -> None:
    with ServeProcess(tmp_path) as daemon:
        daemon.wait_state("tracking", timeout_s=120)
        token = daemon.auth()["Authorization"]
        runs = [_schemathesis(daemon, token, tmp_path, CHECKS, "--exclude-path", HEALTH),
                _schemathesis(daemon, token, tmp_path, HEALTH_CHECKS, "--include-path", HEALTH)]
        alive = daemon.status()
    for run in runs:
        report = run.stdout[-6000:] + run.stderr[-2000:]
        assert run.returncode == 0, report
        assert " passed" in run.stdout and "generated" in run.stdout, report
    (rest, total), (health, _) = (map(int, re.search(r"Selected: (\d+)/(\d+)", run.stdout).groups()) for run in runs)
    assert health == 1 and rest == total - 1 > 10  # every operation but /healthz, then /healthz alone
    assert alive is not None, "the daemon kept running under the generated requests"
