"""Issue 24 (hostile input, round 3): no silent wrong result, no traceback, no lost report.

One test (or a parametrised family) per class of the issue: the floating / missing world joint,
the other robot's validation file, joined logs, a cut last line, zero-tick runs, bascetta with
absurd gains, duplicate YAML keys, API options validated like the CLI, the SIGKILL between the
renames of ``--force``, ``--effects ""`` and the 7-joint batch summary; the hangs (a 3-million
product, a FIFO); the tracebacks (IV on rank-deficient columns from a URDF with joint damping,
a full disk / ``ulimit -f``, ``--out D --plot D``, batch specs, ``ellipsoid --data``, ``demo
--out FILE``, API types); the causes named (time units, encoder counts, offsets, sign flips,
wrapped angles, trailing commas, gzip, Latin-1, comment lines, ``q1,q3``, ``--cutoff 0.01``, a
mimic joint); duplicated log lines, SIGTERM of a batch, and progress of a long run.

The logs are the project's simulated experiment (DFKI C.1 URDF, PD-tracked Fourier excitation,
14-bit encoder, torque noise; ``simulated.py``), so no shared data is needed.
"""

from __future__ import annotations

import errno
import gzip
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pandas as pd
import pytest

from robust_drake import cli
from robust_drake.errors import RobustDrakeError

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROBOT = "dfki_double_pendulum_c1"
QUICK = ["--no-replay", "--no-consistent", "--no-instruments", "--no-nominal", "--no-plots",
         "--max-effects", "1"]


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = REPO + os.pathsep + env.get("PYTHONPATH", "")
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    return env


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """Fit (seed 0) and validation (seed 1) CSVs of the simulated C.1, 12 s at 250 Hz, and a
    validation log of another arm (the Siciliano 2-link, same columns)."""
    from robust_drake.synthetic.simulated import simulate_experiment

    d = tmp_path_factory.mktemp("sim")
    paths = {k: str(d / f"{k}.csv") for k in ("fit", "val", "other")}
    simulate_experiment(ROBOT, duration=12.0, seed=0, out_csv=paths["fit"])
    simulate_experiment(ROBOT, duration=12.0, seed=1, out_csv=paths["val"])
    simulate_experiment("siciliano_2link", duration=12.0, seed=1, out_csv=paths["other"])
    return paths


def _run(capsys, *args):
    status = cli.main([*map(str, args)])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return status, out, err


def _repair(capsys, *args):
    return _run(capsys, "repair", *args)


def _error(capsys, *args):
    status, _, err = _run(capsys, *args)
    assert status == 2, err
    lines = [ln for ln in err.splitlines() if ln.startswith("error: ")]
    assert len(lines) == 1, err
    return lines[0]


def _warnings(err):
    return [ln[len("warning: "):] for ln in err.splitlines() if ln.startswith("warning: ")]


def _lines(path):
    return open(path).read().splitlines()


def _write_lines(path, lines, end="\n"):
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + end)
    return str(path)


# ----------------------------------------------------------------------------- 1 world joint
def _c1_urdf(tmp_path, world_joint: str):
    """The C.1 URDF with its world joint as shipped ("fixed", rpy turning the arm into the
    vertical plane), as "floating", or removed ("none")."""
    from robust_drake.models import resolve_urdf

    text = open(resolve_urdf(ROBOT)).read()
    if world_joint == "none":
        text = re.sub(r'<joint name="base_weld".*?</joint>', "", text, flags=re.S)
    else:
        text = text.replace('<joint name="base_weld" type="fixed">', f'<joint name="base_weld" type="{world_joint}">')
    path = tmp_path / f"c1_{world_joint}.urdf"
    path.write_text(text)
    return str(path)


def test_floating_world_joint_is_refused_unless_a_floating_base_is_asked_for(sim, tmp_path, capsys):
    from robust_drake.models import make_plant

    urdf = _c1_urdf(tmp_path, "floating")
    msg = _error(capsys, "repair", sim["fit"], "--robot", urdf, "--out", tmp_path / "rep", *QUICK)
    assert "'base_weld'" in msg and "floating" in msg and 'type to "fixed"' in msg
    assert not (tmp_path / "rep").exists()
    with pytest.raises(RobustDrakeError, match="floating"):
        make_plant(urdf)
    assert make_plant(urdf, floating_base=True).num_velocities() == 6 + 2  # asked for: a free base


