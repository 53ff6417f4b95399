"""Seeing a closed loop: its block diagram (Graphviz) and the arm moving (Meshcat).

Both are opt-in and cost nothing unless called: the diagram needs Graphviz's ``dot`` program
only to render SVG/PNG/PDF (``.dot`` writes the source, which needs nothing), and Meshcat is
pydrake's own viewer, served on localhost by :func:`pydrake.geometry.StartMeshcat` (no network
access needed; open the printed URL in a browser).
"""

from __future__ import annotations

import pathlib
import shutil

import numpy as np
import subprocess
from typing import Any

from robust_drake.errors import RobustDrakeError

RENDERED = (".svg", ".png", ".pdf")


def diagram_source(loop: Any, max_depth: int = 1, full: bool = False) -> str:
    """The Graphviz (dot) source of a closed loop's Drake diagram.

    By default the picture a control engineer draws: one box per block named as the papers name
    it (``SP1``, ``averaging velocity observer``, ``MultibodyPlant: d2r2``), only the ports that
    carry a signal, and neither the loggers nor the SceneGraph; ``full=True`` gives Drake's own
    drawing (``Diagram.GetGraphvizString``: every port, implementation class names).

    Parameters
    ----------
    loop : ClosedLoop
        A built loop (:func:`robust_drake.build_closed_loop`); its diagram is finished here if
        no run has done so yet.
    max_depth : int
        Nesting depth of sub-diagrams drawn by ``full=True`` (1: the loop's blocks, not their insides).
    full : bool
        Drake's complete drawing instead of the clean one.

    Returns
    -------
    str
        The ``digraph`` text.
    """
    loop._finish()
    if full:
        return loop.diagram.GetGraphvizString(max_depth=max_depth)
    return _clean_source(loop)


#: blocks left out of the clean picture (logging and geometry are not part of the control loop)
_HIDDEN = ("logged_signals", "logger", "scene_graph")


def _block_title(loop, system) -> tuple[str, str]:
    """(title, subtitle) of a block in the clean picture: the papers' names first."""
    from robust_drake.registry import CATALOG, block_label, paper_name

    c = loop.config
    name = system.get_name()
    cls = type(system).__name__
    if name == "controller":
        entry = CATALOG["controller"].get(c.controller) if isinstance(c.controller, str) else None
        return f"controller: {paper_name(block_label(c.controller))}", entry["paper"] if entry else cls
    if name == "observer":
        return f"velocity observer: {block_label(c.observer)}", "" if isinstance(c.observer, str) else cls
    if name == "reference":
        return f"reference: {paper_name(c.trajectory)}", f"{1.0 / loop.period:g} Hz samples"
    if name == "plant":
        return f"MultibodyPlant: {c.robot}", f"load {c.load}, continuous"
    if name == "encoder":
        res = c.encoder_resolution
        return "encoder", "exact" if res is None else f"quantum {float(res):.3g} rad"
    if name == "saturation":
        lim = np.atleast_1d(np.asarray(c.torque_limit, float))
        return "saturation", f"+-{lim[0]:g} N m" if np.all(lim == lim[0]) else "+-" + ", ".join(f"{x:g}" for x in lim) + " N m"
    if name == "plant_friction":
        return "plant friction", "Coulomb + viscous"
    if name == "force_sum":
        return "sum of joint torques", ""
    if name == "friction_compensation":
        return "friction compensation", "JS eqs. 89-90"
    return name, cls


