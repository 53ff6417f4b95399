"""The product path on real measurements (issue 22): DFKI C.1 logs -> ``robust-drake repair`` ->
``robust-drake control REPORT --controller ci`` (verdict, design YAML) -> ``simulate --design``
(the design's nominal run, repeated) and ``simulate --model`` (SP1 with the identified theta0 and
its set, on the identified arm, against SP1 with the URDF's theta0)."""

from __future__ import annotations

import glob
import json
import os

import numpy as np
import pytest
import yaml

from shared_data import dfki_root

ROOT = dfki_root()
C1 = "dfki_double_pendulum_c1"
needs_data = pytest.mark.skipif(ROOT is None, reason="shared DFKI data not available")


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """``robust-drake repair`` on the 1433xx-1437xx files, validated on the 1542xx/1545xx
    swing-ups (about 15 s)."""
    from robust_drake.cli import main

    d = os.path.join(ROOT, "design_C1")
    out = tmp_path_factory.mktemp("c1") / "repair"
    fits, vals = sorted(glob.glob(os.path.join(d, "20230629-143*.csv"))), sorted(glob.glob(os.path.join(d, "20230629-154*.csv")))
    assert len(fits) == 5 and len(vals) == 2
    assert main(["repair", *fits, "--robot", C1, "--validate", *vals, "--out", str(out), "--no-plots", "-q"]) == 0
    return out / "report.json"


@needs_data
def test_control_from_the_report_prints_the_verdict_and_writes_the_design(report, capsys):
    """CI eq. 15 from the identified 99 % set: two drawn plants (with the identified presliding
    friction and its compensation) stay within their per-joint bounds; the design YAML holds the
    controller, gains, theta0, the set, epsilon and the rate, and ``simulate --design`` repeats
    its nominal run (the same metrics to 1e-9: measured identical)."""
    from robust_drake.cli import main

    design = report.parent / "design_ci.yaml"
    rc = main(["control", str(report), "--controller", "ci", "--draws", "2", "--track-duration", "1.5",
               "--transient", "0.75"])
    text = capsys.readouterr().out
    assert "verdict: every drawn plant stayed within its bound" in text and rc == 0, text
    assert "per-joint bound [rad]" in text and f"design: {design}" in text
    doc = yaml.safe_load(design.read_text())
    model = json.loads(report.read_text())["model"]
    d = doc["design"]
    assert d["controller"] == "ci" and d["rate"] == 2500.0 and d["epsilon"] > 0
    assert d["theta0"] == model["base"]["values"] and len(d["P"]) == len(d["theta0"])
    assert len(d["K"]) == len(d["Lambda"]) == 2
    assert main(["simulate", "--design", str(design), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for k, v in doc["nominal"]["metrics"].items():
        assert abs(out[k] - v) <= 1e-9, (k, out[k], v)
    assert main(["control", str(report)]) == 2  # the design exists: not replaced without --force
    assert "--force" in capsys.readouterr().err


@needs_data
def test_sp1_with_the_identified_model_tracks_the_measured_arm_no_worse(report, capsys):
    """On the identified arm (--plant-model: the C.1 as measured, its friction and presliding
    friction included), SP1 with --model uses the identified theta0 (printed in --json) and its
    set, and tracks a filtered step no worse than SP1 with the URDF's theta0 and box (measured
    maxerr 0.71/1.48 mrad against 1.65/5.82 mrad, |error| 3.2/6.5 against 12/94 mrad)."""
    from robust_drake.cli import main

    base = ["simulate", "--robot", C1, "--controller", "sp1", "--trajectory", "step", "--duration", "2",
            "--plant-model", str(report), "--json"]
    runs = {}
    for label, extra in (("urdf", []), ("model", ["--model", str(report)])):
        assert main(base + extra) == 0
        runs[label] = json.loads(capsys.readouterr().out)
    model = json.loads(report.read_text())["model"]
    assert runs["model"]["uncertainty"]["theta0"] == model["base"]["values"]
    assert runs["model"]["uncertainty"]["kind"] == "ellipsoid" and runs["urdf"]["uncertainty"]["kind"] == "box"
    assert runs["model"]["uncertainty"]["theta0"] != runs["urdf"]["uncertainty"]["theta0"]
    for k in ("maxerr1", "maxerr2", "error1", "error2"):
        assert runs["model"][k] <= runs["urdf"][k], (k, runs["model"][k], runs["urdf"][k])
    assert np.isfinite(runs["model"]["rho"]) and runs["model"]["rho"] < runs["urdf"]["rho"]