def test_missing_world_joint_is_welded_and_said_loudly_in_the_report(sim, tmp_path, capsys):
    """Without the world joint the C.1 (a vertical pendulum) is welded at the identity: its joint
    axes are then vertical and gravity reaches no joint. That is said on the console and in
    report.json / report.md; with the shipped fixed joint (its rpy kept) nothing is said and
    gravity acts."""
    from robust_drake.models import gravity_reaches_joints, make_plant

    assert gravity_reaches_joints(make_plant(_c1_urdf(tmp_path, "fixed")))
    assert not gravity_reaches_joints(make_plant(_c1_urdf(tmp_path, "none")))
    for kind, expect in (("none", True), ("fixed", False)):
        out = tmp_path / f"rep_{kind}"
        status, _, err = _repair(capsys, sim["fit"], "--robot", _c1_urdf(tmp_path, kind), "--validate", sim["val"],
                                 "--out", out, *QUICK)
        assert status == 0
        said = [w for w in _warnings(err) if "no joint to the world" in w]
        rep = json.load(open(out / "report.json"))
        in_report = [w for w in rep["warnings"] if "no joint to the world" in w]
        assert bool(said) == expect and said == in_report
        if expect:
            assert "gravity then produces NO torque" in said[0]
            assert said[0] in open(out / "report.md").read()


# ----------------------------------------------------------------------------- 2 other robot
def test_validation_log_of_another_robot_is_flagged(sim, tmp_path, capsys):
    out = tmp_path / "rep"
    status, _, err = _repair(capsys, sim["fit"], "--robot", ROBOT, "--validate", sim["other"], "--out", out, *QUICK)
    assert status == 0
    flagged = [w for w in _warnings(err) if w.startswith("validation files:") and "another robot" in w]
    assert len(flagged) == 1
    assert flagged[0] in json.load(open(out / "report.json"))["warnings"]
    # the arm's own validation log is not flagged
    status, _, err = _repair(capsys, sim["fit"], "--robot", ROBOT, "--validate", sim["val"], "--out", tmp_path / "ok",
                             *QUICK)
    assert not [w for w in _warnings(err) if w.startswith("validation files:")]


# ----------------------------------------------------------------------------- 3 joined logs
def test_two_logs_joined_with_shifted_stamps_are_flagged_and_split(sim, tmp_path, capsys):
    from robust_drake.identification.conditioning import position_jumps
    from robust_drake.identification.data import load

    a, b = pd.read_csv(sim["fit"]), pd.read_csv(sim["val"])
    joined = pd.concat([a.iloc[:1500], b.iloc[1500:]])  # stamps continue, positions jump
    path = tmp_path / "joined.csv"
    joined.to_csv(path, index=False)
    # the untouched logs have no jump the motion cannot make
    assert position_jumps(a[["q1", "q2"]].to_numpy()) == [] and position_jumps(b[["q1", "q2"]].to_numpy()) == []
    data = load(str(path), n_joints=2, quiet=True)
    assert len(np.unique(data.segment)) == 2  # split at the joint
    out = tmp_path / "rep"
    status, _, err = _repair(capsys, path, "--robot", ROBOT, "--validate", sim["val"], "--out", out, *QUICK)
    assert status == 0
    said = [w for w in _warnings(err) if "jumps by" in w and "file lines 1501 and 1502" in w]
    assert said and set(said) <= set(json.load(open(out / "report.json"))["warnings"])


def test_a_run_that_starts_accelerating_is_not_a_joined_log():
    """The first step of a run may exceed the second by a second difference (a hard start: the
    demo's D2R2 validation run, q2 steps 3.35 then 3.00 mrad); with one neighbour that is no jump."""
    from robust_drake.identification.conditioning import position_jumps

    t = np.arange(0.0, 4.0, 0.004)
    # joint 1 starts with a fast transient (steps 3.05, 2.58, 2.34 mrad, then the sine's ~2.1)
    q = np.column_stack([0.3 + 0.9 * np.sin(2.1 * t), 0.34 + 0.4 * np.sin(1.3 * t) + 0.002 * (1 - np.exp(-t / 0.006))])
    assert position_jumps(q) == []
    q[600:, 1] += 0.05  # a real jump in the middle is still found
    assert [(k, j) for k, j, _, _ in position_jumps(q)] == [(599, 1)]


def test_wrapped_angle_is_unwrapped_not_split(sim, tmp_path):
    from robust_drake.identification.data import load

    df = pd.read_csv(sim["fit"])
    df["q1"] = df["q1"] * 4  # a wide swing, then wrapped into (-pi, pi]
    wide = tmp_path / "wide.csv"
    df.to_csv(wide, index=False)
    df["q1"] = np.angle(np.exp(1j * df["q1"]))
    wrapped = tmp_path / "wrapped.csv"
    df.to_csv(wrapped, index=False)
    d = load(str(wrapped), n_joints=2, quiet=True)
    assert any("a wrapped angle; unwrapped" in w for w in d.warnings)
    assert len(np.unique(d.segment)) == 1
    ref = load(str(wide), n_joints=2, quiet=True)
    np.testing.assert_allclose(np.ptp(d.q, axis=0), np.ptp(ref.q, axis=0), rtol=1e-9)


