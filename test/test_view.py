"""The live view (docs/view.md): a page in headless Chromium against the reports' JSON.

The reference is the JSON the same run writes (``validate --json``'s windows, ``live
--json``'s lines): the page's table carries each model's latest report's numbers as data
attributes, parsed from the pushed stream, and must equal them; its report count must equal
the number of windows. The server is driven directly for the "stopped" sign (a report, no
report for longer than the page's limit, a report again) and probed over HTTP for being read
only and on 127.0.0.1 only. Chromium runs off the network (tools/browser.py); the node test
(``live --view``) needs the loopback-only namespace like every node test.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import re
import signal
import socket
import subprocess
import sys
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tools.browser import headless_page
from twotank_validation import cli
from twotank_validation.bags import write_scenario_bag
from twotank_validation.cli_view import ViewRun, view_response
from twotank_validation.online import Alarm, WindowReport
from twotank_validation.online.window import MonitorConfig
from twotank_validation.sim import scenario as sc
from twotank_validation.usecases import ValidateJob
from twotank_validation.usecases.reading import ReadSettings
from twotank_validation.view import Pacer, ViewServer
from twotank_validation.view.messages import mode_message
from twotank_validation.view.response import ResponseError, response_message

FAST = MonitorConfig(ts_s=0.8, period_samples=256)
ROWS = (
    "rs => rs.map(r => ({model: r.dataset.model, beta: r.dataset.beta, beta_op: "
    "r.dataset.betaOp, beta_total: r.dataset.betaTotal, alarm: r.dataset.alarm, "
    "end: r.dataset.end, count: r.dataset.count, seq: r.dataset.seq}))"
)


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    """One headless Chromium for the module (a fresh page per use: ``browser.new_page()``)."""
    with headless_page(bypass_csp=True) as page:  # Playwright's waits evaluate scripts
        yield page.context


@pytest.fixture(scope="module")
def leak_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """8 periods of the rig at Ts 0.8 s, period 256, a leak from 1000 s."""
    base = sc.load_scenario("leak")
    s = dataclasses.replace(
        base, ts_s=0.8, period_samples=256, duration_s=8 * 204.8, faults=("leak=0.04@1000",)
    )
    return write_scenario_bag(s, tmp_path_factory.mktemp("view") / "leak", storage="mcap")


@pytest.fixture(scope="module")
def identified(leak_bag: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``identify --json`` of the module's record (orders 1..2: about a second)."""
    out = tmp_path_factory.mktemp("identify") / "id.json"
    assert cli.main(["identify", str(leak_bag), "--orders", "1..2", "--json", str(out)]) == 0
    return out


def _rows(page: Any) -> dict[str, dict[str, Any]]:
    return {r["model"]: r for r in page.eval_on_selector_all("#latest tbody tr", ROWS)}


def _num(text: str) -> float | None:
    return None if text == "" else float(text)


def _same(row: dict[str, Any], entry: dict[str, Any], count: int) -> None:
    """A table row equals a window's JSON entry (exact: the page keeps the JSON's numbers)."""
    for key in ("beta", "beta_op", "beta_total", "end"):
        assert _num(row[key]) == entry[key], (key, row, entry)
    assert row["alarm"] == entry["alarm"]
    assert int(row["count"]) == count


