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
# # A closed loop in a few lines: SP1 on the D2R2
#
# Jaritz & Spong's D2R2 (horizontal two-link direct-drive arm) tracking the cubic
# polynomial trajectory (eq. 48) with Spong's SP1 controller (eqs. 9-12, 18) at 2500 Hz,
# quantised encoders (655360 counts/rev), the averaging velocity filter (eqs. 64, 66),
# Coulomb + viscous friction on the plant and torque saturation at 31.2 N m.

# %%
# %matplotlib inline
import os
import tempfile

import matplotlib.pyplot as plt
import numpy as np

import robust_drake as rd

SHORT = os.environ.get("ROBUST_DRAKE_SHORT") == "1"
OUT = os.environ.get("ROBUST_DRAKE_NOTEBOOK_OUT") or tempfile.mkdtemp(prefix="quickstart_")
duration = 0.3 if SHORT else None  # the CPT lasts 2 s

# %% [markdown]
# What can be picked by name: robots, controllers (with their parameters and units),
# trajectories. Names are accepted in any case and by the papers' names ("SP1", "LG+").

# %%
print([r["name"] for r in rd.list_robots()])
for c in rd.list_controllers()[:4]:
    print(f"{c['name']:12s} {c['paper_name']:10s} {c['summary']}: {[p['name'] for p in c['parameters']]}")

# %% [markdown]
# Build the diagram from a config; every piece is picked by name.

# %%
config = rd.ClosedLoopConfig(robot="d2r2", load="max", controller="SP1", trajectory="cpt", rate=2500.0)
loop = rd.build_closed_loop(config)
# Meshcat (pydrake's 3-D viewer) records the run; the replay is saved as one HTML file below.
meshcat, vis = rd.add_meshcat(loop)
result = loop.simulate(duration)
result  # one line: the run and its criteria (result.to_pandas() has every logged signal, with units)

# %%
replay = rd.save_replay(meshcat, vis, os.path.join(OUT, "closed_loop_replay.html"), loop=loop, result=result)
print("3-D replay (open in any browser):", replay)
print({k: f"{v:.4g}" for k, v in result.metrics.items()})
df = result.to_pandas()
print(df.shape, {c: df.attrs["units"][c] for c in ("q1", "v_hat1", "tau1", "e_task")})

# %% [markdown]
# The diagram itself: rendered to SVG where Graphviz's `dot` is installed, else its source.

# %%
import shutil  # noqa: E402

if shutil.which("dot"):
    from IPython.display import SVG, display

    display(SVG(filename=str(rd.render_diagram(loop, os.path.join(OUT, "closed_loop.svg")))))
else:
    print("(Graphviz not installed; the dot source:)\n", rd.render_diagram(loop, os.path.join(OUT, "loop.dot")).read_text()[:400], "...")

# %% [markdown]
# Any logged signal is a column of `to_pandas()`: here the observer's velocity estimate against
# the true velocity of joint 2 (the encoder's quantisation shows in the estimate).

# %%
ax = df[["v2", "v_hat2"]].plot(figsize=(8, 3), lw=0.8)
ax.set(xlabel="t [s]", ylabel="[rad/s]")
plt.show()

# %% [markdown]
# The package's own figures are matplotlib `Figure` objects (shown inline, saved with
# `fig.savefig`): errors, torques with the saturation limit, and the end effector's path.

# %%
rd.tracking_figure(result)

# %%
rd.task_path_figure(result)

# %% [markdown]
# Without a 3-D viewer: a stick-figure animation of the planar arm (matplotlib, a JavaScript
# player in the notebook; `rd.save_animation(result, "arm.gif")` writes a GIF).

# %%
from IPython.display import HTML  # noqa: E402

HTML(rd.animate_planar(result, fps=10).to_jshtml())

# %% [markdown]
# Compare with the PD baseline with the same K, Lambda.

# %%
pd_result = rd.simulate(rd.ClosedLoopConfig(load="max", controller="pd", trajectory="cpt"), duration)
print("task-space |error|: SP1", round(result.metrics["error_task"], 5), " PD", round(pd_result.metrics["error_task"], 5))
assert np.isfinite(result.metrics["error_task"])