# ----------------------------------------------------------------------------- 4 cut last line
def test_last_line_cut_inside_a_number_is_flagged_and_left_out(sim, tmp_path, capsys):
    from robust_drake.identification.data import read_csv

    lines = _lines(sim["fit"])
    last = lines[-1].split(",")
    last[-2] = "%.8e" % (10 * float(last[-2]) + 1.0)  # tau1 as a long number, then cut inside it
    lines[-1] = ",".join(last[:-1])[:-5]
    cut = _write_lines(tmp_path / "cut.csv", lines, end="")
    raw = read_csv(cut)
    assert len(raw.t) == len(lines) - 2  # header and the cut line
    out = tmp_path / "rep"
    status, _, err = _repair(capsys, cut, "--robot", ROBOT, "--validate", sim["val"], "--out", out, *QUICK)
    assert status == 0
    said = [w for w in _warnings(err) if "does not end with a newline" in w and f"file line {len(lines)}" in w]
    assert len(said) == 1 and said[0] in json.load(open(out / "report.json"))["warnings"]


# ----------------------------------------------------------------------------- 5 zero ticks
@pytest.mark.parametrize("argv", [
    ["simulate", "--duration", "0.2", "--rate", "1"],
    ["simulate", "--duration", "1e-9"],
    ["compare", "--table", "2", "--rate", "1"],
    ["sweep-rate", "--rates", "1"],
])
def test_runs_of_fewer_than_a_few_ticks_are_refused(argv, capsys):
    from robust_drake.diagram import MIN_TICKS

    msg = _error(capsys, *argv)
    assert f"a run needs at least {MIN_TICKS}" in msg


# ----------------------------------------------------------------------------- 6 bascetta
def test_bascetta_with_absurd_gains_says_diverged(capsys):
    status, out, err = _run(capsys, "bascetta", "--gains", "1e12,1e6")
    assert status == 1
    assert "Case A DIVERGED" in out and "Case B DIVERGED" in out
    assert "% lower" not in out and "not compared" in out
    assert "RuntimeWarning" not in err


# ----------------------------------------------------------------------------- 7 YAML
@pytest.mark.parametrize("text, expect", [
    ("controllers: [pd]\nloads: [none]\ncontrollers: [sp1]\n", r"line 3: key 'controllers' appears twice.*line 1"),
    ("duration: 0.5\nrates: [fast]\n", r"'rate' must be a number > 0"),
    ("duration: 0.5\nseeds: [0.5]\n", r"'seed' must be a whole number"),
    ("duration: [0.5]\n", r"'duration' must be a number"),
])
def test_bad_batch_specs_are_refused_in_one_line(tmp_path, capsys, text, expect):
    spec = tmp_path / "spec.yaml"
    spec.write_text(text)
    msg = _error(capsys, "batch", spec, "--out", tmp_path / "r.parquet")
    assert re.search(expect, msg), msg


def test_binary_spec_and_json_duplicates_are_refused(tmp_path, capsys):
    spec = tmp_path / "spec.yaml"
    spec.write_bytes(bytes(range(256)) * 4)
    assert "not a text file" in _error(capsys, "batch", spec, "--out", tmp_path / "r.parquet")
    js = tmp_path / "spec.json"
    js.write_text('{"controllers": ["pd"], "controllers": ["sp1"]}')
    assert "appears twice" in _error(capsys, "batch", js, "--out", tmp_path / "r.parquet")


def test_yaml_exponent_numbers_are_numbers():
    from robust_drake.scenario import yaml_load

    doc = yaml_load("rates: [2.5e3, 1e3]\nduration: 5e-1\nlabel: 1e3x\n")
    assert doc == {"rates": [2500.0, 1000.0], "duration": 0.5, "label": "1e3x"}


def test_product_of_three_million_scenarios_is_refused_in_under_a_second(tmp_path):
    from robust_drake.scenario import MAX_SCENARIOS, load_spec

    lst = lambda n: "[" + ",".join(str(i + 1) for i in range(n)) + "]"  # noqa: E731
    spec = tmp_path / "big.yaml"
    spec.write_text(f"controllers: [pd, sp1, sp2]\nseeds: {lst(1000)}\nrates: {lst(1000)}\n")
    t0 = time.perf_counter()
    with pytest.raises(RobustDrakeError, match=r"3,000,000 scenarios \(3 controllers x 1000 seeds x 1000 rates\)"):
        load_spec(spec)
    assert time.perf_counter() - t0 < 1.0  # counted, not expanded (a regression guard, not a benchmark)
    assert MAX_SCENARIOS < 3_000_000