def test_a_replay_s_page_shows_the_json_s_numbers_and_a_late_visitor_gets_the_history(
    browser: Any, leak_bag: Path, tmp_path: Path
) -> None:
    job = ValidateJob(
        str(leak_bag),
        ReadSettings(monitor=FAST),
        models=("A", "B"),
        diagnosis=False,
        json_path=str(tmp_path / "v.json"),
    )
    requests: list[str] = []
    with ViewServer(title="leak") as view:
        early = browser.new_page()
        early.on("request", lambda r: requests.append(r.url))
        early.goto(view.url)
        early.wait_for_function("window.twotankView && window.twotankView.connected")
        reports: list[WindowReport] = []
        starts: list[int] = []

        def listen(rep: WindowReport, start_ns: int) -> None:
            reports.append(rep)
            starts.append(start_ns)
            view.publish_report(rep, start_ns)

        outcome = job.run(on_report=listen)
        doc = json.loads((tmp_path / "v.json").read_text())
        windows = {m: e["windows"] for m, e in doc["models"].items()}
        total = sum(len(w) for w in windows.values())
        assert outcome.code == 0
        assert total >= 20
        for page in (early, browser.new_page()):  # open during the run; after it
            if page is not early:
                page.goto(view.url)
            page.wait_for_function(f"window.twotankView.received >= {total}")
            rows = _rows(page)
            assert set(rows) == {"A", "B"}
            for model, ws in windows.items():
                _same(rows[model], ws[-1], len(ws))
            # the latest judged window's spectrum reached the page, every number exact
            shown = page.evaluate(
                "Object.fromEntries(Array.from(window.twotankView.models.values()).map("
                "m => [m.name, [m.spectrum.spectrum.freqs_hz, m.spectrum.spectrum.w_min, "
                "m.spectrum.spectrum.noise_floor, m.spectrum.spectrum.excited]]))"
            )
            for model in ("A", "B"):
                last = [r for r in reports if r.model == model and r.judged][-1]
                keep = last.freqs_hz > 0
                freqs, w_min, floor, excited = shown[model]
                assert freqs == last.freqs_hz[keep].tolist()
                assert w_min == last.w_min[keep].tolist()
                assert len(w_min) > 100
                # the per-bin noise floor and the excited lines, as the report has them
                assert floor == last.noise_floor[keep].tolist()
                assert excited == np.flatnonzero(last.excited[keep]).tolist()
                # and as the JSON's entry of that window summarises them
                end = (last.end_ns - starts[-1]) / 1e9
                entry = next(w for w in windows[model] if w["end"] == end)
                assert entry["excited_lines"] == len(excited) > 0
                assert entry["excited_band_hz"] == [freqs[excited[0]], freqs[excited[-1]]]
            legend = page.text_content("#bin-legend") or ""
            assert "noise floor per bin" in legend
            assert "excited band" in legend
            page.close()
    # the page asked nothing of anyone but the view
    assert requests
    assert all(u.startswith(view.url) for u in requests), requests


def _report(k: int, beta: float = 0.5) -> WindowReport:
    return WindowReport(
        model="B",
        start_ns=k * 10**9,
        end_ns=(k + 409) * 10**9,
        n_periods=2,
        n_samples=512,
        judged=True,
        data_quality="ok",
        beta=beta,
        beta_lower=math.nan,
        beta_upper=math.nan,
        margin=1 - beta,
        invalidated=False,
        alarm=Alarm.OK,
        convention="power",
        solver="closed_form",
        freqs_hz=np.linspace(0.0, 0.625, 257),
        w_min=np.full(257, 0.01),
        compute_time_s=0.0,
    )


def test_the_page_says_when_reports_stop_and_clears_it_when_they_resume(browser: Any) -> None:
    with ViewServer(stale_after_s=0.4) as view:
        page = browser.new_page()
        page.goto(view.url)
        page.wait_for_function("window.twotankView.connected")
        view.publish_report(_report(0, 0.25))
        page.wait_for_function("window.twotankView.received === 1")
        assert page.get_attribute("#status", "data-stopped") == "0"
        assert page.is_hidden("#response")  # no --view-response: no such section
        # no report for longer than the limit: the sign shows (the page's own 250 ms poll)
        page.wait_for_selector('#status[data-stopped="1"]', timeout=3000)
        assert "reports stopped" in (page.text_content("#status") or "")
        view.publish_report(_report(102, 0.75))
        page.wait_for_selector('#status[data-stopped="0"]', timeout=3000)
        row = _rows(page)["B"]
        assert (_num(row["beta"]), row["count"]) == (0.75, "2")
        page.close()


