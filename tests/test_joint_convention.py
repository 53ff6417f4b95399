"""One joint convention (issue 25, README "Joint numbering"): every text that names a joint --
messages, warnings, report.md, the strings of report.json, effect labels, residual signal names --
numbers joints from 1 in URDF order with the URDF name beside the number, the same numbers as the
CSV columns and ``SimulationResult.to_pandas`` (``q1``, ``tau3``).

A real repair of a generated 3-joint log (the PUMA 560's first three joints, whose URDF names
``joint1..joint3`` make an off-by-one visible: "joint 1 (joint2)" is wrong), a hidden cogging
torque on the second joint (index 1), is scanned for every joint reference.
"""

import json
import logging
import re
import warnings

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("robust_drake.model_repair.pipeline")

ROBOT = "puma560_3link"
N = 3
#: "joint 2 (joint2)" / "joints 1, 3" / "joint(s) 2" / "joint 2:" ...
JOINT_NAMED = re.compile(r"\bjoint (\d+) \(([A-Za-z_][\w]*)[,)]")
JOINT_NUMBER = re.compile(r"\bjoints? ?(?:\(s\))? (\d+)\b")
#: an effect label: kind[number] (or kind[all])
LABEL = re.compile(r"\b([a-z_]+)\[(\d+|all)\]")
#: residual signal names as the CSV columns: q2, qd1, sign_qd3, qdd2, tau1
SIGNAL = re.compile(r"\b(q|qd|sign_qd|qdd|tau)(\d+)\b")
#: the old 0-based signal names (q[1], tau[0])
OLD_SIGNAL = re.compile(r"\b(q|qd|sign_qd|qdd|tau)\[\d+\]")


def _strings(x):
    """Every string inside a JSON value (keys included)."""
    if isinstance(x, str):
        yield x
    elif isinstance(x, dict):
        for k, v in x.items():
            yield str(k)
            yield from _strings(v)
    elif isinstance(x, list):
        for v in x:
            yield from _strings(v)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    import robust_drake as rd
    from robust_drake.synthetic import battery as B

    d = tmp_path_factory.mktemp("joints")
    fits, vals, truth = B.generate(ROBOT, "position_dependent", str(d), rate_hz=250.0, duration=6.0)
    assert truth["joint"] == 1  # the generator's 0-based index: the second joint, q2
    messages = []
    handler = logging.Handler()
    handler.emit = lambda rec: messages.append(rec.getMessage())
    logger = logging.getLogger("robust_drake")
    logger.addHandler(handler)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = rd.repair(fits, robot=ROBOT, validate=vals, out=str(d / "rep"), progress=messages.append)
    finally:
        logger.removeHandler(handler)
    messages += [str(w.message) for w in caught]
    out = d / "rep"
    return {"rep": json.loads((out / "report.json").read_text()), "md": (out / "report.md").read_text(),
            "messages": messages, "result": res, "dir": d, "fits": fits, "out": out}


def _texts(run):
    return [run["md"], *run["messages"], *_strings(run["rep"])]


def test_names_match_numbers(run):
    """Every "joint N (name)" pairs N with the URDF's N-th joint name; nothing says joint 0."""
    names = run["rep"]["joint_names"]
    assert names == ["joint1", "joint2", "joint3"]
    pairs = [(int(k), nm) for t in _texts(run) for k, nm in JOINT_NAMED.findall(t)]
    assert pairs, "the report names no joint"
    wrong = sorted({(k, nm) for k, nm in pairs if nm in names and names.index(nm) + 1 != k})
    assert not wrong, wrong
    numbers = {int(k) for t in _texts(run) for k in JOINT_NUMBER.findall(t)}
    assert numbers and numbers <= set(range(1, N + 1)), numbers
    assert not [t for t in _texts(run) if re.search(r"\bjoint 0\b", t)]