# ----------------------------------------------------------------------------- 8 options
@pytest.mark.parametrize("api, argv, text", [
    ({"min_gain": -1}, ["--min-gain=-1"], "must be >= 0"),
    ({"min_gain": float("nan")}, ["--min-gain", "nan"], "must be >= 0"),
    ({"max_effects": -1}, ["--max-effects=-1"], "must be"),
    ({"effects": ""}, ["--effects", ""], "is empty"),
    ({"effects": "payload,nonsense"}, ["--effects", "payload,nonsense"], "unknown effect kind(s) ['nonsense']"),
    ({"sigma_rel": 0}, ["--sigma-rel", "0"], "must be > 0"),
    ({"cutoff_hz": float("inf")}, ["--cutoff", "inf"], "must be > 0 and finite"),
])
def test_api_options_are_validated_like_the_cli(sim, tmp_path, capsys, api, argv, text):
    """The same rule refuses both spellings; the API's message names its keyword, the CLI's its flag."""
    import robust_drake as rd

    with pytest.raises(RobustDrakeError) as exc:
        rd.repair(sim["fit"], ROBOT, out=tmp_path / "api", **api)
    assert text in str(exc.value) and "--" not in str(exc.value)
    assert str(exc.value).startswith(next(iter(api)))
    try:
        msg = _error(capsys, "repair", sim["fit"], "--robot", ROBOT, "--out", tmp_path / "cli", *argv)
    except SystemExit as stop:  # argparse's own check (exit 2, usage line)
        assert stop.code == 2
        msg = capsys.readouterr().err
    assert text in msg and argv[0].split("=")[0] in msg
    assert not (tmp_path / "api").exists() and not (tmp_path / "cli").exists()


@pytest.mark.parametrize("kwargs, text", [
    ({"fit": 123}, "logs must be CSV paths, an array"),
    ({"fit": None}, "logs must be CSV paths, an array"),
    ({"robot": None}, "robot must be a robot name"),
    ({"cutoff_hz": "8"}, "cutoff_hz must be a number"),
    ({"progress": 42}, "progress must be a callable"),
    ({"out": 123}, "out must be a folder path"),
    ({"effects": ["payload", 3]}, "unknown effect kind(s) ['payload', 3]"[:20]),
])
def test_api_wrong_types_are_refused_before_anything_runs(sim, kwargs, text, tmp_path, monkeypatch):
    import robust_drake as rd

    monkeypatch.chdir(tmp_path)
    args = {"fit": sim["fit"], "robot": ROBOT, **kwargs}
    with pytest.raises(RobustDrakeError) as exc:
        rd.repair(args.pop("fit"), args.pop("robot"), **args)
    assert text in str(exc.value)
    assert os.listdir(tmp_path) == []  # out=123 no longer writes ./123/


@pytest.mark.parametrize("mutate, text", [
    (lambda d: d["base"]["values"].__setitem__(0, None), "base.values must hold finite numbers; entry 0 is None"),
    (lambda d: d["base"]["values"].__setitem__(1, "x"), "entry 1 is 'x'"),
    (lambda d: d["friction"]["coulomb"].append(0.1), "friction.coulomb has 3 values for 2 joints"),
    (lambda d: d["base"]["values"].pop(), "base.values has"),
    (lambda d: d.pop("joint_names"), "joint_names is missing"),
])
def test_identified_model_json_is_checked(mutate, text):
    from robust_drake.identification.model import IdentifiedModel

    good = IdentifiedModel(robot=ROBOT, joint_names=["joint1", "joint2"], base_names=["a", "b", "c"],
                           base_values=np.array([1.0, 2.0, 3.0]), base_covariance=None,
                           coulomb=np.array([0.1, 0.2]), viscous=np.array([0.0, 0.01])).to_json()
    IdentifiedModel.from_json(json.loads(json.dumps(good)))
    bad = json.loads(json.dumps(good))
    mutate(bad)
    with pytest.raises(RobustDrakeError, match="not a valid identified model") as exc:
        IdentifiedModel.from_json(bad)
    assert text in str(exc.value)


def test_identified_model_of_another_robot_is_refused_when_used():
    from robust_drake.identification.least_squares import load_regressor
    from robust_drake.identification.model import IdentifiedModel

    reg = load_regressor("siciliano_2link")
    m = IdentifiedModel(robot=ROBOT, joint_names=["joint1", "joint2"], base_names=list(reg.base_names),
                        base_values=np.ones(len(reg.base_names)), base_covariance=None,
                        coulomb=np.zeros(2), viscous=np.zeros(2))
    if list(load_regressor(ROBOT).base_names) == list(reg.base_names):
        pytest.skip("the two arms share base-parameter names")
    with pytest.raises(RobustDrakeError, match="does not belong to this robot"):
        m.predict_torque(np.zeros((1, 2)), np.zeros((1, 2)), np.zeros((1, 2)))


# ----------------------------------------------------------------------------- 9 --force swap
_KILL_SCRIPT = r"""
import os, signal, sys
from robust_drake import cli
from robust_drake.model_repair import pipeline as P
mode = sys.argv[1]
if mode == "renames":  # no atomic exchange: the two renames, killed between them
    P._exchange = lambda a, b: False
    real = os.rename
    def rename(src, dst):
        real(src, dst)
        if os.path.basename(dst).startswith(".rep.old-"):
            os.kill(os.getpid(), signal.SIGKILL)
    os.rename = rename
else:  # the exchange done, killed before the old report is removed
    real = P._exchange
    def exchange(a, b):
        ok = real(a, b)
        os.kill(os.getpid(), signal.SIGKILL)
        return ok
    P._exchange = exchange
sys.exit(cli.main(["repair", *sys.argv[2:]]))
"""


