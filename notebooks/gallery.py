# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Gallery: one figure of each command
#
# Every command that draws takes `--plot DIR` and writes its named PNG files into DIR. This
# notebook runs each command's short form with the `robust-drake` program (as a terminal would)
# and shows the files. With `ROBUST_DRAKE_SHORT=1` (the tests) every run
# is cut to a fraction of a second; unset it for the paper's horizons.

# %%
# %matplotlib inline
import os
import pathlib
import subprocess
import sys
import tempfile

from IPython.display import Image, Markdown, display

SHORT = os.environ.get("ROBUST_DRAKE_SHORT") == "1"
OUT = pathlib.Path(os.environ.get("ROBUST_DRAKE_NOTEBOOK_OUT") or tempfile.mkdtemp(prefix="gallery_"))
DUR = ["--duration", "0.3"] if SHORT else []


def show_plot_files(command, argv, files):
    """Run one command quietly with --plot DIR and display the named PNG files it wrote."""
    folder = OUT / command
    # `robust-drake ARGS` (the same program through this kernel's Python)
    run = subprocess.run([sys.executable, "-m", "robust_drake.cli", "-q", command, *argv, "--plot", str(folder)],
                         capture_output=True, text=True)
    status = run.returncode
    if status == 2:
        raise RuntimeError(f"robust-drake {command} refused its arguments: {run.stderr.strip()}")
    display(Markdown(f"### `robust-drake {command} {' '.join(argv)} --plot DIR` (exit {status})"))
    for f in files:
        display(Image(filename=str(folder / f), width=720))


# %%
# the circle's first second is skipped by the metrics (JS section 10), so it runs at least 1.3 s
show_plot_files("simulate", ["--controller", "sp2", "--trajectory", "circle", *(["--duration", "1.3"] if SHORT else [])],
     ["tracking.png", "task_path.png"])

# %%
show_plot_files("compare", ["--table", "5", "--controllers", "sp1,sp2", "--workers", "1", *DUR], ["table5.png"])

# %%
show_plot_files("sweep-rate", ["--controllers", "sp1,sp2", "--rates", "500,2500", "--workers", "1", *DUR], ["sweep_rate.png"])

# %%
show_plot_files("montecarlo", ["--controllers", "sp1,pd", "--draws", "3" if SHORT else "50", "--workers", "1",
                    "--out", str(OUT / "mc.parquet"), "--force", *DUR], ["montecarlo_maxerr_task.png"])

# %%
show_plot_files("calafiore", ["--n-true", "1", *DUR],
     ["fig5_nominal_errors.png", "fig6_robust_errors.png", "torques.png"])

# %%
show_plot_files("bascetta", DUR, ["fig3_w_base.png"])