def test_effect_labels_and_signals_are_one_based(run):
    """Effect labels kind[k] and signal names q<k> use k = 1..3; the integer joint fields of
    report.json are the 0-based index of the same joint (label number = index + 1)."""
    from robust_drake.effects import EFFECTS

    rep = run["rep"]
    for t in _texts(run):
        for kind, k in LABEL.findall(t):
            if kind in EFFECTS and k != "all":
                assert 1 <= int(k) <= N, (kind, k, t[:200])
        for kind, k in SIGNAL.findall(t):
            assert 1 <= int(k) <= N, (kind, k, t[:200])
        assert not OLD_SIGNAL.search(t), t[:200]
    rows = (rep["effects"] + rep["selection"]["steps"] + rep["selection"]["last_ranking"]
            + rep["nominal"].get("span_candidates", []))
    assert rows
    for r in rows:
        m = LABEL.match(r["label"])
        assert m and m.group(1) == r["kind"], r["label"]
        assert m.group(2) == ("all" if r["joint"] is None else str(r["joint"] + 1)), (r["label"], r["joint"])
    for e in rep["effects"]:
        if e["joint"] is not None:
            assert e["joint_name"] == rep["joint_names"][e["joint"]]
    # the hidden cogging on the second joint is found there and said so in the words of the README
    found = [e for e in rep["effects"] if e["kind"] == "position_dependent"]
    assert found and found[0]["joint"] == 1 and found[0]["label"].startswith("position_dependent[2]")
    assert "**position_dependent** (joint 2 (joint2))" in run["md"]
    assert "numbered from 0" not in run["md"] and "from 0" not in run["md"]
    assert "1 = `joint1`, 2 = `joint2`, 3 = `joint3`" in run["md"]


def test_same_numbers_as_simulate_and_the_logs(run):
    """The report's joint k is the column q<k> / tau<k> of the log it read and of simulate's
    DataFrame; the residual's signal names are those same column names."""
    import robust_drake as rd

    log_cols = list(pd.read_csv(run["fits"][0], nrows=1).columns)
    assert log_cols == ["t"] + [f"q{k}" for k in (1, 2, 3)] + [f"tau{k}" for k in (1, 2, 3)]
    df = rd.simulate(robot=ROBOT, controller="pd", trajectory="sine", duration=0.05).to_pandas()
    for prefix in ("q", "tau", "e"):
        assert [c for c in df.columns if re.fullmatch(prefix + r"\d+", c)] == [f"{prefix}{k}" for k in (1, 2, 3)]
    variables = {d["variable"] for key in ("baseline", "final")
                 for d in run["rep"]["residual"][key].get("state_dependence_top", [])}
    assert variables
    assert {v for v in variables if SIGNAL.fullmatch(v)} == variables - {"t"}
    # the measured torque of joint k is the log's tau<k>: signal tau<k> of the residual analysis
    from robust_drake.identification.data import load
    from robust_drake.model_repair.residual import explanatory_variables

    data = load(run["fits"], robot=ROBOT)
    ev = explanatory_variables(data)
    for k in (1, 2, 3):
        np.testing.assert_array_equal(ev[f"tau{k}"], data.tau[:, k - 1])


def test_messages_in_the_callers_words(run, tmp_path, capsys):
    """Python is told overwrite=True, the command line --force; a log in degrees is named once
    with its column and the same joint number, and no option that does not exist is suggested."""
    import robust_drake as rd
    from robust_drake import cli
    from robust_drake.errors import RobustDrakeError

    with pytest.raises(RobustDrakeError) as exc:
        rd.repair(run["fits"], robot=ROBOT, out=str(run["out"]))
    assert "overwrite=True" in str(exc.value) and "--force" not in str(exc.value)
    assert cli.main(["repair", *run["fits"], "--robot", ROBOT, "--out", str(run["out"])]) == 2
    err = capsys.readouterr().err
    assert "--force" in err and "overwrite=True" not in err

    df = pd.read_csv(run["fits"][0])
    df["q2"] = np.degrees(df["q2"])
    deg = tmp_path / "degrees.csv"
    df.to_csv(deg, index=False)
    with pytest.raises(RobustDrakeError) as exc:
        rd.repair([str(deg)], robot=ROBOT, out=str(tmp_path / "r_api"))
    assert "|q2| (joint 2)" in str(exc.value) and "allow_degrees" not in str(exc.value)
    assert cli.main(["repair", str(deg), "--robot", ROBOT, "--out", str(tmp_path / "r_cli")]) == 2
    err = capsys.readouterr().err
    assert err.count("more than two turns") == 1 and "|q2| (joint 2)" in err and "allow_degrees" not in err