@pytest.mark.parametrize("mode", ["exchange", "renames"])
def test_sigkill_while_force_replaces_the_report_loses_nothing(sim, tmp_path, capsys, mode):
    from robust_drake.model_repair.pipeline import _exchange

    out = tmp_path / "rep"
    args = [sim["fit"], "--robot", ROBOT, "--validate", sim["val"], "--out", str(out), *QUICK]
    assert _repair(capsys, *args)[0] == 0
    before = json.load(open(out / "report.json"))
    probe_a, probe_b = tmp_path / "pa", tmp_path / "pb"
    probe_a.mkdir(), probe_b.mkdir()
    if mode == "exchange" and not _exchange(str(probe_a), str(probe_b)):
        pytest.skip("no atomic exchange on this system / file system")
    proc = subprocess.run([sys.executable, "-c", _KILL_SCRIPT, mode, *args, "--force"], env=_env(),
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    leftovers = [p for p in os.listdir(tmp_path) if p.startswith(".rep.")]
    assert leftovers  # the kill left something behind
    if mode == "exchange":
        # at every instant --out held a complete report: here the new one
        assert json.load(open(out / "report.json"))["samples"] == before["samples"]
        assert (out / "report.md").exists()
    else:
        assert not out.exists()  # killed between the two renames
    # the next run puts the earlier report back (or drops the stale copy), says so, and refuses
    # to overwrite it without --force
    msg = _error(capsys, "repair", *args)
    assert "holds an earlier repair report" in msg
    assert json.load(open(out / "report.json"))["samples"] == before["samples"]
    assert [p for p in os.listdir(tmp_path) if p.startswith(".rep.")] == []
    status, _, err = _repair(capsys, *args, "--force")
    assert status == 0


def test_stale_temporary_folders_of_a_killed_run_are_removed_and_said(sim, tmp_path, capsys):
    out = tmp_path / "rep"
    stale = tmp_path / ".rep.tmp-999999999-abc"  # a pid that cannot be running
    stale.mkdir()
    (stale / "report.json").write_text("{}")
    status, _, err = _repair(capsys, sim["fit"], "--robot", ROBOT, "--validate", sim["val"], "--out", out, *QUICK)
    assert status == 0 and not stale.exists()
    said = [w for w in _warnings(err) if "unfinished report of a killed run" in w]
    assert len(said) == 1 and said[0] in json.load(open(out / "report.json"))["warnings"]


# ----------------------------------------------------------------------------- 10 batch metric
def test_seven_joint_batch_summarises_a_defined_metric(tmp_path, capsys):
    spec = tmp_path / "s7.yaml"
    spec.write_text("robot: serial7\ntrajectory: sine\nduration: 0.1\nrate: 500\ncontrollers: [pd]\nobserver: exact\n")
    status, out, err = _run(capsys, "batch", spec, "--out", tmp_path / "s7.parquet", "--workers", "1", "--json",
                            "--no-progress")
    doc = json.loads(out)
    assert status == 0 and doc["status_counts"]["ok"] == 1
    assert doc["metric"] == "maxerr_joints" and "planar 2-link" in doc["metric_note"]
    row = doc["summary"][0]
    df = pd.read_parquet(tmp_path / "s7.parquet")
    assert row["worst"] == pytest.approx(max(df[f"maxerr{j}"].iloc[0] for j in range(1, 8)))


# ----------------------------------------------------------------------------- hangs: FIFO
@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs")
def test_fifo_fit_file_is_read_once(sim, tmp_path):
    fifo = tmp_path / "fit.fifo"
    os.mkfifo(fifo)
    content = open(sim["fit"], "rb").read()

    def writer():  # opens the FIFO once: a second open by the reader would wait forever
        with open(fifo, "wb") as fh:
            fh.write(content)

    t = threading.Thread(target=writer, daemon=True)
    t.start()
    proc = subprocess.run([sys.executable, "-m", "robust_drake.cli", "repair", str(fifo), "--robot", ROBOT,
                           "--validate", sim["val"], "--out", str(tmp_path / "rep"), "--no-replay",
                           "--no-consistent", "--no-nominal", "--no-plots", "--max-effects", "1", "-q"],
                          env=_env(), capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr
    assert json.load(open(tmp_path / "rep" / "report.json"))["samples"] > 2000


# ----------------------------------------------------------------------------- tracebacks
def test_urdf_with_joint_damping_repairs_with_iv_like_the_plain_urdf(sim, tmp_path, capsys):
    """Drake's damping columns duplicate the viscous ones; the IV solve must handle the rank like
    least squares, and the damping must not be a second column: the repair is then the plain one."""
    from robust_drake.identification.instruments import solve_iv
    from robust_drake.identification.least_squares import solve_ls
    from robust_drake.models import resolve_urdf

    text = open(resolve_urdf(ROBOT)).read()
    for j in (1, 2):
        text = text.replace(f'<joint name="joint{j}" type="continuous">',
                            f'<joint name="joint{j}" type="continuous"><dynamics damping="0.01" friction="0.05"/>')
    urdf = tmp_path / "damped.urdf"
    urdf.write_text(text)
    args = ["--validate", sim["val"], "--no-replay", "--no-consistent", "--no-plots", "--json"]
    reps = []
    for robot in (urdf, ROBOT):
        status, out, _ = _repair(capsys, sim["fit"], "--robot", robot, "--out", tmp_path / f"r{len(reps)}", *args)
        assert status == 0
        reps.append(json.loads(out))
    damped, plain = reps
    assert damped["estimator"]["method"] == plain["estimator"]["method"] == "instrumental_variables"
    np.testing.assert_allclose(damped["final"]["rms_validate"], plain["final"]["rms_validate"], rtol=1e-9)
    assert any("joint damping" in w for w in damped["warnings"])
    # the solve itself on exactly duplicated columns: LS and IV both fit on the identifiable subspace
    rng = np.random.default_rng(0)
    Y = rng.normal(size=(400, 1, 3))
    Y = np.concatenate([Y, Y[:, :, 2:3]], axis=2)  # column 3 = column 2
    tau = Y[:, :, :3] @ np.array([1.0, -2.0, 0.5]) + 0.01 * rng.normal(size=(400, 1))
    Z = Y + 0.001 * rng.normal(size=Y.shape)
    ls, iv = solve_ls(Y, tau, list("abcd"), warn=False), solve_iv(Y, Z, tau, list("abcd"))
    for fit in (ls, iv):
        assert fit.theta[2] + fit.theta[3] == pytest.approx(0.5, abs=0.01)
        assert np.isinf(fit.se[2]) and np.isinf(fit.se[3]) and set(fit.unidentifiable) == {"c", "d"}


def test_disk_full_is_one_line_and_leaves_nothing_behind(sim, tmp_path, capsys, monkeypatch):
    from robust_drake.model_repair import pipeline as P

    def full(report, folder):
        raise OSError(errno.ENOSPC, "No space left on device", os.path.join(folder, "report.json"))

    monkeypatch.setattr(P, "write_report_files", full)
    msg = _error(capsys, "repair", sim["fit"], "--robot", ROBOT, "--validate", sim["val"], "--out",
                 tmp_path / "rep", *QUICK)
    assert msg.startswith("error: disk full writing") and "report.json" in msg
    assert os.listdir(tmp_path) == []


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_FSIZE")
def test_file_size_limit_is_named_and_leaves_nothing_behind(sim, tmp_path):
    import resource

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))  # ulimit -f 4

    out = tmp_path / "rep"
    proc = subprocess.run([sys.executable, "-m", "robust_drake.cli", "repair", sim["fit"], "--robot", ROBOT,
                           "--validate", sim["val"], "--out", str(out), *QUICK], env=_env(),
                          capture_output=True, text=True, timeout=240, preexec_fn=limit)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert "file too large for the file-size limit (ulimit -f)" in proc.stderr
    assert os.listdir(tmp_path) == []