def _clean_source(loop) -> str:
    import html

    diagram = loop.diagram
    systems = [s for s in diagram.GetSystems() if s.get_name() not in _HIDDEN]
    ids = {id(s): f"b{i}" for i, s in enumerate(systems)}
    edges, used_in, used_out = [], {}, {}
    for (dst, iin), (src, iout) in diagram.connection_map().items():
        if id(dst) not in ids or id(src) not in ids:
            continue
        edges.append((ids[id(src)], int(iout), ids[id(dst)], int(iin)))
        used_in.setdefault(id(dst), set()).add(int(iin))
        used_out.setdefault(id(src), set()).add(int(iout))
    lines = ["digraph closed_loop {", "rankdir=LR;", 'node [shape=plaintext, fontname="Helvetica", fontsize=11];',
             'edge [fontname="Helvetica", fontsize=9];']
    for s in systems:
        title, sub = _block_title(loop, s)
        ins = [s.get_input_port(i).get_name() for i in sorted(used_in.get(id(s), ()))]
        outs = [s.get_output_port(i).get_name() for i in sorted(used_out.get(id(s), ()))]
        idx_in, idx_out = sorted(used_in.get(id(s), ())), sorted(used_out.get(id(s), ()))
        rows = max(len(ins), len(outs), 1)
        body = [f'<TR><TD COLSPAN="2" BGCOLOR="#dde8f5"><B>{html.escape(title)}</B>'
                + (f'<BR/><FONT POINT-SIZE="9">{html.escape(sub)}</FONT>' if sub else "") + "</TD></TR>"]
        for r in range(rows):
            left = (f'<TD PORT="u{idx_in[r]}" ALIGN="LEFT">{html.escape(ins[r])}</TD>' if r < len(ins)
                    else '<TD BORDER="0"></TD>')
            right = (f'<TD PORT="y{idx_out[r]}" ALIGN="RIGHT">{html.escape(outs[r])}</TD>' if r < len(outs)
                     else '<TD BORDER="0"></TD>')
            body.append(f"<TR>{left}{right}</TR>")
        lines.append(f'{ids[id(s)]} [label=<<TABLE BORDER="0" CELLBORDER="1" CELLSPACING="0" CELLPADDING="4">'
                     + "".join(body) + "</TABLE>>];")
    for a, ia, b, ib in edges:
        lines.append(f"{a}:y{ia}:e -> {b}:u{ib}:w;")
    lines.append("}")
    return "\n".join(lines) + "\n"


def render_diagram(loop: Any, path: str | pathlib.Path, max_depth: int = 1, full: bool = False) -> pathlib.Path:
    """Write the loop's block diagram to ``path``: ``.dot`` (source) or ``.svg``/``.png``/``.pdf``.

    Parameters
    ----------
    loop : ClosedLoop
        A built loop.
    path : str or pathlib.Path
        Output file; its suffix picks the format. The folder is created.
    max_depth : int
        Nesting depth of sub-diagrams drawn (``full=True``).
    full : bool
        Drake's complete drawing (every port) instead of the clean one (:func:`diagram_source`).

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    RobustDrakeError
        Unknown suffix, or a rendered format without Graphviz's ``dot`` on the PATH (the message
        says how to install it or to write ``.dot`` instead).
    """
    path = pathlib.Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".dot", ".gv", *RENDERED):
        raise RobustDrakeError(f"diagram file {str(path)!r}: use a .svg, .png, .pdf or .dot name")
    dot = shutil.which("dot")
    if suffix in RENDERED and dot is None:
        raise RobustDrakeError(
            f"rendering {path.name} needs Graphviz's 'dot' program, which is not on the PATH; install "
            "Graphviz (e.g. 'apt install graphviz', 'brew install graphviz', 'conda install graphviz') "
            f"or write the source with a .dot name ({path.with_suffix('.dot')}) and render it elsewhere")
    source = diagram_source(loop, max_depth, full=full)
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix in (".dot", ".gv"):
        path.write_text(source)
        return path
    r = subprocess.run([dot, f"-T{suffix[1:]}", "-o", str(path)], input=source, text=True,
                       capture_output=True, timeout=120)
    if r.returncode != 0:
        raise RobustDrakeError(f"Graphviz could not render {path}: {r.stderr.strip()[:300]}")
    return path


def add_meshcat(loop: Any, meshcat: Any = None) -> tuple[Any, Any]:
    """Show the loop's arm in Meshcat (pydrake's browser viewer), recording the next run.

    Call after :func:`robust_drake.build_closed_loop` and before the loop's first ``simulate``;
    afterwards call :func:`publish_recording` to replay the run in the browser at any speed.

    Parameters
    ----------
    loop : ClosedLoop
        A built loop that has not run yet.
    meshcat : pydrake.geometry.Meshcat, optional
        An existing viewer (notebooks reuse one); None starts one on localhost.

    Returns
    -------
    tuple
        ``(meshcat, visualizer)``; ``meshcat.web_url()`` is the address to open.
    """
    from pydrake.geometry import MeshcatVisualizer, StartMeshcat

    if loop.diagram is not None:
        raise RobustDrakeError("add_meshcat must be called before the loop's first simulate()")
    if getattr(loop, "scene_graph", None) is None:
        raise RobustDrakeError("this loop has no SceneGraph to draw")
    meshcat = meshcat if meshcat is not None else StartMeshcat()
    vis = MeshcatVisualizer.AddToBuilder(loop.builder, loop.scene_graph, meshcat)
    vis.StartRecording(set_transforms_while_recording=False)
    return meshcat, vis


