"""Progress off a terminal, debug messages with ``-v``, one copy of each message, and ``list``.

The long commands run with stderr piped (not a terminal, as in CI or ``2> log``) and must print a
progress line at least every ~10 % with the elapsed and remaining time; ``-v`` adds debug lines
(stage timings, solver calls, the simulator's run); ``robust-drake list --json`` names everything
the registry and the robot descriptions offer.
"""

import json
import logging
import os
import re
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LINE = re.compile(r"^(?P<what>[\w-]+): +(?P<pct>\d+)% \((?P<n>\d+)/(?P<total>\d+) \w+\), elapsed [\d:]+, remaining [\d:?]+")


def _cli(*args, timeout=600):
    """``robust-drake ARGS`` in a subprocess with stdout and stderr piped."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    r = subprocess.run([sys.executable, "-m", "robust_drake.cli", *map(str, args)], capture_output=True, text=True,
                       timeout=timeout, env=env, cwd=ROOT)
    assert "Traceback" not in r.stderr, r.stderr[-3000:]
    return r


def _progress(stderr, what):
    rows = [LINE.match(line) for line in stderr.splitlines()]
    rows = [m for m in rows if m and m["what"] == what]
    # the percentages grow and end at 100 %
    pcts = [int(m["pct"]) for m in rows]
    assert pcts == sorted(pcts) and pcts and pcts[-1] == 100, stderr
    return rows


@pytest.fixture(scope="module")
def sim_csvs(tmp_path_factory):
    from robust_drake.synthetic.simulated import simulate_experiment

    d = tmp_path_factory.mktemp("progress")
    fit, val = d / "fit.csv", d / "val.csv"
    simulate_experiment("dfki_double_pendulum_c1", duration=8.0, seed=0, out_csv=str(fit))
    simulate_experiment("dfki_double_pendulum_c1", duration=8.0, seed=1, out_csv=str(val))
    return fit, val


def test_piped_repair_prints_progress_lines_and_v_adds_stage_timings(sim_csvs, tmp_path):
    fit, val = sim_csvs
    r = _cli("-v", "repair", fit, "--validate", val, "--robot", "dfki_double_pendulum_c1", "--out",
             tmp_path / "rep", "--no-plots", "--no-replay", "--json")
    assert r.returncode == 0, r.stderr[-2000:]
    json.loads(r.stdout)  # stdout stays one JSON document
    assert len(_progress(r.stderr, "repair")) >= 5
    timings = re.findall(r"^repair stage (\w+): [\d.]+ s$", r.stderr, re.M)
    assert {"load_inputs", "fit_baseline", "select_effects", "never_worse"} <= set(timings), r.stderr
    assert re.search(r"^solve physically consistent fit .*: \w+ k?\w+, cost ", r.stderr, re.M), r.stderr


def test_piped_montecarlo_prints_progress_lines(tmp_path):
    r = _cli("montecarlo", "--controllers", "sp1,SP2", "--draws", "3", "--duration", "0.2", "--workers", "1",
             "--out", tmp_path / "mc.parquet", "--json")
    assert r.returncode == 0, r.stderr[-2000:]
    rows = _progress(r.stderr, "montecarlo")
    assert len(rows) >= 5 and int(rows[-1]["total"]) == 6  # 2 controllers x 3 draws, "SP2" accepted


def test_piped_logs_to_control_prints_progress_lines():
    r = _cli("logs-to-control", "--robot", "siciliano_2link", "--draws", "3", "--json")
    assert r.returncode in (0, 1), r.stderr[-2000:]
    assert len(_progress(r.stderr, "logs-to-control")) >= 5


def test_quiet_prints_no_progress_and_verbose_prints_debug(tmp_path):
    quiet = _cli("-q", "montecarlo", "--controllers", "sp1", "--draws", "2", "--duration", "0.1", "--workers", "1",
                 "--out", tmp_path / "q.parquet", "--json")
    assert quiet.returncode == 0 and not any(LINE.match(x) for x in quiet.stderr.splitlines()), quiet.stderr
    r = _cli("-v", "simulate", "--duration", "0.1", "--json")
    assert re.search(r"^simulated sp1 on d2r2: 0.1 s \(250 ticks at 2500 Hz", r.stderr, re.M), r.stderr


def test_a_message_is_printed_once_when_a_root_handler_is_active(capsys):
    """pydrake's configure_logging (and Meshcat's first message) put a console handler on the root
    logger; the package's own handler then stays silent instead of printing every line twice."""
    import io

    from robust_drake.log import logger, set_log_level

    root = logging.getLogger()
    stream = io.StringIO()
    saved = list(root.handlers)
    handler = logging.StreamHandler(sys.stderr)
    root.addHandler(handler)
    try:
        set_log_level("INFO")
        logger.info("simulating sp1 on d2r2 ...")
        err = capsys.readouterr().err
    finally:
        root.removeHandler(handler)
        root.handlers[:] = saved
        set_log_level("WARNING")
    assert err.count("simulating sp1 on d2r2 ...") == 1, err
    del stream


