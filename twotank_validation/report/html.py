"""One self-contained HTML page per report: the figures, their captions and the numbers.

``validate --report`` and ``diagnose --report`` write ``report.html`` beside their PNGs. The
page is static (no script), carries no external reference (no URL, no ``@import``), prints
readably (a print stylesheet) and shows the numbers of the very dict written as JSON: every
value cell carries ``data-path``, the JSON path (a JSON list of keys) of the value it shows,
so a reader (and the tests) can trace each number to the JSON.

Figures are embedded as base64 PNG (``data:`` URIs), not inline SVG: the PNGs are written
anyway, so the page shows the same bytes with no second rendering; a window's time records
hold thousands of points, which as SVG paths would make the page megabytes; and an ``<img>``
scales and prints alike in every browser.

The page is built by string joining with :func:`html.escape` on every text that comes from
data (model, channel and file names, messages): Jinja2 is not a dependency of the package
(requirements.txt) and two small pages do not warrant one.
"""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

CSS = """
body { font: 14px/1.45 system-ui, sans-serif; max-width: 1100px; margin: 1.5em auto;
       padding: 0 1em; color: #111; }
h1 { font-size: 1.5em; } h2 { font-size: 1.25em; border-bottom: 1px solid #ccc; }
h3 { font-size: 1.05em; }
table { border-collapse: collapse; margin: 0.6em 0 1.2em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.2em 0.5em; text-align: left; vertical-align: top; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
thead th { background: #f2f2f2; }
tbody th { font-weight: normal; background: #fafafa; }
.OK { background: #dff0d8; } .WARN { background: #fcf0d0; } .ERROR { background: #f5d0d0; }
.STALE { background: #e6e6e6; } .bad { color: #a00; font-weight: bold; }
figure { margin: 1em 0 1.6em; } figure img { max-width: 100%; height: auto; }
figcaption { font-size: 0.9em; color: #333; max-width: 60em; }
.note { color: #444; font-size: 0.9em; }
@media print {
  body { max-width: none; margin: 0; font-size: 10pt; color: #000; }
  h2, h3 { break-after: avoid; }
  figure, table { break-inside: avoid; }
  figure img { max-width: 100%; max-height: 22cm; }
  thead { display: table-header-group; }
  .OK, .WARN, .ERROR, .STALE, thead th { -webkit-print-color-adjust: exact;
                                          print-color-adjust: exact; }
}
"""

MISSING = "—"
"""What a cell shows for a JSON ``null`` (not judged, not finite, not known)."""


def esc(text: Any) -> str:
    """Text from data, escaped for HTML content and attribute values alike."""
    return html.escape(str(text), quote=True)


def fmt(value: Any) -> str:
    """A JSON value as a cell's text: 4 significant digits, ``yes``/``no``, ``—`` for null."""
    if value is None:
        return MISSING
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return f"{value:.4g}" if math.isfinite(value) else str(value)
    return esc(value)


def get(doc: Any, path: Sequence[Any]) -> Any:
    """The value at ``path`` (keys and list indices) of a JSON document."""
    for key in path:
        doc = doc[key]
    return doc


def cell(
    doc: Any, path: Sequence[Any], tag: str = "td", cls: str = "", text: str | None = None
) -> str:
    """A cell showing the value at ``path`` of ``doc``, with its path in ``data-path``.

    ``text``: what it shows instead of :func:`fmt` of the value (escaped here).
    """
    value = get(doc, path)
    kind = "num" if isinstance(value, int | float) and not isinstance(value, bool) else ""
    classes = " ".join(c for c in (kind, cls) if c)
    attr = f' class="{esc(classes)}"' if classes else ""
    shown = fmt(value) if text is None else esc(text)
    return f'<{tag}{attr} data-path="{esc(json.dumps(list(path)))}">{shown}</{tag}>'


