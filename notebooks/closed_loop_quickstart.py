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

from robust_drake.diagram import ClosedLoopConfig, build_closed_loop

SHORT = os.environ.get("ROBUST_DRAKE_SHORT") == "1"
duration = 0.3 if SHORT else None  # the CPT lasts 2 s

# %% [markdown]
# Build the diagram from a config; every piece is picked by name (see `robust_drake.registry`).

# %%
config = ClosedLoopConfig(robot="d2r2", load="max", controller="sp1", trajectory="cpt", rate=2500.0)
loop = build_closed_loop(config)
result = loop.simulate(duration)
print({k: f"{v:.4g}" for k, v in result.metrics.items()})
print(f"{result.sim_seconds:.2f} s simulated in {result.wall_seconds:.2f} s")

# %% [markdown]
# The diagram itself (a Graphviz string; paste into any viewer):

# %%
print(loop.diagram.GetGraphvizString(max_depth=1)[:400], "...")

# %% [markdown]
# Tracking errors and torques, as in the paper's figures 4-11.

# %%
fig, ax = plt.subplots(3, 1, figsize=(8, 6), sharex=True)
ax[0].plot(result.t, result.q[:, 0] - result.q_d[:, 0]); ax[0].set_ylabel("e1 [rad]")
ax[1].plot(result.t, result.q[:, 1] - result.q_d[:, 1]); ax[1].set_ylabel("e2 [rad]")
ax[2].plot(result.t, result.tau); ax[2].set_ylabel("tau [N m]"); ax[2].set_xlabel("t [s]")
plt.show()

# %% [markdown]
# Compare with the PD baseline with the same K, Lambda.

# %%
from robust_drake.diagram import simulate

pd_result = simulate(ClosedLoopConfig(load="max", controller="pd", trajectory="cpt"), duration)
print("task-space |error|: SP1", round(result.metrics["error_task"], 5), " PD", round(pd_result.metrics["error_task"], 5))
assert np.isfinite(result.metrics["error_task"])