def publish_recording(visualizer: Any) -> None:
    """Stop recording and publish the animation of the run to the Meshcat page.

    Parameters
    ----------
    visualizer : pydrake.geometry.MeshcatVisualizer
        The second element returned by :func:`add_meshcat`.
    """
    visualizer.StopRecording()
    visualizer.PublishRecording()


def frame_arm(meshcat: Any, loop: Any, q: Any = None) -> None:
    """Point Meshcat's camera at the arm: the box around every body's origin over the joint
    angles ``q`` [rad] (rows; default: the plant's default posture), seen from above the
    front-right at about two and a half times its size."""
    import numpy as np

    plant = loop.plant
    ctx = plant.CreateDefaultContext()
    rows = np.atleast_2d(np.asarray(q if q is not None else plant.GetPositions(ctx), float))
    rows = rows[np.linspace(0, len(rows) - 1, min(len(rows), 25)).astype(int)]
    from pydrake.multibody.tree import BodyIndex

    points = []
    for row in rows:
        if row.size != plant.num_positions():
            continue
        plant.SetPositions(ctx, row)
        points += [plant.EvalBodyPoseInWorld(ctx, plant.get_body(BodyIndex(i))).translation()
                   for i in range(plant.num_bodies())]
    if not points:
        return
    P = np.array(points)
    centre = 0.5 * (P.min(axis=0) + P.max(axis=0))
    size = max(float(np.max(P.max(axis=0) - P.min(axis=0))), 0.3)
    direction = np.array([0.55, -1.0, 0.8]) / np.linalg.norm([0.55, -1.0, 0.8])
    meshcat.SetCameraPose(centre + 2.5 * size * direction, centre)


def save_replay(meshcat: Any, visualizer: Any, path: "str | pathlib.Path", loop: Any = None,
                result: Any = None) -> pathlib.Path:
    """Write the recorded run as one self-contained HTML file (Meshcat's ``StaticHtml``: the
    scene, the arm's meshes and the animation, no server needed; open it in any browser, play it
    from the "Open Controls" menu).

    Parameters
    ----------
    meshcat : pydrake.geometry.Meshcat
        The viewer of :func:`add_meshcat`.
    visualizer : pydrake.geometry.MeshcatVisualizer
        Its visualizer (recording since :func:`add_meshcat`).
    path : str or pathlib.Path
        The ``.html`` file to write (the folder is created).
    loop : ClosedLoop, optional
        The loop that ran; with ``result`` the camera is pointed at the arm's motion.
    result : SimulationResult, optional
        The run (its ``q`` frames the camera).

    Returns
    -------
    pathlib.Path
        The file written.
    """
    path = pathlib.Path(path)
    if path.suffix.lower() not in (".html", ".htm"):
        raise RobustDrakeError(f"meshcat replay {str(path)!r}: use a .html file name")
    publish_recording(visualizer)
    if loop is not None:
        frame_arm(meshcat, loop, None if result is None else result.q)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(meshcat.StaticHtml())
    return path