def verdict(window: Mapping[str, Any]) -> str:
    """A window entry's verdict: ``INVALIDATED``, ``valid`` or ``not judged`` (β null)."""
    if window["beta"] is None:
        return "not judged"
    return "INVALIDATED" if window["invalidated"] else "valid"


def _window_cell(doc: Any, base: list[Any], key: str, window: Mapping[str, Any]) -> str:
    if key == "invalidated":
        return cell(doc, [*base, key], cls="bad" if window[key] else "", text=verdict(window))
    return cell(doc, [*base, key], cls=window["alarm"] if key == "alarm" else "")


def table(head: Sequence[str], rows: Sequence[Sequence[str]], caption: str = "") -> str:
    """A table: ``head`` plain texts (escaped), ``rows`` of cells already made (HTML)."""
    cap = f"<caption>{esc(caption)}</caption>" if caption else ""
    th = "".join(f"<th>{esc(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(r) + "</tr>" for r in rows)
    return f"<table>{cap}<thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>"


def key_table(doc: Any, base: Sequence[Any], rows: Sequence[tuple[str, Any]]) -> str:
    """A two-column table: a label (escaped) and the value at ``base + [key]`` per row."""
    body = [[f"<th>{esc(label)}</th>", cell(doc, [*base, key])] for label, key in rows]
    return table(("quantity", "value"), body)


def figure(path: Path, alt: str, caption: str) -> str:
    """A PNG embedded as a ``data:`` URI with its caption; a note where the file is missing."""
    if not path.is_file():
        return f'<p class="note">figure {esc(path.name)} was not drawn.</p>'
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (
        f'<figure><img src="data:image/png;base64,{data}" alt="{esc(alt)}">'
        f"<figcaption><b>{esc(path.name)}.</b> {esc(caption)}</figcaption></figure>"
    )


def page(title: str, body: str) -> str:
    """The whole document: static, no script, no external reference."""
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{esc(title)}</title><style>{CSS}</style></head>"
        f"<body><h1>{esc(title)}</h1>{body}</body></html>\n"
    )


# --------------------------------------------------------------------------- validate

PER_BIN_CAPTION = (
    "The paper's figure: the smallest norm of the noise W(n) that explains the data at each "
    "frequency bin, given some perturbation within its bound (markers joined: the excited "
    "lines; faint dots: bins only noise reaches; shaded: the excited band). The dashed line "
    "is the budget 1: β is the root weighted sum of squares of these values over the band, "
    "so a single bin above 1 invalidates the model on its own, and many bins near 1 do "
    "together. The dotted curve is the noise floor, what the window's measurement noise "
    "alone is expected to cost at each bin under the model's noise weights: bins far above "
    "it are dynamics the model set does not cover; bins on it are noise."
)
NYQUIST_CAPTION = (
    "The worst bin on the Nyquist plane (the paper's Fig. 8): the nominal response of the "
    "output with the largest error to the input with the largest part in it, over the "
    "excited band (black), the discs the perturbations (‖Δ‖ ≤ 1) can move it within at "
    "excited harmonics (blue; heavy at the worst bin), and the response the data ask of that "
    "channel pair at the worst bin (red cross) with the noise weights' reach (dashed red). "
    "Outside its disc by more than the dashed reach: the data cannot be explained with this "
    "pair alone within the budget. Axes in output units per input unit."
)
RECORDS_CAPTION = (
    "The window's time records as the validator judged them: the inputs (top) and the "
    "measured outputs (bottom), in model units, against time from the recording's start. A "
    "periodic input repeats every period; a step, a gap or a drift here explains a verdict "
    "the spectra alone do not."
)
SIGNALS_CAPTION = (
    "The minimum-norm signals in time (the paper's Figs. 8–9): the weighted noise W_n w(k) "
    "(top) and the perturbation outputs v(k) (bottom) that explain the window with the least "
    "‖w‖. Noise of the size of the measurement noise: the model set covers the data; a "
    "periodic pattern in the noise: dynamics the model misses."
)
TIMELINE_CAPTION = (
    "β_total per window against the recording's time, one bar per window spanning it, "
    "coloured by the debounced alarm (green OK, orange WARN, red ERROR, grey STALE; a bar "
    "at 0: not judged). The dashed line at 1 is the limit: above it the window invalidates "
    "the model."
)
WHY_TEXT = {
    "max_beta": "the window of largest β",
    "first_alarm": "the window the alarm first rose on",
}
WINDOW_COLUMNS: tuple[tuple[str, str], ...] = (
    ("start (s)", "start"),
    ("end (s)", "end"),
    ("β", "beta"),
    ("β_op", "beta_op"),
    ("β_total", "beta_total"),
    ("verdict (invalidated: β > 1)", "invalidated"),
    ("alarm", "alarm"),
    ("noise β", "noise_beta"),
    ("not judged because", "reason"),
)
VIEW_ROWS: tuple[tuple[str, str], ...] = (
    ("window start (s)", "start"),
    ("window end (s)", "end"),
    ("β", "beta"),
    ("noise β (the noise alone, expected)", "noise_beta"),
    ("worst bin (index)", "worst_bin"),
    ("worst bin frequency (Hz)", "worst_bin_hz"),
    ("min ‖W(n)‖ at the worst bin", "worst_bin_w_min"),
    ("noise floor at the worst bin", "worst_bin_noise_floor"),
    ("Nyquist figure: output", "nyquist_output"),
    ("Nyquist figure: input", "nyquist_input"),
    ("excited lines", "excited_lines"),
    ("band β counts", "band_text"),
    ("bins in the band", "band_bins"),
)


