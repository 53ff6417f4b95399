"""Seeing a closed loop: its block diagram (Graphviz) and the arm moving (Meshcat).

Both are opt-in and cost nothing unless called: the diagram needs Graphviz's ``dot`` program
only to render SVG/PNG/PDF (``.dot`` writes the source, which needs nothing), and Meshcat is
pydrake's own viewer, served on localhost by :func:`pydrake.geometry.StartMeshcat` (no network
access needed; open the printed URL in a browser).
"""

from __future__ import annotations

import pathlib
import shutil
import subprocess
from typing import Any

from robust_drake.errors import RobustDrakeError

RENDERED = (".svg", ".png", ".pdf")


def diagram_source(loop: Any, max_depth: int = 1) -> str:
    """The Graphviz (dot) source of a closed loop's Drake diagram.

    Parameters
    ----------
    loop : ClosedLoop
        A built loop (:func:`robust_drake.build_closed_loop`); its diagram is finished here if
        no run has done so yet.
    max_depth : int
        Nesting depth of sub-diagrams drawn (1: the loop's blocks, not their insides).

    Returns
    -------
    str
        The ``digraph`` text of ``Diagram.GetGraphvizString``.
    """
    loop._finish()
    return loop.diagram.GetGraphvizString(max_depth=max_depth)


def render_diagram(loop: Any, path: str | pathlib.Path, max_depth: int = 1) -> pathlib.Path:
    """Write the loop's block diagram to ``path``: ``.dot`` (source) or ``.svg``/``.png``/``.pdf``.

    Parameters
    ----------
    loop : ClosedLoop
        A built loop.
    path : str or pathlib.Path
        Output file; its suffix picks the format. The folder is created.
    max_depth : int
        Nesting depth of sub-diagrams drawn.

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
    source = diagram_source(loop, max_depth)
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