def animate_planar(result: Any, fps: float = 25.0, speed: float = 1.0, title: str | None = None) -> Any:
    """A stick-figure animation of a planar 2-link arm (no browser needed): the links at the
    measured angles, the desired posture dashed, the end effector's path so far, and the time.

    Parameters
    ----------
    result : SimulationResult
        A run of a planar 2-link arm (``result.link_lengths`` set).
    fps : float
        Frames per second of the animation.
    speed : float
        Simulated seconds per second of animation (1: real time).
    title : str, optional
        Title; None names the controller, robot and trajectory.

    Returns
    -------
    matplotlib.animation.FuncAnimation
        ``anim.save("arm.gif", writer="pillow")``, or in a notebook
        ``IPython.display.HTML(anim.to_jshtml())``.
    """
    import numpy as np
    from matplotlib.animation import FuncAnimation

    from robust_drake.kinematics import planar_forward_kinematics
    from robust_drake.plotting import style, subplots

    if not result.link_lengths:
        raise RobustDrakeError("animate_planar needs a planar 2-link arm (result.link_lengths); use the Meshcat "
                               "replay (simulate --meshcat FILE.html) for other arms")
    if not (fps > 0 and speed > 0):
        raise RobustDrakeError(f"fps and speed must be positive (got {fps}, {speed})")
    l1, l2 = result.link_lengths
    t = np.asarray(result.t)
    frames = np.searchsorted(t, np.arange(t[0], t[-1] + 1e-12, speed / fps)).clip(0, len(t) - 1)
    q, q_d = np.asarray(result.q), np.asarray(result.q_d)

    def joints(qr):
        elbow = np.stack([l1 * np.cos(qr[:, 0]), l1 * np.sin(qr[:, 0])], axis=1)
        return elbow, planar_forward_kinematics(qr, result.link_lengths)

    with style():
        return _stick_figure(result, t, frames, q, q_d, joints, fps, title, subplots)


def _stick_figure(result, t, frames, q, q_d, joints, fps, title, subplots):
    import numpy as np
    from matplotlib.animation import FuncAnimation

    l1, l2 = result.link_lengths
    elbow, tip = joints(q)
    elbow_d, tip_d = joints(q_d)
    fig, ax = subplots(figsize=(5.5, 5.5))
    reach = 1.05 * (l1 + l2)
    ax.set(xlim=(-reach, reach), ylim=(-reach, reach), xlabel="x [m]", ylabel="y [m]", aspect="equal")
    ax.grid(alpha=0.3)
    ax.plot(tip_d[:, 0], tip_d[:, 1], color="0.6", lw=0.8, ls=":", label="desired path")
    desired, = ax.plot([], [], "--", color="0.35", lw=1.5, label="desired posture")
    arm, = ax.plot([], [], "-o", color="C0", lw=3, ms=6, label="arm")
    trail, = ax.plot([], [], color="C3", lw=1.0, label="end effector")
    clock = ax.text(0.02, 0.97, "", transform=ax.transAxes, va="top")
    ax.legend(loc="lower left", fontsize=8)
    c = result.config or {}
    from robust_drake.registry import paper_name

    ax.set_title(title or f"{paper_name(c.get('controller', '?'))} on {c.get('robot', '?')}, "
                          f"{paper_name(c.get('trajectory', '?'))}")

    def draw(k):
        i = frames[k]
        arm.set_data([0, elbow[i, 0], tip[i, 0]], [0, elbow[i, 1], tip[i, 1]])
        desired.set_data([0, elbow_d[i, 0], tip_d[i, 0]], [0, elbow_d[i, 1], tip_d[i, 1]])
        trail.set_data(tip[: i + 1, 0], tip[: i + 1, 1])
        clock.set_text(f"t = {t[i]:.2f} s")
        return arm, desired, trail, clock

    return FuncAnimation(fig, draw, frames=len(frames), interval=1000.0 / fps, blit=False)


def save_animation(result: Any, path: "str | pathlib.Path", fps: float = 25.0, speed: float = 1.0) -> pathlib.Path:
    """Write :func:`animate_planar` to ``path``: ``.gif`` (Pillow) or ``.html`` (self-contained
    JavaScript player).

    Parameters
    ----------
    result : SimulationResult
        A run of a planar 2-link arm.
    path : str or pathlib.Path
        Output file (``.gif`` or ``.html``); the folder is created.
    fps : float
        Frames per second.
    speed : float
        Simulated seconds per second of animation.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    path = pathlib.Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".html"):
        raise RobustDrakeError(f"animation file {str(path)!r}: use a .gif or .html name")
    anim = animate_planar(result, fps=fps, speed=speed)
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".gif":
        anim.save(str(path), writer="pillow", fps=fps, dpi=70)
    else:
        path.write_text(anim.to_jshtml(fps=fps))
    return path
