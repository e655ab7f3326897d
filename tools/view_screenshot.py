"""A screenshot of the live view (docs/view.md): ``validate BAG --view`` of a simulated leak.

Usage (inside the loopback-only namespace, like the tests):
    bash scripts/run bench ../tools/view_screenshot.py docs/figures/view.png

Simulates the leak scenario at Ts 0.8 s and a 256-sample period (12 periods, a leak of 0.04
from 1270 s) into a temporary bag, runs ``twotank-validation validate BAG --ts 0.8 --period
256 --model A --model B --view``, opens the printed URL in headless Chromium
(tools/browser.py) once the replay has finished, and saves the page.
"""

from __future__ import annotations

import dataclasses
import re
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from tools.browser import headless_page
from twotank_validation.bags import write_scenario_bag
from twotank_validation.sim import scenario as sc


@contextmanager
def view_page(cmd: Sequence[str]) -> Iterator[Any]:
    """A headless Chromium page at the view ``cmd`` serves, once its replay has ended.

    ``cmd`` is a ``validate ... --view`` command line; it is stopped with SIGINT on leaving.
    """
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        url = None
        assert proc.stderr is not None
        for line in proc.stderr:
            if m := re.match(r"view: (http://127\.0\.0\.1:\d+/)$", line.strip()):
                url = m.group(1)
            if "page stays" in line:
                break
        if url is None:
            raise SystemExit("validate --view printed no URL")
        with headless_page(1280, 900, bypass_csp=True) as page:
            page.goto(url)
            yield page
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=20)


def main(out: str) -> None:
    """Write the screenshot to ``out``."""
    base = sc.load_scenario("leak")
    s = dataclasses.replace(
        base, ts_s=0.8, period_samples=256, duration_s=12 * 204.8, faults=("leak=0.04@1270",)
    )
    with tempfile.TemporaryDirectory() as tmp:
        bag = write_scenario_bag(s, Path(tmp) / "leak", storage="mcap")
        cmd = [sys.executable, "-m", "twotank_validation.cli", "validate", str(bag)]
        cmd += ["--ts", "0.8", "--period", "256", "--model", "A", "--model", "B"]
        cmd += ["--view", "--quiet"]
        with view_page(cmd) as page:
            page.wait_for_function("window.twotankView.ended !== null")
            page.wait_for_function("document.body.dataset.drawn > 0")
            page.wait_for_timeout(300)
            page.screenshot(path=out, full_page=True)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "docs/figures/view.png")