def test_effect_label_and_term_tokens():
    """The library's own labels: the spring on index 5 is spring[6]; a configuration term token
    s1 is sin q1 (the first joint), and its coefficient is named sin(q1)."""
    from robust_drake.effects import make_effect, parse_terms

    assert make_effect("spring", 5).name == "spring[6]"
    assert make_effect("time_delay").name.startswith("time_delay[all]")
    assert parse_terms("s1,c3") == [("s", 0), ("c", 2)]
    with pytest.raises(Exception, match="from 1"):
        parse_terms("s0")
    e = make_effect("configuration_dependent", 1, terms="s1,c1")
    assert e.name == "configuration_dependent[2](terms=s1,c1)"
    q = np.array([[0.3, 0.0, 0.0]])
    cols = e.evaluate_columns(q)
    np.testing.assert_allclose(cols[0, 1], [np.sin(0.3), np.cos(0.3)])  # on joint 2's row, functions of q1
    assert list(e.parameters([1.0, 2.0], q)) [:2] == ["sin(q1)", "cos(q1)"]


def test_model_files_of_version_1_are_read_in_the_new_numbering(tmp_path):
    """A version-1 model file (configuration terms numbered from 0) reads back with the same
    functions under the new names: "s0" on the elbow (sin of the first joint's angle) becomes
    "s1", its coefficient sin(q0) becomes sin(q1); a saved model is version 2 and reads back as
    written."""
    from robust_drake.effects import make_effect, parse_terms
    from robust_drake.identification.model import MODEL_VERSION, IdentifiedModel

    v1 = {"format": "robust_drake.identified_model", "version": 1, "robot": ROBOT,
          "joint_names": ["joint1", "joint2", "joint3"], "base": {"names": ["b0"], "values": [1.0], "covariance": None},
          "friction": {"coulomb": [0.1] * 3, "viscous": [0.01] * 3},
          "effects": [{"kind": "configuration_dependent", "joint": 2, "coefficients": [1.2, -0.8],
                       "parameters": {"terms": "s0,c0", "sin(q0)": 1.2, "cos(q0)": -0.8, "peak": 2.0}}]}
    path = tmp_path / "v1.json"
    path.write_text(json.dumps(v1))
    m = IdentifiedModel.load(str(path))
    (e,) = m.effects
    assert e.joint == 2 and e.parameters == {"terms": "s1,c1", "sin(q1)": 1.2, "cos(q1)": -0.8, "peak": 2.0}
    assert parse_terms(e.parameters["terms"]) == [("s", 0), ("c", 0)]  # still the first joint's angle
    eff = make_effect("configuration_dependent", e.joint, terms=e.parameters["terms"])
    np.testing.assert_allclose(eff.coef_from_parameters(e.parameters, 3), [1.2, -0.8])
    m.save(str(tmp_path / "v2.json"))
    doc = json.loads((tmp_path / "v2.json").read_text())
    assert doc["version"] == MODEL_VERSION == 2 and doc["effects"][0]["parameters"]["terms"] == "s1,c1"
    assert IdentifiedModel.load(str(tmp_path / "v2.json")).effects[0].parameters == e.parameters