def test_the_view_is_read_only_and_listens_on_127_0_0_1_only() -> None:
    with ViewServer() as view:
        assert view._httpd.server_address[0] == "127.0.0.1"
        assert view._httpd.socket.getsockname()[0] == "127.0.0.1"
        page = urllib.request.urlopen(view.url)
        assert "connect-src 'self'" in page.headers["Content-Security-Policy"]
        assert b"http" not in page.read()  # no URL anywhere in the page
        for method in ("POST", "PUT", "DELETE", "PATCH"):
            req = urllib.request.Request(view.url + "events", data=b"{}", method=method)
            with pytest.raises(urllib.error.HTTPError) as err:
                urllib.request.urlopen(req)
            assert err.value.code == 405
        with pytest.raises(urllib.error.HTTPError) as err:  # a name rebound to 127.0.0.1
            urllib.request.urlopen(urllib.request.Request(view.url, headers={"Host": "evil.x"}))
        assert err.value.code == 403
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(view.url + "reset")
        assert err.value.code == 404
        # nothing answers on the machine's other addresses
        other = socket.gethostbyname(socket.gethostname())
        if other != "127.0.0.1" and not other.startswith("127."):
            with pytest.raises(ConnectionRefusedError):
                socket.create_connection((other, view.port), timeout=1).close()


def test_a_late_visitor_gets_the_last_n_reports_and_each_model_s_latest_spectrum() -> None:
    view = ViewServer(history=3)  # not started: subscribe() is what a new page's stream sends
    try:
        view.publish(mode_message("normal", 0.0))
        view.publish(mode_message("safe", 1.5, "invalidated: model B"))
        for k in range(5):
            view.publish_report(_report(k, 0.1 * (k + 1)))
        first, _ = view.subscribe()
        docs = [json.loads(m) for m in first]
        # the mode in force, though older than the last 3 reports, then those reports
        kinds = ["hello", "mode", "report", "report", "report", "spectrum"]
        assert [d["type"] for d in docs] == kinds
        assert (docs[1]["mode"], docs[1]["time"]) == ("safe", 1.5)
        assert [d["beta"] for d in docs[2:5]] == pytest.approx([0.3, 0.4, 0.5])
        assert docs[5]["seq"] == docs[4]["seq"]  # the spectrum of the latest report
    finally:
        view.close()


def test_pacer_holds_reports_to_the_replay_speed() -> None:
    now = [100.0]
    waits: list[float] = []

    def sleep(s: float) -> None:
        waits.append(s)
        now[0] += s

    pace = Pacer(10.0, sleep=sleep, clock=lambda: now[0])
    for k in (0, 0, 50, 100):  # data s of the window ends; two models share the first
        pace(_report(k))
    assert waits == pytest.approx([5.0, 5.0])
    with pytest.raises(ValueError, match="must be > 0"):
        Pacer(0.0)


def test_view_options_are_refused_where_they_cannot_work(capsys: Any, leak_bag: Path) -> None:
    assert cli.main(["validate", str(leak_bag), "--replay-speed", "5"]) == 2
    assert "add --view" in capsys.readouterr().err
    assert cli.main(["validate", str(leak_bag), str(leak_bag), "--view"]) == 2
    assert "--view shows one recording" in capsys.readouterr().err
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = str(taken.getsockname()[1])
        assert cli.main(["validate", str(leak_bag), "--view", "--view-port", port]) == 2
    assert "choose another port" in capsys.readouterr().err


def test_cli_docs_list_the_view_options() -> None:
    """docs/cli.md: a row for each view option of live and validate, every option of view."""
    subs = next(
        a for a in cli.build_parser()._actions if isinstance(a, argparse._SubParsersAction)
    ).choices
    text = (Path(__file__).parents[1] / "docs" / "cli.md").read_text()
    for name in ("live", "validate", "view"):
        section = text.split(f"\n## {name}\n")[1].split("\n## ")[0]
        options = {
            o
            for a in subs[name]._actions
            for o in a.option_strings
            if o.startswith("--") and o != "--help"
            if name == "view" or o.startswith("--view") or o == "--replay-speed"
        }
        assert options >= {"--view-port"}, (name, options)
        for option in options:
            assert f"| `{option}" in section, f"docs/cli.md's {name} table lacks {option}"
    assert "[`view`](#view)" in text


