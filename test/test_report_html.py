"""The HTML page of ``validate --report`` and ``diagnose --report``.

References: the JSON written beside the page (``report.json``, whose ``summary`` must be the
``--json`` document itself) for every number shown, read back from the table cells; the PNG
files on disk for every embedded figure (byte for byte); the hostile name's raw text, which
must not reach the page unescaped; and a real browser (headless Chromium), which must load
every image from the page alone. ``diagnose``'s page is checked on a real diagnosis in
``test/diagnose/test_diagnose.py`` (the command's test); here on a hand-made document with a
hostile channel name.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from html_checks import Page, assert_cells_equal, assert_self_contained

import twotank_validation
from tools.report_page import validate_report
from twotank_validation import cli
from twotank_validation.report import html as report_html

HOSTILE = 'B<i>&"x'


@pytest.fixture(scope="module")
def validated(tmp_path_factory) -> Path:
    """``validate --report`` of the simulated rig, Model A and Model B under a hostile name."""
    folder = tmp_path_factory.mktemp("html")
    doc = yaml.safe_load(
        (Path(twotank_validation.__file__).parent / "models" / "model_b.yaml").read_text()
    )
    doc["name"] = HOSTILE
    hostile = folder / "hostile.yaml"
    hostile.write_text(yaml.safe_dump(doc, sort_keys=False))
    assert cli.main(validate_report(folder, ("A", str(hostile)))) == cli.EXIT_OK
    return folder


def test_the_page_is_self_contained_and_embeds_every_figure(validated) -> None:
    text = (validated / "report" / "report.html").read_text(encoding="utf-8")
    page = Page(text)
    assert_self_contained(text, page)
    embedded = page.images()
    on_disk = sorted((validated / "report").glob("*.png"))
    # the alarm timeline, and 4 figures per window of interest: A (largest β, first alarm), B
    assert len(on_disk) == 1 + 4 * 3
    assert sorted(embedded) == sorted(p.read_bytes() for p in on_disk)
    stems = {p.stem.split("_")[0] for p in on_disk}
    assert {"per", "nyquist", "records", "time", "alarm"} == stems
    assert text.count("<figcaption>") == len(on_disk)


def test_the_tables_show_the_json_s_numbers(validated) -> None:
    numbers = json.loads((validated / "report" / "report.json").read_text())
    # the summary the page shows is the --json document itself
    assert numbers["summary"] == json.loads((validated / "v.json").read_text())
    page = Page((validated / "report" / "report.html").read_text(encoding="utf-8"))
    assert_cells_equal(page, numbers)
    shown = {tuple(p) for p, _ in page.cells}
    for name, entry in numbers["summary"]["models"].items():
        for k in range(len(entry["windows"])):  # every window: β, verdict, alarm, noise β
            for key in ("beta", "invalidated", "alarm", "noise_beta"):
                assert ("summary", "models", name, "windows", k, key) in shown
    for name, views in numbers["windows_of_interest"].items():
        for why in views:
            for key in ("worst_bin", "worst_bin_hz", "worst_bin_noise_floor", "band_text"):
                assert ("windows_of_interest", name, why, key) in shown
    assert set(numbers["windows_of_interest"]["A"]) == {"max_beta", "first_alarm"}


def test_a_hostile_model_name_is_escaped(validated) -> None:
    text = (validated / "report" / "report.html").read_text(encoding="utf-8")
    assert HOSTILE not in text  # only its escaped form
    assert "B&lt;i&gt;&amp;&quot;x" in text
    page = Page(text)
    assert "i" not in {tag for tag, _ in page.tags}  # the name opened no element
    assert f"Model {HOSTILE}" in "".join(page.text)


def test_chromium_renders_the_page(validated, tmp_path) -> None:
    """Opened from disk (file://) in headless Chromium: every image decoded, the title shown."""
    from tools.browser import headless_page  # noqa: PLC0415

    url = (validated / "report" / "report.html").resolve().as_uri()
    with headless_page(1000, 1300) as page:
        page.goto(url)
        widths = page.eval_on_selector_all(
            "img", "els => els.map(e => e.complete ? e.naturalWidth : 0)"
        )
        assert len(widths) == 13
        assert min(widths) > 0
        assert page.title() == "validate: rig.csv"
        assert page.inner_text("h1") == "validate: rig.csv"
        assert f"Model {HOSTILE}" in page.inner_text("body")
        shot = tmp_path / "page.png"
        page.screenshot(path=str(shot))
        assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        page.emulate_media(media="print")  # the print stylesheet applies, images still there
        assert page.eval_on_selector("figure", "e => getComputedStyle(e).breakInside") == ("avoid")


def test_the_diagnose_page_escapes_a_hostile_channel(tmp_path) -> None:
    """A hand-made diagnosis document: the hostile channel and effect text stay text."""
    ch = 'T<&>"'
    doc = {
        "model": "B&",
        "summary": "Model B& lacks <delay> on T",
        "fit_windows_start_s": [0.0, 100.0],
        "heldout_windows_start_s": [200.0],
        "before": {"beta": 1.52, "rms": {"h": 0.01, ch: 0.2}},
        "after": {"beta": 0.61, "rms": {"h": 0.0101, ch: 0.02}},
        "per_output": {
            ch: {"noise_ratio_before": 40.0, "noise_ratio_after": 1.2, "explained_fraction": 0.98}
        },
        "effects": [
            {
                "kind": "delay",
                "channel": ch,
                "parameters": {"delay_s": 10.2, "fixed_gain": 1.0},
                "evidence": "phase falls <linearly> & steadily",
                "heldout_reduction": 0.9,
                "uncertainty": {"delay_s": {"stderr": 0.3, "ci95": [9.6, 10.8], "at_bound": None}},
            }
        ],
        "findings": [],
        "rejected": [{"candidate": "leak <h>", "heldout_reduction": 0.01, "reason": "a & b"}],
        "not_applicable": [],
    }
    text = report_html.diagnose_page(doc, tmp_path)
    page = Page(text)
    assert_self_contained(text, page)
    for raw in (ch, "<delay>", "<linearly>", "<h>"):
        assert raw not in text
    assert {tag for tag, _ in page.tags}.isdisjoint({"delay", "linearly", "h"})
    # β and two RMS before and after, the noise ratios, the fitted and the fixed parameter
    assert assert_cells_equal(page, doc) == 3 * 2 + 3 + 6 + 2
    assert "phase falls <linearly> & steadily" in "".join(page.text)