def test_batch_disk_full_keeps_the_finished_rows_and_no_torn_file(tmp_path, capsys, monkeypatch):
    from robust_drake import batch as B

    spec = tmp_path / "spec.yaml"
    spec.write_text("duration: 0.05\ncontrollers: [pd, sp1]\n")
    out = tmp_path / "b.parquet"
    real, calls = B.ResultStore.append, []

    def append(self, row):
        calls.append(1)
        if len(calls) == 2:  # the second row finds the disk full
            raise OSError(errno.ENOSPC, "No space left on device", str(self.parts / "x.parquet"))
        real(self, row)

    monkeypatch.setattr(B.ResultStore, "append", append)
    msg = _error(capsys, "batch", spec, "--out", out, "--workers", "1", "--no-progress")
    assert msg.startswith("error: disk full")
    assert len(pd.read_parquet(out)) == 1  # the finished row is in the results file
    assert sorted(os.listdir(tmp_path)) == ["b.parquet", "spec.yaml"]  # no .parts, no torn temporary


def test_out_and_plot_the_same_folder(sim, tmp_path, capsys):
    out = tmp_path / "rep"
    status, _, _ = _repair(capsys, sim["fit"], "--robot", ROBOT, "--validate", sim["val"], "--out", out,
                           "--plot", out, "--no-replay", "--no-consistent", "--no-instruments", "--no-nominal",
                           "--max-effects", "1")
    assert status == 0 and (out / "residual_fit.png").exists()


def test_ellipsoid_data_with_a_short_row_and_demo_out_file(tmp_path, capsys):
    data = tmp_path / "d.csv"
    data.write_text("q1,q2,qd1,qd2,qdd1,qdd2,tau1,tau2\n0.1,0.2,0,0,1,1,2,3\n0.3,0.2,0,0\n")
    msg = _error(capsys, "ellipsoid", "--data", data)
    assert "'qdd1' at data row 2" in msg and "fewer values than the header" in msg
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert "is a file, not a folder" in _error(capsys, "demo", "--out", afile)