def test_live_view_shows_the_live_json(browser: Any) -> None:
    """``live --view``: the page of a short simulated run equals ``live --json``'s lines.

    In closed loop with the supervisor watching model A (invalid on the rig: it goes safe at
    A's first judged window), the page shows the supervisor's mode as ``live --json``'s
    transition line has it, pushed when it happened: before the reports of later windows.
    """
    cmd = [sys.executable, "-m", "twotank_validation.cli", "live", "--ts", "0.8", "--period",
           "256", "--duration", "1000", "--json", "--view", "--closed-loop",
           "--supervisor", "A"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url, err = None, []
        assert proc.stderr is not None
        for line in proc.stderr:
            err.append(line)
            if m := re.match(r"view: (http://127\.0\.0\.1:\d+/)$", line.strip()):
                url = m.group(1)
            if "page stays" in line:
                break
        assert url is not None, "".join(err)
        page = browser.new_page()
        page.goto(url)
        page.wait_for_function("window.twotankView.received >= 2")
        rows = _rows(page)
        mode = page.eval_on_selector(
            "#mode", "b => ({mode: b.dataset.mode, time: b.dataset.time, seq: b.dataset.seq, "
            "hidden: b.hidden, text: b.textContent})"
        )  # fmt: skip
        page.close()
    finally:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=20)
    assert proc.returncode == 0
    lines = [json.loads(x) for x in out.splitlines() if x.startswith('{"model"')]
    for model in ("A", "B"):
        mine = [x for x in lines if x["model"] == model]
        _same(rows[model], mine[-1], len(mine))
    (tr,) = [json.loads(x)["transition"] for x in out.splitlines() if '"transition"' in x]
    assert (mode["mode"], float(mode["time"]), mode["hidden"]) == (tr["to"], tr["time"], False)
    assert tr["reason"] in mode["text"]
    # pushed as it happened: reports of windows ending after it came later
    later = [x for x in lines if x["end"] > tr["time"]]
    assert later
    assert int(mode["seq"]) < max(int(r["seq"]) for r in rows.values())


def _response_rows(page: Any) -> list[dict[str, str]]:
    return page.eval_on_selector_all(
        "#response-table tbody tr", "rs => rs.map(r => Object.assign({}, r.dataset))"
    )


def test_the_identified_response_reaches_every_page_with_the_json_s_numbers(
    browser: Any, identified: Path, capsys: Any
) -> None:
    """``--view-response``: each page's table holds the identify JSON's report, number for number.

    The reference is the JSON file itself, indexed (line, output, input) as identify writes
    it, with the models' channel names in their order; a page that comes after reports (and
    after the history has moved on, :func:`test_a_late_visitor_gets_the_identified_response_
    first`) gets it as well.
    """
    doc = json.loads(identified.read_text())
    rep = doc["report"]
    msg = view_response(argparse.Namespace(view_response=str(identified)), ("A", "B"))
    assert "matched by shape" not in capsys.readouterr().err  # the JSON names its channels
    assert msg["matched"] == "names"
    outputs, inputs = ("height", "temperature"), ("hot", "cold")
    with ViewRun(0, title="id", bands={}, speed=None, replay=False, response=msg) as run:
        assert run.server is not None
        early = browser.new_page()
        early.goto(run.server.url)
        early.wait_for_function("window.twotankView.response !== null")
        for k in range(3):
            run.report(_report(k))
        late = browser.new_page()
        late.goto(run.server.url)
        late.wait_for_function("window.twotankView.received === 3")
        for page in (early, late):
            assert page.is_visible("#response")
            assert page.locator("#response-plots canvas").count() == 4
            rows = _response_rows(page)
            assert len(rows) == len(rep["freqs_hz"]) * 4 > 0
            for r in rows:
                c, i = outputs.index(r["output"]), inputs.index(r["input"])
                k = rep["freqs_hz"].index(float(r["freq"]))
                assert [float(r["measuredRe"]), float(r["measuredIm"])] == rep["measured"][k][c][i]
                assert [float(r["nominalRe"]), float(r["nominalIm"])] == rep["nominal"][k][c][i]
                assert float(r["stdNoise"]) == rep["std_noise"][k][c][i]
                assert float(r["stdDistortion"]) == rep["std_distortion"][k][c][i]
                assert float(r["stdTotal"]) == pytest.approx(
                    math.hypot(rep["std_noise"][k][c][i], rep["std_distortion"][k][c][i])
                )
                assert float(r["weight"]) == rep["perturbation"]["weight"][k][c]
            legend = page.text_content("#response-legend") or ""
            assert "excited band" in legend
            assert "(1 ± |W|)" in legend
            page.close()


