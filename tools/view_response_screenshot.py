"""A screenshot of the live view's "Identified response" (docs/view.md).

Usage (inside the loopback-only namespace, like the tests):
    bash scripts/run bench ../tools/view_response_screenshot.py docs/figures/view-response.png

Simulates the nominal scenario at Ts 0.8 s and a 256-sample period (12 periods) into a
temporary bag, runs ``twotank-validation identify BAG --json id.json`` on it, then
``validate BAG --ts 0.8 --period 256 --model A --view --view-response id.json``, opens the
printed URL in headless Chromium (tools/browser.py) and saves the section.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import tempfile
from pathlib import Path

from tools.view_screenshot import view_page
from twotank_validation.bags import write_scenario_bag
from twotank_validation.sim import scenario as sc


def main(out: str) -> None:
    """Write the screenshot to ``out``."""
    s = dataclasses.replace(
        sc.load_scenario("nominal"), ts_s=0.8, period_samples=256, duration_s=12 * 204.8
    )
    cli = [sys.executable, "-m", "twotank_validation.cli"]
    with tempfile.TemporaryDirectory() as tmp:
        bag = write_scenario_bag(s, Path(tmp) / "nominal", storage="mcap")
        ident = str(Path(tmp) / "id.json")
        subprocess.run([*cli, "identify", str(bag), "--json", ident, "--quiet"], check=True)
        cmd = [*cli, "validate", str(bag), "--ts", "0.8", "--period", "256", "--model", "A"]
        cmd += ["--view", "--view-response", ident, "--quiet"]
        with view_page(cmd) as page:
            page.wait_for_function("window.twotankView.response !== null")
            page.wait_for_timeout(300)
            page.locator("#response").screenshot(path=out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "docs/figures/view-response.png")