def test_log_progress_every_tenth():
    """LogProgress writes one line per 10 % of the total (and the last), whatever the step count."""
    from robust_drake.log import LogProgress

    lines = []
    handler = logging.Handler()
    handler.emit = lambda rec: lines.append(rec.getMessage())
    from robust_drake.log import logger

    logger.addHandler(handler)
    old = logger.level
    logger.setLevel(logging.INFO)
    try:
        bar = LogProgress(800, "montecarlo", unit="runs")
        for _ in range(800):
            bar.update(1)
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old)
    assert len(lines) == 10 and lines[0].startswith("montecarlo:  10% (80/800 runs), elapsed ")
    assert lines[-1].startswith("montecarlo: 100% (800/800 runs)")


def test_list_json_names_every_robot_controller_and_trajectory():
    from robust_drake import registry
    from robust_drake.models import ROBOTS

    r = _cli("list", "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert {x["name"] for x in doc["robots"]} == set(ROBOTS)
    assert {x["name"] for x in doc["controllers"]} == set(registry.CONTROLLERS)
    assert {x["name"] for x in doc["trajectories"]} == set(registry.TRAJECTORIES)
    assert {x["name"] for x in doc["observers"]} == set(registry.OBSERVERS)
    cpt = next(x for x in doc["trajectories"] if x["name"] == "cpt")
    assert {"name": "amplitude_deg", "unit": "deg"}.items() <= cpt["parameters"][0].items()
    assert next(x for x in doc["controllers"] if x["name"] == "lgplus")["paper_name"] == "LG+"


def test_documented_parameters_are_accepted_by_the_factories():
    """Every trajectory/observer parameter listed is a keyword of its factory (the list is the
    signature), and a wrong one is refused naming the accepted ones."""
    import inspect

    import robust_drake as rd
    from robust_drake import registry

    for kind in ("trajectory", "observer", "plant_effect"):
        for name in registry.names(kind):
            sig = inspect.signature(registry.resolve(kind, name)).parameters
            assert set(registry.accepted_params(kind, name)) <= set(sig), (kind, name)
    with pytest.raises(rd.RobustDrakeError, match=r"trajectory 'cpt' has no parameter 'amp' \(did you mean "
                                                 r"'amplitude_deg'\?\); accepted: amplitude_deg \[deg\]"):
        rd.simulate(trajectory="cpt", trajectory_params={"amp": 1.0})
    with pytest.raises(rd.RobustDrakeError, match=r"no parameter 'eps' \(did you mean 'epsilon'"):
        rd.simulate(controller="zc", controller_params={"eps": 3.0}, duration=0.01)
    with pytest.raises(rd.RobustDrakeError, match=r"unknown controller 'sp3' \(did you mean 'sp2' or 'sp1'\?\)"):
        rd.simulate(controller="sp3")


def test_paper_names_and_any_case_are_accepted():
    import robust_drake as rd

    for given, name in (("SP1", "sp1"), ("LG+", "lgplus"), ("Zc", "zc")):
        assert rd.ClosedLoopConfig(controller=given).controller == name
    assert rd.ClosedLoopConfig(robot="D2R2", trajectory="CPT").robot == "d2r2"
    assert {c["name"] for c in rd.list_controllers()} >= {"sp1", "sp2", "zc", "lgplus"}
    assert any(r["name"] == "panda" and r["joints"] == 7 for r in rd.list_robots())


def test_every_subcommand_has_examples_that_parse():
    import shlex

    from robust_drake.cli import EXAMPLES, RUNTIMES, build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    assert set(sub.choices) <= set(EXAMPLES)
    for name, p in sub.choices.items():
        assert "examples:\n  robust-drake " + name in p.format_help(), name
        for line in EXAMPLES[name]:
            argv = shlex.split(line.format(**RUNTIMES).split("#")[0].split("|")[0].split(">")[0])
            assert argv[0] == "robust-drake" and argv[1] == name
            parser.parse_args(argv[1:])  # SystemExit on an option that does not exist


def test_messages_name_the_option_as_the_caller_spells_it(tmp_path, capsys):
    """An earlier report is refused with --force on the command line, overwrite=True from Python."""
    import robust_drake as rd
    from robust_drake.cli import main

    (tmp_path / "report.json").write_text("{}")
    with pytest.raises(rd.RobustDrakeError) as py:
        rd.repair(str(tmp_path / "none.csv"), robot="d2r2", out=tmp_path)
    assert "overwrite=True" in str(py.value) and "--force" not in str(py.value)
    assert main(["repair", str(tmp_path / "none.csv"), "--robot", "d2r2", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "--force" in err and "overwrite=True" not in err
