"""The headless Chromium the page tests drive: launched once for this folder's tests on a test process
(a launch with its Playwright driver costs ~1 s of CPU; the folder has a dozen tests), each test in pages of
its own that are closed when it ends (a browser context each: no cookie or storage is shared)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"]


@pytest.fixture(scope="package")
def _chromium() -> Iterator[object]:
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as playwright:
        chromium = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS, headless=True)
        try:
            yield chromium
        finally:
            chromium.close()


@pytest.fixture
def browser(_chromium) -> Iterator[object]:
    """The folder's Chromium; the pages the test opened are closed after it (a page left open would keep
    polling its daemon, or retrying one that is gone, through the tests after it)."""
    yield _chromium
    for context in _chromium.contexts:
        context.close()