@pytest.mark.parametrize("call, text", [
    (lambda rd: rd.ellipsoid(samples=2.5), "samples must be a whole number >= 1, got 2.5"),
    (lambda rd: rd.ellipsoid(samples="5"), "samples must be a whole number >= 1, got '5'"),
    (lambda rd: rd.simulate(true_theta=[1.0], duration=0.05), "must hold the 3 parameters of JS eq. 14"),
])
def test_api_wrong_types_of_other_entry_points(call, text):
    import robust_drake as rd

    with pytest.raises(RobustDrakeError) as exc:
        call(rd)
    assert text in str(exc.value)


def test_least_squares_refuses_nan():
    from robust_drake.errors import DataError
    from robust_drake.identification.least_squares import solve_ls

    Y = np.ones((20, 2, 3)) + np.arange(120).reshape(20, 2, 3) ** 0.5
    tau = np.ones((20, 2))
    tau[3, 1] = np.nan
    with pytest.raises(DataError, match="NaN"):
        solve_ls(Y, tau, list("abc"))


# ----------------------------------------------------------------------------- causes named
def _mutated(src, dst, fn):
    df = pd.read_csv(src)
    fn(df)
    df.to_csv(dst, index=False)
    return str(dst)


@pytest.mark.parametrize("name, fn, expect", [
    ("us", lambda d: d.__setitem__("t", d["t"] * 1e6), r"time looks like microseconds.*divide by 1e\+06 for 250 Hz"),
    ("ns", lambda d: d.__setitem__("t", d["t"] * 1e9), r"time looks like nanoseconds.*divide by 1e\+09 for 250 Hz"),
    ("counts", lambda d: d.__setitem__("q2", np.round(d["q2"] * 4096 / (2 * np.pi))), r"raw encoder counts"),
    ("turns", lambda d: d.__setitem__("q1", d["q1"] + 6 * np.pi), r"multi-turn encoder offset of about 3\.0 turns"),
    ("deg", lambda d: d.__setitem__("q1", np.degrees(d["q1"]) * 3), r"positions look like degrees"),
])
def test_wrong_units_name_their_cause(sim, tmp_path, capsys, name, fn, expect):
    bad = _mutated(sim["fit"], tmp_path / f"{name}.csv", fn)
    msg = _error(capsys, "repair", bad, "--robot", ROBOT, "--out", tmp_path / "rep", *QUICK)
    assert re.search(expect, msg), msg
    assert "allow_degrees" not in msg


def test_sign_flip_is_named(sim, tmp_path, capsys):
    bad = _mutated(sim["fit"], tmp_path / "flip.csv", lambda d: d.update(-d.filter(like="tau")))
    status, _, err = _repair(capsys, bad, "--robot", ROBOT, "--validate", sim["val"], "--out", tmp_path / "rep",
                             *QUICK)
    assert status == 0
    assert any(w.startswith("units:") and "sign flip" in w for w in _warnings(err))


@pytest.mark.parametrize("variant", ["trailing_comma", "gzip", "latin1", "crlf_comment_at_top"])
def test_readable_variants_give_the_identical_data(sim, tmp_path, variant):
    from robust_drake.identification.data import read_csv

    lines = _lines(sim["fit"])
    path = tmp_path / f"{variant}.csv"
    if variant == "trailing_comma":
        _write_lines(path, [ln + "," for ln in lines])
    elif variant == "gzip":
        path.write_bytes(gzip.compress(open(sim["fit"], "rb").read()))
    elif variant == "latin1":  # an odd byte in the name of a column nobody uses
        text = "\n".join([lines[0] + ",comment\xe9"] + [ln + ",1" for ln in lines[1:]]) + "\n"
        path.write_bytes(text.encode("latin-1"))
    else:
        path.write_bytes(("# logged by the test rig\r\n" + "\r\n".join(lines) + "\r\n").encode())
    ref, got = read_csv(sim["fit"]), read_csv(str(path))
    for k in ("t", "q", "tau"):
        np.testing.assert_array_equal(getattr(got, k), getattr(ref, k))
    assert got.notes == []


def test_comment_lines_among_the_data_are_counted_with_line_numbers(sim, tmp_path):
    from robust_drake.identification.data import read_csv

    lines = _lines(sim["fit"])
    lines.insert(700, "# operator restarted the logger")
    raw = read_csv(_write_lines(tmp_path / "c.csv", lines))
    assert len(raw.t) == len(lines) - 2
    assert raw.notes == ["c.csv: 1 comment line(s) among the data skipped (file lines [701]); check that nothing "
                         "was pasted into the log"]
    assert raw.line(699) == 702  # data row 700 sits below the comment


def test_text_and_short_lines_are_named_by_file_line(sim, tmp_path, capsys):
    lines = _lines(sim["fit"])
    lines[40] = lines[40].rsplit(",", 2)[0]  # two values short
    msg = _error(capsys, "repair", _write_lines(tmp_path / "s.csv", lines), "--robot", ROBOT, "--out", tmp_path / "r")
    assert "file line 41 has 3 values, the header 5" in msg
    lines = _lines(sim["fit"])
    lines[50] = lines[50].replace(lines[50].split(",")[2], "0.3x")
    msg = _error(capsys, "repair", _write_lines(tmp_path / "x.csv", lines), "--robot", ROBOT, "--out", tmp_path / "r")
    assert "column 'q2' at file line 51 holds '0.3x', not a number" in msg