def _excited_text(view: Mapping[str, Any]) -> str:
    lo, hi = view["excited_band_hz"]
    return f"{lo:.4g} – {hi:.4g} Hz"


def validate_page(numbers: Mapping[str, Any], folder: Path) -> str:
    """The page of ``validate --report``: ``numbers`` as written to ``report.json``.

    Args:
        numbers: ``{"summary": <validate --json document>, "windows_of_interest": {model:
            {why: window_view_numbers}}}``.
        folder: where the PNGs are (embedded from there).
    """
    s = numbers["summary"]
    parts = [
        "<p>"
        + f"Recording <code>{esc(s['bag'])}</code> ({esc(s['source'])}, time base "
        + f"{esc(s['time_base'])}): {fmt(s['messages'])} messages read; "
        + ("complete" if s["complete"] else '<span class="bad">INCOMPLETE</span>')
        + ("; interrupted" if s["interrupted"] else "")
        + ". Times in s from the recording's first stamp. Numbers: <code>report.json</code> "
        "(the same dict; <code>summary</code> is the <code>--json</code> document).</p>"
    ]
    if s["problems"]:
        items = "".join(f"<li>{esc(p)}</li>" for p in s["problems"])
        parts.append(f"<p>Problems:</p><ul>{items}</ul>")
    rows = []
    for name in s["models"]:
        base = ["summary", "models", name]
        rows.append(
            [
                f"<th>{esc(name)}</th>",
                cell(numbers, [*base, "judged"]),
                cell(numbers, [*base, "not_judged"]),
                cell(numbers, [*base, "beta_max"]),
                cell(numbers, [*base, "first_alarm"]),
                cell(numbers, [*base, "beta_outside_max"])
                if "beta_outside_max" in s["models"][name]
                else f"<td>{MISSING}</td>",
            ]
        )
    parts.append("<h2>Models</h2>")
    parts.append(
        table(
            ("model", "windows judged", "not judged", "β max", "first alarm (s)", "β outside band"),
            rows,
        )
    )
    parts.append(
        figure(folder / "alarm_timeline.png", "β_total per window and alarm", TIMELINE_CAPTION)
    )
    for name, entry in s["models"].items():
        parts.append(f"<h2>Model {esc(name)}</h2>")
        parts.append("<h3>Windows: β and the alarm</h3>")
        body = []
        for k, w in enumerate(entry["windows"]):
            base = ["summary", "models", name, "windows", k]
            body.append([_window_cell(numbers, base, key, w) for _, key in WINDOW_COLUMNS])
        parts.append(table([h for h, _ in WINDOW_COLUMNS], body))
        for why, view in numbers["windows_of_interest"].get(name, {}).items():
            what = WHY_TEXT.get(why, why)
            base = ["windows_of_interest", name, why]
            parts.append(f"<h3>Model {esc(name)}: {esc(what)}</h3>")
            parts.append(key_table(numbers, base, VIEW_ROWS))
            parts.append(
                f'<p class="note">Excited band: {esc(_excited_text(view))} (the shaded span '
                "of the per-bin figure).</p>"
            )
            stem = view["stem"]
            alt = f"model {name}, {what}"
            parts += [
                figure(folder / f"per_bin_{stem}.png", f"per-bin min ‖W‖, {alt}", PER_BIN_CAPTION),
                figure(folder / f"nyquist_{stem}.png", f"worst bin, {alt}", NYQUIST_CAPTION),
                figure(folder / f"records_{stem}.png", f"time records, {alt}", RECORDS_CAPTION),
                figure(
                    folder / f"time_signals_{stem}.png", f"minimum-norm signals, {alt}",
                    SIGNALS_CAPTION,
                ),
            ]  # fmt: skip
    return page(f"validate: {Path(str(s['bag'])).name}", "".join(parts))


