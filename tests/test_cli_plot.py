"""The command line's surface (issue 16): help everywhere, --version, -v/-q, and ``--plot DIR``
meaning the same in every command that plots (a folder, created, holding named PNG files)."""

import argparse
import json
import pathlib

import pytest

from robust_drake import __version__
from robust_drake.cli import build_parser, main


def _subparsers(parser):
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            return a
    raise AssertionError("no subcommands")


def test_every_subcommand_and_option_has_help():
    parser = build_parser()
    sub = _subparsers(parser)
    helps = {c.dest: c.help for c in sub._choices_actions}
    missing = []
    for name, p in sub.choices.items():
        if not (helps.get(name) or "").strip():
            missing.append(f"{name}: no help line")
        if not (p.description or "").strip():
            missing.append(f"{name}: no description")
        for a in p._actions:
            if a.help is argparse.SUPPRESS or isinstance(a, argparse._HelpAction):
                continue
            if not (a.help or "").strip():
                missing.append(f"{name} {'/'.join(a.option_strings) or a.dest}: no help")
    for a in parser._actions:
        if not isinstance(a, (argparse._SubParsersAction, argparse._HelpAction)) and not (a.help or "").strip():
            missing.append(f"global {a.option_strings}: no help")
    assert not missing, missing


def test_plot_option_is_a_folder_everywhere():
    sub = _subparsers(build_parser())
    plotting = {name: next(a for a in p._actions if "--plot" in a.option_strings)
                for name, p in sub.choices.items() if any("--plot" in a.option_strings for a in p._actions)}
    assert set(plotting) >= {"simulate", "demo", "bascetta", "montecarlo", "compare", "sweep-rate", "calafiore", "repair"}
    for name, action in plotting.items():
        assert action.metavar == "DIR" and action.nargs is None, name
        assert "folder" in action.help, name


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"robust-drake {__version__}"


@pytest.mark.parametrize("argv, level", [
    (["simulate", "--rate", "-1"], "INFO"),
    (["-q", "simulate", "--rate", "-1"], "WARNING"),
    (["simulate", "-q", "--rate", "-1"], "WARNING"),
    (["-v", "simulate", "--rate", "-1"], "DEBUG"),
    (["simulate", "--verbose", "--rate", "-1"], "DEBUG"),
])
def test_verbosity_flags_before_and_after_the_subcommand(argv, level):
    import logging

    assert main(argv) == 2  # a user error, after the level was set
    assert logging.getLevelName(logging.getLogger("robust_drake").level) == level


def test_plot_file_name_is_refused_with_the_new_meaning(tmp_path, capsys):
    assert main(["simulate", "--duration", "0.1", "--plot", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --plot takes a folder") and not (tmp_path / "x.png").exists()


def _repair_inputs(tmp_path):
    from robust_drake.experiments.repair_control import generate_experiment

    return generate_experiment(str(tmp_path / "data"), duration=3.0)


# Each plotting command's cheapest form, and the files it must write into --plot DIR.
CASES = {
    "simulate": (["simulate", "--duration", "0.2"], ["tracking.png", "task_path.png"]),
    "sweep-rate": (["sweep-rate", "--controllers", "sp1", "--rates", "500", "--duration", "0.2",
                    "--workers", "1"], ["sweep_rate.png"]),
    "compare": (["compare", "--table", "2", "--controllers", "sp1", "--duration", "0.2", "--workers", "1"],
                ["table2.png"]),
    "montecarlo": (["montecarlo", "--controllers", "sp1", "--draws", "1", "--duration", "0.2",
                    "--workers", "1", "--out", "{tmp}/mc.parquet"], ["montecarlo_maxerr_task.png"]),
    "calafiore": (["calafiore", "--n-true", "1", "--duration", "0.2"],
                  ["fig4_reference.png", "fig5_nominal_errors.png", "fig6_robust_errors.png", "torques.png"]),
    "demo": (["demo", "--skip-repair", "--duration", "0.2", "--workers", "1", "--out", "{tmp}/demo"],
             ["cpt_none.png", "cpt_max.png"]),
    "bascetta": (["bascetta", "--duration", "0.2"],
                 ["fig1_joint_trajectory.png", "fig2_cartesian_trajectory.png", "fig3_w_base.png",
                  "fig4_w_elbow.png"]),
    "repair": (["repair", "{fit}", "--validate", "{val}", "--robot", "d2r2", "--out", "{tmp}/rep",
                "--no-replay", "--no-consistent", "--no-instruments", "--no-nominal", "--max-effects", "1"],
               ["residual_fit.png", "residual_validate.png", "torque_validate.png"]),
}


@pytest.mark.parametrize("name", list(CASES))
def test_plot_dir_writes_the_named_files(name, tmp_path, capsys):
    argv, files = CASES[name]
    fill = {"tmp": str(tmp_path)}
    if name == "repair":
        fill["fit"], fill["val"] = _repair_inputs(tmp_path)
    plot_dir = tmp_path / "nested" / "plots"  # created by the command
    status = main([a.format(**fill) for a in argv] + ["--json", "--plot", str(plot_dir)])
    captured = capsys.readouterr()
    assert status == 0
    json.loads(captured.out)  # --json: stdout is one JSON document, progress went elsewhere
    if name == "repair":  # 13 s of silence before: its progress lines now reach stderr
        assert "data: fit" in captured.err and "baseline rms" in captured.err
    for f in files:
        p = plot_dir / f
        assert p.is_file() and p.stat().st_size > 5000, f"{name}: {f} missing or empty"
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", f


def test_diagram_source_and_a_clear_message_without_graphviz(tmp_path, capsys, monkeypatch):
    dot = tmp_path / "loop.dot"
    assert main(["simulate", "--duration", "0.05", "--diagram", str(dot)]) == 0
    text = dot.read_text()
    # the closed loop's blocks are in the picture
    assert text.startswith("digraph") and "plant" in text.lower() and "controller" in text.lower()
    import shutil

    monkeypatch.setattr(shutil, "which", lambda name: None)
    assert main(["simulate", "--duration", "0.05", "--diagram", str(tmp_path / "loop.svg")]) == 2
    err = capsys.readouterr().err
    assert "error: rendering loop.svg needs Graphviz's 'dot'" in err and not (tmp_path / "loop.svg").exists()


def test_meshcat_view_records_the_run():
    """Opt-in Meshcat (localhost, ~0.05 s to start): the recorded animation spans the run."""
    import robust_drake as rd
    from robust_drake.viz import add_meshcat, publish_recording

    loop = rd.build_closed_loop(rd.ClosedLoopConfig(duration=0.1))
    meshcat, vis = add_meshcat(loop)
    assert not meshcat.HasPath("/drake/visualizer/d2r2")
    res = loop.simulate()
    publish_recording(vis)
    assert meshcat.web_url().startswith("http://localhost") and not res.diverged
    assert meshcat.HasPath("/drake/visualizer/d2r2")  # the arm's geometry reached the viewer
    with pytest.raises(Exception, match="before the loop's first simulate"):
        add_meshcat(loop, meshcat)


def test_diagram_rendered_to_svg_where_graphviz_is_installed(tmp_path):
    import shutil

    if shutil.which("dot") is None:
        pytest.skip("Graphviz's 'dot' is not installed (the message is tested above)")
    svg = tmp_path / "loop.svg"
    assert main(["simulate", "--duration", "0.05", "--diagram", str(svg)]) == 0
    text = svg.read_text()
    assert "<svg" in text and "controller" in text and "plant" in text
