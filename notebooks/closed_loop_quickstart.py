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
import os

import matplotlib.pyplot as plt
import numpy as np

import robust_drake as rd

SHORT = os.environ.get("ROBUST_DRAKE_SHORT") == "1"
duration = 0.3 if SHORT else None  # the CPT lasts 2 s

# %% [markdown]
# Build the diagram from a config; every piece is picked by name (see `robust_drake.registry`).

# %%
config = rd.ClosedLoopConfig(robot="d2r2", load="max", controller="sp1", trajectory="cpt", rate=2500.0)
loop = rd.build_closed_loop(config)
# Opt-in: watch the arm in Meshcat (pydrake's viewer on localhost); set ROBUST_DRAKE_MESHCAT=1.
vis = None
if os.environ.get("ROBUST_DRAKE_MESHCAT") == "1":
    meshcat, vis = rd.add_meshcat(loop)
    print("open", meshcat.web_url())
result = loop.simulate(duration)
if vis is not None:
    from robust_drake.viz import publish_recording

    publish_recording(vis)  # replay the run from the Meshcat page
print({k: f"{v:.4g}" for k, v in result.metrics.items()})
print(f"{result.sim_seconds:.2f} s simulated in {result.wall_seconds:.2f} s")

# %% [markdown]
# The diagram itself: rendered to SVG where Graphviz's `dot` is installed, else its source.

# %%
import shutil  # noqa: E402

if shutil.which("dot"):
    from IPython.display import SVG, display

    display(SVG(filename=str(rd.render_diagram(loop, "/tmp/closed_loop.svg"))))
else:
    from robust_drake.viz import diagram_source

    print("(Graphviz not installed; the dot source:)\n", diagram_source(loop)[:400], "...")

# %% [markdown]
# Tracking errors and torques, as in the paper's figures 4-11.

# %%
fig, ax = plt.subplots(3, 1, figsize=(8, 6), sharex=True)
ax[0].plot(result.t, result.q[:, 0] - result.q_d[:, 0]); ax[0].set_ylabel("e1 [rad]")
ax[1].plot(result.t, result.q[:, 1] - result.q_d[:, 1]); ax[1].set_ylabel("e2 [rad]")
ax[2].plot(result.t, result.tau); ax[2].set_ylabel("tau [N m]"); ax[2].set_xlabel("t [s]")
plt.show()

# %% [markdown]
# The package's own figures are matplotlib `Figure` objects (shown inline, saved with
# `fig.savefig`): errors, torques with the saturation limit, and the end effector's path.

# %%
rd.tracking_figure(result)

# %%
rd.task_path_figure(result)

# %% [markdown]
# Compare with the PD baseline with the same K, Lambda.

# %%
pd_result = rd.simulate(rd.ClosedLoopConfig(load="max", controller="pd", trajectory="cpt"), duration)
print("task-space |error|: SP1", round(result.metrics["error_task"], 5), " PD", round(pd_result.metrics["error_task"], 5))
assert np.isfinite(result.metrics["error_task"])