# --------------------------------------------------------------------------- diagnose

SPECTRA_CAPTION = (
    "Residual spectra on the held-out windows: per output, the raw error |Y − G U| at the "
    "excited bins before (circles) and after (crosses) the fitted effects, with the noise at "
    "the other bins (grey dots) as the floor; right, the per-bin min ‖W(n)‖ of the first "
    "held-out window before and after. An effect that explains the error brings the crosses "
    "down to the grey floor."
)
OUTPUTS_CAPTION = (
    "The measured outputs of the first held-out window (grey) against the model's simulation "
    "and the diagnosed model's (dashed), in model units against time: the diagnosed curve "
    "should follow the measurement where the model's does not. The legend quotes each RMS "
    "error."
)
EFFECT_CAPTION = (
    "The fitted effect against the evidence: per chosen effect, the measured-to-modelled "
    "ratio Y/(G U) at every bin the fit used (magnitude top, phase bottom, ±1σ of the "
    "measurement noise) and the fitted effect's ratio at those bins (crosses) and as a "
    "curve; the title quotes the R² of these points. Points scattered about 1 (0°) with no "
    "trend: nothing to explain."
)


def _effect_rows(doc: Mapping[str, Any]) -> list[list[str]]:
    rows = []
    for i, e in enumerate(doc["effects"]):
        unc = e.get("uncertainty", {})
        for name in e["parameters"]:
            base = ["effects", i]
            row = [
                f"<td>{esc(e['kind'])}</td>",
                f"<td>{esc(e['channel'] or MISSING)}</td>",
                f"<td>{esc(name)}</td>",
                cell(doc, [*base, "parameters", name]),
            ]
            if name in unc:
                u = [*base, "uncertainty", name]
                row += [
                    cell(doc, [*u, "stderr"]),
                    cell(doc, [*u, "ci95", 0]),
                    cell(doc, [*u, "ci95", 1]),
                    cell(doc, [*u, "at_bound"]),
                ]
            else:  # a fixed parameter: not fitted
                row += [f"<td>{MISSING}</td>"] * 3 + ["<td>fixed</td>"]
            row.append(cell(doc, [*base, "heldout_reduction"]))
            rows.append(row)
    return rows


