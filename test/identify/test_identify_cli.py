"""``identify`` from the command line: a simulated 1 × 3 plant and the Cascaded Tanks record.

References: the simulated plant's model file (the identified set must hold on a held-out
record of it and fail on the plant with a changed pump gain); for the measured rig, the
output-error fit of ``test/data/models/cascaded_tanks.yaml`` (a time-domain estimator, its
derivation in that file), against which the response measured here is checked, and the rig's
second experiment, on which the identified set is validated.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from twotank_validation import cli
from twotank_validation.core import lti
from twotank_validation.core.model import load_model

DATA = Path(__file__).parent.parent / "data"
CT = DATA / "cascaded_tanks"
CT_OPTIONS = ["--ts", "4", "--period", "1024", "--periods-per-window", "1", "--settle-periods", "0"]


def _simulate(out: Path, *extra: str) -> None:
    code = cli.main(
        [
            "simulate", "--model", str(DATA / "models" / "one_by_three.yaml"), "--format", "csv",
            "--ts", "0.1", "--period", "256", "--periods", "6", "--rms", "0.5",
            "--out", str(out), "--quiet", *extra,
        ]
    )  # fmt: skip
    assert code == cli.EXIT_OK


def _beta(path: Path, model: Path, tmp: Path, *options: str) -> list[float]:
    out = tmp / f"{path.stem}.{model.stem}.json"
    code = cli.main(
        [
            "validate", str(path), "--map", str(path.with_suffix(".map.yaml")),
            "--model", str(model), *options, "--quiet", "--json", str(out),
        ]
    )  # fmt: skip
    assert code == cli.EXIT_OK
    (windows,) = [m["windows"] for m in json.loads(out.read_text())["models"].values()]
    return [w["beta"] for w in windows if w["beta"] is not None]


def test_an_identified_set_holds_on_held_out_data_and_fails_on_a_changed_plant(
    tmp_path: Path, capsys
) -> None:
    fit, held, changed = (tmp_path / f"{n}.csv" for n in ("fit", "held", "changed"))
    _simulate(fit, "--noise-seed", "1")
    _simulate(held, "--noise-seed", "2")
    _simulate(changed, "--noise-seed", "3", "--fault", "input_gain:pump=0.8@0")
    model, report = tmp_path / "id.yaml", tmp_path / "report"
    options = ["--ts", "0.1", "--period", "256"]
    code = cli.main(
        [
            "identify", str(fit), "--map", str(fit.with_suffix(".map.yaml")), *options,
            "--orders", "1..5", "--out-model", str(model), "--json", str(tmp_path / "id.json"),
            "--report", str(report), "--quiet",
        ]
    )  # fmt: skip
    out = capsys.readouterr().out
    assert code == cli.EXIT_OK
    assert "nominal: order" in out
    doc = json.loads((tmp_path / "id.json").read_text())
    assert doc["estimator"] == "periodic"
    assert sorted(p.name for p in report.iterdir()) == sorted(
        f"{s}.{e}" for s in ("identify_bode", "identify_orders", "identify_weights")
        for e in ("pdf", "png")
    )  # fmt: skip
    assert sorted(doc["report"]) == sorted(
        ["freqs_hz", "level", "measured", "std_noise", "std_distortion", "radius", "nominal",
         "perturbation", "noise"]
    )  # fmt: skip
    assert max(_beta(held, model, tmp_path, *options)) < 1.0
    assert min(_beta(changed, model, tmp_path, *options)) > 1.0


def test_cascaded_tanks_identified_on_one_experiment_holds_on_the_other(
    tmp_path: Path, capsys
) -> None:
    model, js = tmp_path / "ct.yaml", tmp_path / "ct.json"
    code = cli.main(
        [
            "identify", str(CT / "dataBenchmark.csv"), "--map", str(CT / "estimation.map.yaml"),
            *CT_OPTIONS, "--band", "0:0.004", "--out-model", str(model), "--json", str(js),
            "--quiet",
        ]
    )  # fmt: skip
    assert code == cli.EXIT_OK, capsys.readouterr().err
    doc = json.loads(js.read_text())
    # one period with its start-up transient: the local polynomial method
    assert doc["estimator"] == "local polynomial"
    f = np.array(doc["response"]["freqs_hz"])
    g = np.array(doc["response"]["g"])[:, 0, 0]
    g = g[:, 0] + 1j * g[:, 1]
    sd = np.array(doc["response"]["std"])[:, 0, 0]
    oe = load_model(DATA / "models" / "cascaded_tanks.yaml")
    g_oe = lti.continuous_response(oe.nominal, 2 * np.pi * f)[:, 0, 0]
    # the response measured here against the independent output-error fit
    assert np.all(np.abs(g - g_oe) <= 3.5 * sd)
    # the set identified on the estimation experiment holds on the test experiment
    out = tmp_path / "test.json"
    code = cli.main(
        [
            "validate", str(CT / "dataBenchmark.csv"), "--map", str(CT / "test.map.yaml"),
            "--model", str(model), *CT_OPTIONS, "--quiet", "--json", str(out),
        ]
    )  # fmt: skip
    assert code == cli.EXIT_OK
    (w,) = json.loads(out.read_text())["models"]["identified"]["windows"]
    assert w["beta"] < 1.0


@pytest.mark.parametrize(
    ("extra", "said"),
    [
        (["--band", "3:4"], "no excited line in 3..4 Hz"),
        (["--orders", "9..2"], "--orders '9..2'"),
        (["--orders", "80..82"], "can be fitted"),
    ],
)
def test_bad_requests_are_clear_errors(tmp_path: Path, capsys, extra: list[str], said: str) -> None:
    rec = tmp_path / "r.csv"
    _simulate(rec, "--noise-seed", "1")
    code = cli.main(
        ["identify", str(rec), "--map", str(rec.with_suffix(".map.yaml")), "--ts", "0.1",
         "--period", "256", "--quiet", *extra]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert code == cli.EXIT_ERROR
    assert said in err
    assert "Traceback" not in err


def test_an_order_whose_poles_the_data_do_not_determine_is_named(tmp_path: Path, capsys):
    """Order 14, far above the 1 x 3 plant's own: some poles sit within a few σ of the origin
    (fit_rational's standard deviations): the summary says so and names the fix."""
    rec = tmp_path / "r.csv"
    _simulate(rec, "--noise-seed", "1")
    code = cli.main(
        ["identify", str(rec), "--map", str(rec.with_suffix(".map.yaml")), "--ts", "0.1",
         "--period", "256", "--orders", "14..14"]
    )  # fmt: skip
    out = capsys.readouterr()
    assert code == cli.EXIT_OK
    assert "no order in 14..14 has every pole determined by the data" in out.err + out.out
    assert "--orders" in out.err + out.out


def _table(path: Path, u: np.ndarray, y: np.ndarray) -> Path:
    import pandas as pd  # noqa: PLC0415

    pd.DataFrame({"t": np.arange(u.size) * 0.1, "u": u, "y": y}).to_csv(path, index=False)
    imap = path.with_suffix(".map.yaml")
    imap.write_text(
        "inputs:\n  - {name: u, column: u}\noutputs:\n  - {name: y, column: y}\n"
        "time: {column: t, unit: s}\n"
    )
    return imap


@pytest.mark.parametrize(
    ("samples", "said"),
    [(6 * 256, "input not periodic"), (200, "the recording holds no whole window")],
)
def test_a_non_periodic_input_or_too_short_a_record_is_refused_with_the_fix(
    tmp_path: Path, capsys, samples: int, said: str
) -> None:
    """White noise does not repeat every period; 200 samples hold no whole window."""
    rng = np.random.default_rng(0)
    u = rng.standard_normal(6 * 256)
    y = np.convolve(u, 0.1 * 0.9 ** np.arange(60))[: u.size]
    imap = _table(tmp_path / "r.csv", u[:samples], y[:samples])
    code = cli.main(["identify", str(tmp_path / "r.csv"), "--map", str(imap), "--period", "256"])
    err = capsys.readouterr().err
    assert code != cli.EXIT_OK
    assert said in err
    assert "no window to identify from could be judged" in err
    assert "identify_probe" not in err  # no internal name
    assert "--period" in err  # the fix named
    assert "Traceback" not in err


def test_delays_are_written_into_the_model_file_and_it_holds_on_held_out_data(
    tmp_path: Path,
) -> None:
    """The delays fitted (here they absorb the hold's half sample and what order 3 leaves)
    are the model file's ``output_delays_s``, and that file validates a held-out record."""
    rec, held, js, model = (tmp_path / n for n in ("r.csv", "h.csv", "r.json", "m.yaml"))
    _simulate(rec, "--noise-seed", "1")
    _simulate(held, "--noise-seed", "2")
    code = cli.main(
        ["identify", str(rec), "--map", str(rec.with_suffix(".map.yaml")), "--ts", "0.1",
         "--period", "256", "--orders", "2..3", "--delays", "--quiet", "--json", str(js),
         "--out-model", str(model)]
    )  # fmt: skip
    assert code == cli.EXIT_OK
    fit = json.loads(js.read_text())["fit"]
    written = load_model(model).nominal.output_delays_s
    assert written == pytest.approx(fit["delays_s"])
    assert max(_beta(held, model, tmp_path, "--ts", "0.1", "--period", "256")) < 1.0
