"""``validate --report`` on a short simulated record, and a screenshot of its HTML page.

Used by ``test/test_report_html.py`` and to make the documentation's screenshot::

    python -m tools.report_page docs/figures/report_html_validate.png

(the nominal rig, 6 periods of 256 samples at 0.8 s, simulated; Models A and B; the page
opened as a ``file://`` URL in headless Chromium, :mod:`tools.browser`).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import pandas as pd

from tools.browser import headless_page
from tools.streamfuzz import CONFIG, clean_record


def validate_report(folder: Path, models: tuple[str, ...] = ("A", "B")) -> list[str]:
    """The rig's record as ``folder/rig.csv`` and the ``validate`` arguments that judge it.

    The arguments write ``folder/v.json`` and the report into ``folder/report``.
    """
    stamps, u, y = clean_record(6)
    table = folder / "rig.csv"
    pd.DataFrame(
        {"t": stamps / 1e9, "hot": u[:, 0], "cold": u[:, 1], "h": y[:, 0], "T": y[:, 1]}
    ).to_csv(table, index=False)
    args = ["validate", str(table), "--time", "t", "--quiet"]
    for m in models:
        args += ["--model", m]
    args += ["--period", str(CONFIG.period_samples)]
    args += ["--input", "hot=column:hot", "--input", "cold=column:cold"]
    args += ["--output", "height=column:h", "--output", "temperature=column:T"]
    return [*args, "--json", str(folder / "v.json"), "--report", str(folder / "report")]


def screenshot(page_file: Path, out: Path, width: int = 1000, height: int = 1200) -> None:
    """The top of the page (``width`` x ``height`` CSS px) as a PNG of 256 colours (small)."""
    from PIL import Image  # noqa: PLC0415 (matplotlib's dependency)

    with headless_page(width, height) as page:
        page.goto(page_file.resolve().as_uri())
        page.screenshot(path=str(out))
    with Image.open(out) as shot:
        small = shot.convert("RGB").quantize(256, method=Image.Quantize.FASTOCTREE)
    small.save(out, optimize=True)


def main(argv: list[str]) -> int:
    """Write the screenshot of a fresh report's page to ``argv[0]``."""
    from twotank_validation import cli  # noqa: PLC0415

    if len(argv) != 1:
        print("usage: python -m tools.report_page OUT.png", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        code = cli.main(validate_report(folder))
        if code != 0:
            return code
        screenshot(folder / "report" / "report.html", Path(argv[0]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