def diagnose_page(doc: Mapping[str, Any], folder: Path) -> str:
    """The page of ``diagnose --report``: ``doc`` is the ``diagnose --json`` document.

    Args:
        doc: the diagnosis JSON (``Diagnosis.to_json``, with the recording's stretches where
            the command wrote them).
        folder: where the PNGs are (embedded from there).
    """
    parts = [
        f"<p>{esc(doc['summary'])}</p>",
        '<p class="note">Fit on the windows starting at '
        + esc(", ".join(f"{t:.0f}" for t in doc["fit_windows_start_s"]))
        + " s; judged on the held-out windows starting at "
        + esc(", ".join(f"{t:.0f}" for t in doc["heldout_windows_start_s"]))
        + " s. Numbers: the <code>diagnose --json</code> document (the same dict).</p>",
        "<h2>Error before and after, held-out windows</h2>",
    ]
    before, after = doc["before"], doc["after"]
    rows = [
        [
            "<th>β (largest over the held-out windows)</th>",
            cell(doc, ["before", "beta"]),
            cell(doc, ["after", "beta"]),
        ]
    ]
    for o in before["rms"]:
        rows.append(
            [
                f"<th>RMS error {esc(o)} (excited band, model units)</th>",
                cell(doc, ["before", "rms", o]),
                cell(doc, ["after", "rms", o]) if o in after["rms"] else f"<td>{MISSING}</td>",
            ]
        )
    parts.append(table(("held-out data", f"model {doc['model']}", "diagnosed"), rows))
    if doc["per_output"]:
        rows = [
            [
                f"<th>{esc(o)}</th>",
                cell(doc, ["per_output", o, "noise_ratio_before"]),
                cell(doc, ["per_output", o, "noise_ratio_after"]),
                cell(doc, ["per_output", o, "explained_fraction"]),
            ]
            for o in doc["per_output"]
        ]
        parts.append(
            table(
                (
                    "output",
                    "error before (× noise floor)",
                    "left after (× noise floor)",
                    "share explained",
                ),
                rows,
            )
        )
    parts.append("<h2>The fitted effect</h2>")
    if doc["effects"]:
        parts.append(
            table(
                (
                    "effect",
                    "channel",
                    "parameter",
                    "value (SI)",
                    "standard error",
                    "95 % CI low",
                    "95 % CI high",
                    "at search bound",
                    "held-out error removed",
                ),
                _effect_rows(doc),
            )
        )
        items = "".join(
            f"<li><b>{esc(e['kind'])}</b>: {esc(e['evidence'])}</li>" for e in doc["effects"]
        )
        parts.append(f"<ul>{items}</ul>")
    else:
        parts.append("<p>Nothing added to the model.</p>")
    if doc["findings"]:
        items = "".join(
            f"<li>{esc(f.get('kind'))} on {esc(f.get('channel'))}: {esc(f.get('evidence'))}; "
            f"what to do: {esc(f.get('recommendation'))}</li>"
            for f in doc["findings"]
        )
        parts.append(f"<h2>Found outside the model file</h2><ul>{items}</ul>")
    if doc["rejected"] or doc["not_applicable"]:
        items = "".join(
            f"<li>{esc(r['candidate'])}: {esc(r['reason'])}</li>"
            for r in [*doc["rejected"], *doc["not_applicable"]]
        )
        parts.append(f"<h2>Rejected</h2><ul>{items}</ul>")
    parts.append("<h2>Figures</h2>")
    parts.append(
        figure(
            folder / "diagnosis_spectra.png", "residual spectra before and after", SPECTRA_CAPTION
        )
    )
    parts.append(
        figure(folder / "diagnosis_outputs.png", "measured outputs and models", OUTPUTS_CAPTION)
    )
    if doc["effects"]:
        parts.append(
            figure(folder / "diagnosis_effect.png", "the fitted effect's evidence", EFFECT_CAPTION)
        )
    return page(f"diagnose: model {doc['model']}", "".join(parts))