def test_numbering_gap_and_cutoff_name_the_cause(sim, tmp_path, capsys):
    gap = tmp_path / "q13.csv"
    pd.read_csv(sim["fit"]).rename(columns={"q2": "q3", "tau2": "tau3"}).to_csv(gap, index=False)
    msg = _error(capsys, "repair", gap, "--robot", ROBOT, "--out", tmp_path / "r")
    assert "position columns not numbered 1..n without gaps: ['q1', 'q3']" in msg
    msg = _error(capsys, "repair", sim["fit"], "--robot", ROBOT, "--cutoff", "0.01", "--out", tmp_path / "r")
    assert "the filter cut-off 0.01 Hz trims 2 / f_c = 200 s" in msg and "raise the cut-off" in msg


def test_mimic_joint_is_named(tmp_path):
    from robust_drake.models import make_plant, resolve_urdf

    text = open(resolve_urdf(ROBOT)).read().replace(
        '<joint name="joint2" type="continuous">',
        '<joint name="joint2" type="continuous"><mimic joint="joint1" multiplier="-1" offset="0"/>')
    urdf = tmp_path / "mimic.urdf"
    urdf.write_text(text)
    with pytest.raises(RobustDrakeError, match="joint 'joint2' mimics joint 'joint1'"):
        make_plant(str(urdf))


def test_library_messages_do_not_name_command_line_flags(tmp_path):
    """The API spelling in API messages (the command line maps them onto its flags)."""
    import robust_drake as rd

    (tmp_path / "rep").mkdir()
    (tmp_path / "rep" / "report.json").write_text("{}")
    with pytest.raises(RobustDrakeError) as exc:
        rd.repair("x.csv", ROBOT, out=tmp_path / "rep")
    assert "overwrite=True" in str(exc.value) and "--" not in str(exc.value)
    with pytest.raises(RobustDrakeError) as exc:
        rd.repair("x.csv", ROBOT, out="")
    assert str(exc.value).startswith("out is empty")


# ----------------------------------------------------------------------------- logging, signals
def test_progress_lines_appear_once_after_drake_has_logged(tmp_path, capsys):
    import logging

    from robust_drake.models import make_plant

    with pytest.raises(RobustDrakeError):  # Drake warns about the floating joint: a root handler appears
        make_plant(_c1_urdf(tmp_path, "floating"))
    root_had = list(logging.getLogger().handlers)
    try:
        logging.basicConfig()  # as pydrake does the first time Drake logs
        status, _, err = _run(capsys, "simulate", "--duration", "0.6", "--rate", "500", "-v")
        assert status == 0
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert not [ln for ln in lines if ln.startswith("INFO:robust_drake") or ln.startswith("DEBUG:robust_drake")]
        assert len(lines) == len(set(lines))
    finally:
        for h in list(logging.getLogger().handlers):
            if h not in root_had:
                logging.getLogger().removeHandler(h)


def test_sigterm_of_a_batch_cleans_up(tmp_path):
    spec = tmp_path / "spec.yaml"
    spec.write_text("duration: 1.0\ncontrollers: [pd, sp1, sp2]\nloads: [none, max]\nseeds: [0, 1, 2, 3]\n")
    out = tmp_path / "t.parquet"
    parts = out.with_name(out.name + ".parts")
    proc = subprocess.Popen([sys.executable, "-m", "robust_drake.cli", "batch", str(spec), "--out", str(out),
                             "--workers", "2", "--no-progress"], env=_env(), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(list(parts.glob("*.parquet"))) < 1:
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143, err
    assert "leaked semaphore" not in err and "Traceback" not in err
    assert "terminated" in err and len(pd.read_parquet(out)) >= 1 and not parts.exists()


def test_long_simulation_logs_its_progress_with_an_estimate(monkeypatch, caplog):
    """The chunked advance (PROGRESS_TICKS lowered to reach it in a short run) logs the share done
    and the time left, and gives the same run as one AdvanceTo."""
    import logging

    from robust_drake import diagram as D

    cfg = D.ClosedLoopConfig(controller="pd", trajectory="cpt", rate=500.0, duration=1.0)
    whole = D.simulate(cfg)
    monkeypatch.setattr(D, "PROGRESS_TICKS", 100)
    monkeypatch.setattr(D, "PROGRESS_AFTER_S", 0.0)
    with caplog.at_level(logging.INFO, logger="robust_drake"):
        chunked = D.simulate(cfg)
    msgs = [r.getMessage() for r in caplog.records if r.getMessage().startswith("simulating:")]
    assert len(msgs) == D.PROGRESS_CHUNKS - 1 and "s left" in msgs[0]
    np.testing.assert_allclose(chunked.q, whole.q, rtol=0, atol=1e-9)