def test_a_late_visitor_gets_the_identified_response_first(identified: Path) -> None:
    msg = view_response(argparse.Namespace(view_response=str(identified)), ("A",))
    view = ViewServer(history=2)  # not started: subscribe() is what a new page's stream sends
    try:
        assert msg is not None
        view.publish(msg)
        for k in range(4):
            view.publish_report(_report(k))
        first, _ = view.subscribe()
        kinds = [json.loads(m)["type"] for m in first]
        assert kinds == ["hello", "response", "report", "report", "spectrum"]
        assert json.loads(first[1])["entries"] == msg["entries"]
    finally:
        view.close()


def test_a_wrong_view_response_file_is_exit_2_naming_the_fix(
    capsys: Any, leak_bag: Path, identified: Path, tmp_path: Path
) -> None:
    doc = json.loads(identified.read_text())
    one_input = json.loads(identified.read_text())
    for key in ("measured", "nominal", "std_noise", "std_distortion"):
        one_input["report"][key] = [[e[:1] for e in line] for line in doc["report"][key]]
    elsewhere = json.loads(identified.read_text())
    elsewhere["perturbation_weights"][0]["name"] = "pressure_multiplicative"
    files = {
        "not-json.json": ("not a json", "identify BAG --json FILE"),
        "validate.json": (json.dumps({"models": {}}), "not an identify JSON"),
        "one-input.json": (json.dumps(one_input), "2 output(s) x 1 input(s)"),
        "elsewhere.json": (json.dumps(elsewhere), "'pressure', not one of the models' outputs"),
    }
    for name, (text, why) in files.items():
        (tmp_path / name).write_text(text)
        bad = str(tmp_path / name)
        assert cli.main(["validate", str(leak_bag), "--view", "--view-response", bad]) == 2
        err = capsys.readouterr().err
        assert why in err, err
        assert err.count("\n") == 1, err  # one line
    for cmd in (["live", "--view"], ["view"]):
        assert cli.main([*cmd, "--view-response", str(tmp_path / "one-input.json")]) == 2
        assert "identify a recording of these channels" in capsys.readouterr().err
    assert cli.main(["validate", str(leak_bag), "--view-response", str(identified)]) == 2
    assert "add --view" in capsys.readouterr().err


def test_a_response_of_the_total_sigma_only_or_with_channel_names(identified: Path) -> None:
    """The other forms of the report: the total σ alone (``std``), and named channels."""
    doc = json.loads(identified.read_text())
    rep = doc["report"]
    rep["std"] = np.hypot(rep.pop("std_noise"), rep.pop("std_distortion")).tolist()
    rep["std_noise"] = rep["std"]
    del doc["inputs"], doc["outputs"]  # as an identify JSON without its channels' names
    msg = response_message(doc, ("hot", "cold"), ("height", "temperature"))
    assert msg["matched"] == "shape"
    entry = msg["entries"][1]  # height / cold
    assert (entry["output"], entry["input"]) == ("height", "cold")
    assert entry["std_distortion"] is None
    assert entry["std_total"] == [line[0][1] for line in rep["std"]]
    doc |= {"inputs": ["hot", "cold"], "outputs": ["height", "temperature"]}
    assert response_message(doc, ("hot", "cold"), ("height", "temperature"))["matched"] == "names"
    with pytest.raises(ResponseError, match="identify a recording of these channels"):
        response_message(doc, ("cold", "hot"), ("height", "temperature"))
