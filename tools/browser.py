"""A headless Chromium page for the tests and benches of the pages we serve or write.

Debian's ``chromium`` (apt; ``scripts/run test`` installs it where it may) driven by
Playwright (``playwright`` from PyPI, its driver only: it never downloads a browser of its
own, ``executable_path`` points at Debian's). The flags keep Chromium off the network: no
background connections, no component updates, no sync, a fresh profile each time; the tests
run it inside the loopback-only namespace as well.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

CHROMIUM_ARGS = (
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)


class NoBrowserError(RuntimeError):
    """Chromium is not installed."""


def chromium_path() -> str:
    """The Chromium binary, or :class:`NoBrowserError` naming the fix."""
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    raise NoBrowserError(
        "no chromium on PATH: install Debian's (apt-get install chromium), or run the tests "
        "through `bash scripts/run test`, which installs it where it may"
    )


@contextmanager
def headless_page(width: int = 1280, height: int = 900, **context: Any) -> Iterator[Any]:
    """A Playwright ``Page`` in a fresh headless Chromium, closed on leaving.

    ``context``: more options of the browser context (e.g. ``bypass_csp=True``, for a test
    that reads a page whose Content-Security-Policy forbids Playwright's evaluated scripts).
    """
    from playwright.sync_api import sync_playwright  # noqa: PLC0415 (tests and benches only)

    exe = chromium_path()
    with (
        tempfile.TemporaryDirectory(prefix="twotank-chromium-") as profile,
        sync_playwright() as pw,
    ):
        browser = pw.chromium.launch_persistent_context(
            profile,
            executable_path=exe,
            headless=True,
            args=list(CHROMIUM_ARGS),
            viewport={"width": width, "height": height},
            **context,
        )
        try:
            yield browser.new_page()
        finally:
            browser.close()
