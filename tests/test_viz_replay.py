"""The saved 3-D replay and the diagram picture, checked by the programs a user opens them with.

``simulate --meshcat FILE.html`` writes Meshcat's self-contained page; the page is opened in a real
headless Chromium (the distribution's package, installed by ``.ci/run``): it must load without a
script error and draw the arm (the screenshot differs from the same page without the arm). The
block diagram's SVG is rendered by Graphviz's ``dot`` and parsed as XML.
"""

import base64
import re
import shutil
import subprocess
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from robust_drake.cli import main

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def _browser():
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("no Chromium on this machine (Debian: apt-get install chromium; .ci/run installs it)")


def _messages(html: str) -> list[bytes]:
    """The msgpack commands the page replays (base64 data URLs)."""
    return [base64.b64decode(b) for b in re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html)]


@pytest.fixture(scope="module")
def replay(tmp_path_factory):
    out = tmp_path_factory.mktemp("replay")
    path = out / "out.html"
    assert main(["-q", "simulate", "--duration", "0.4", "--meshcat", str(path), "--json"]) == 0
    return path


def test_meshcat_html_holds_the_recorded_animation(replay, capsys):
    html = replay.read_text()
    assert html.lstrip().startswith("<!DOCTYPE html>")
    anim = [m for m in _messages(html) if b"set_animation" in m]
    assert len(anim) == 1, "one animation command"
    # msgpack: every keyframe is a map with a "time" key (fixstr 0xa4 'time'); a 0.4 s run recorded
    # at Meshcat's default 64 frames per second gives about 26 frames per moving body
    frames = anim[0].count(b"\xa4time")
    assert frames >= 2 * 20, frames
    # the meshes of the arm are in the page too (no server needed)
    assert sum(b"set_object" in m for m in _messages(html)) >= 2


def _screenshot(browser, page, png, profile):
    r = subprocess.run(
        [browser, "--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run",
         f"--user-data-dir={profile}", "--enable-logging=stderr", "--v=0", "--window-size=640,480",
         "--virtual-time-budget=6000", f"--screenshot={png}", page.as_uri()],
        capture_output=True, text=True, timeout=120)
    assert png.is_file(), r.stderr[-2000:]
    return r.stderr


def test_replay_opens_in_a_headless_browser_and_draws_the_arm(replay, tmp_path):
    from PIL import Image
    from pydrake.geometry import Meshcat

    browser = _browser()
    # the same page without the arm: an empty scene, the camera where the replay put it
    html = replay.read_text()
    target = [m for m in _messages(html) if b"set_target" in m]
    empty = Meshcat()
    try:
        empty_html = empty.StaticHtml()
    finally:
        del empty
    if target:  # same camera command as the replay
        b64 = base64.b64encode(target[-1]).decode()
        empty_html = empty_html.replace("</body>", f'<script>fetch("data:application/octet-binary;base64,{b64}")'
                                        '.then(r => r.arrayBuffer()).then(b => viewer.handle_command_bytearray('
                                        'new Uint8Array(b)));</script></body>', 1)
    (tmp_path / "empty.html").write_text(empty_html)
    log_arm = _screenshot(browser, replay, tmp_path / "arm.png", tmp_path / "p1")
    _screenshot(browser, tmp_path / "empty.html", tmp_path / "empty.png", tmp_path / "p2")
    console = [line for line in log_arm.splitlines() if "CONSOLE" in line]
    errors = [line for line in console if re.search(r"Uncaught|SyntaxError|TypeError|ReferenceError", line)]
    assert not errors, errors
    a = np.asarray(Image.open(tmp_path / "arm.png").convert("RGB"), float)
    e = np.asarray(Image.open(tmp_path / "empty.png").convert("RGB"), float)
    assert a.shape == e.shape
    changed = np.abs(a - e).sum(axis=2) > 60  # pixels where the arm is drawn
    assert changed.mean() > 0.002, f"the arm covers only {changed.mean():.2%} of the screenshot"


def test_diagram_svg_renders_through_dot(tmp_path):
    if shutil.which("dot") is None:
        pytest.skip("Graphviz's dot is not installed (Debian: apt-get install graphviz; .ci/run installs it)")
    import robust_drake as rd

    loop = rd.build_closed_loop(rd.ClosedLoopConfig(controller="sp1"))
    path = rd.render_diagram(loop, tmp_path / "loop.svg")
    root = ET.parse(path).getroot()
    assert root.tag.endswith("svg")
    text = " ".join(t.text or "" for t in root.iter() if t.tag.endswith("text"))
    assert "SP1" in text and "plant" in text
    # the plant's unused ports are hidden: none of its ~30 per-body output ports is drawn
    assert "spatial_accelerations" not in text and "contact_results" not in text


def test_stick_figure_animation_of_a_planar_arm(tmp_path):
    """The animation's frames follow the run: the last frame's arm tip is the end effector's
    position at the last sample (forward kinematics of the logged angles)."""
    import robust_drake as rd
    from PIL import Image
    from robust_drake.kinematics import planar_forward_kinematics

    res = rd.simulate(trajectory="circle", controller="sp2", duration=0.4)
    anim = rd.animate_planar(res, fps=10)
    arm = next(line for line in anim._fig.axes[0].get_lines() if line.get_label() == "arm")
    anim._func(len(anim._save_seq) - 1 if anim._save_seq else 4)
    tip = planar_forward_kinematics(res.q[-1:], res.link_lengths)[0]
    assert np.allclose([arm.get_xdata()[-1], arm.get_ydata()[-1]], tip, atol=1e-9)
    gif = rd.save_animation(res, tmp_path / "arm.gif", fps=10)
    assert Image.open(gif).n_frames == 5  # 0.4 s at 10 frames per second, both ends
    with pytest.raises(rd.RobustDrakeError, match="planar 2-link"):
        rd.animate_planar(rd.simulate(robot="puma560_3link", controller="pd", trajectory="sine", duration=0.05))


def test_continuous_custom_controller_in_a_sampled_loop_warns():
    import robust_drake as rd
    from pydrake.systems.framework import LeafSystem

    class Continuous(LeafSystem):
        def __init__(self, ctx):
            super().__init__()
            for name, m in (("x_d", 3), ("q", 1), ("v", 1), ("v_error", 1)):
                self.DeclareVectorInputPort(name, m * ctx.n)
            self.DeclareVectorOutputPort("u", ctx.n, lambda c, o: o.SetFromVector(np.zeros(ctx.n)))

    with pytest.warns(UserWarning, match="declares no periodic update.*not sampled at 2500 Hz"):
        rd.build_closed_loop(rd.ClosedLoopConfig(controller=Continuous))
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rd.build_closed_loop(rd.ClosedLoopConfig(controller="sp1"))  # the registry's are sampled


def test_meshcat_options_are_checked(capsys):
    assert main(["simulate", "--duration", "0.05", "--meshcat-wait", "1"]) == 2
    assert "--meshcat-wait needs --meshcat" in capsys.readouterr().err
    assert main(["simulate", "--duration", "0.05", "--meshcat", "out.png"]) == 2
    assert "--meshcat takes a .html file name" in capsys.readouterr().err
