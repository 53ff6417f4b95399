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
# # Your own controller in the loop
#
# `ClosedLoopConfig(controller=...)` takes a registry name (`"pd"`, `"sp1"`, ...), a pydrake
# `LeafSystem` instance, or a factory `f(ctx) -> LeafSystem`; the same holds for `observer=`.
# The builder checks the ports (controller: inputs `x_d` (3n), `q`, `v`, `v_error` (n) ->
# output `u` (n); observer: inputs `q`, `x_d` -> outputs `v`, `v_error`) and names any
# missing one. Subclassing `DiscreteController` gives the ports, the sample-and-hold and the
# feedforward hook; only `compute` is left to write.
#
# Below: a computed-torque law (PD with Spong's gains K, Lambda plus Drake's inverse
# dynamics) on the Siciliano vertical 2-link arm, against the PD baseline with the same gains.

# %%
# %matplotlib inline
import os

import matplotlib.pyplot as plt
import numpy as np

import robust_drake as rd

SHORT = os.environ.get("ROBUST_DRAKE_SHORT") == "1"
duration = 0.6 if SHORT else 2.0  # the sine reference lasts as long as we run it

# %% [markdown]
# The controller: 13 lines.

# %%
from pydrake.multibody.tree import MultibodyForces


class ComputedTorque(rd.DiscreteController):
    def __init__(self, ctx):
        super().__init__(ctx.n, ctx.period, name="ComputedTorque")
        self.K, self.Lam = map(np.asarray, rd.default_gains(ctx))   # same gains as the "pd" baseline
        self.plant = rd.make_plant(ctx.robot, ctx.load)
        self.pctx, self.f0 = self.plant.CreateDefaultContext(), MultibodyForces(self.plant)

    def compute(self, t, q_d, qd_d, qdd_d, q, v, v_error):
        self.plant.SetPositions(self.pctx, q); self.plant.SetVelocities(self.pctx, v)
        tau = self.plant.CalcInverseDynamics(self.pctx, qdd_d - self.Lam * v_error, self.f0)
        tau -= self.plant.CalcGravityGeneralizedForces(self.pctx)  # + g(q)
        return tau - self.K * (v_error + self.Lam * (q - q_d))      # - K r


# %% [markdown]
# Pass the class itself as the factory (it is called with the loop's `BuildContext`).

# %%
common = dict(robot="siciliano_2link", trajectory="sine", rate=1000.0, observer="exact", duration=duration)
ct = rd.simulate(controller=ComputedTorque, **common)
pd = rd.simulate(controller="pd", **common)
for name, r in (("computed torque", ct), ("PD", pd)):
    late = r.t >= 0.5
    print(f"{name:16s} max |q - q_d| after 0.5 s: {np.abs(r.q[late] - r.q_d[late]).max():.3e} rad"
          f"   (config records controller = {r.config['controller']!r})")

# %%
fig, ax = plt.subplots(2, 1, figsize=(8, 5), sharex=True)
for r, style, name in ((pd, "--", "PD"), (ct, "-", "computed torque")):
    ax[0].plot(r.t, r.q[:, 0] - r.q_d[:, 0], style, label=name)
    ax[1].plot(r.t, r.q[:, 1] - r.q_d[:, 1], style, label=name)
ax[0].set_ylabel("e1 [rad]"); ax[1].set_ylabel("e2 [rad]"); ax[1].set_xlabel("t [s]")
ax[0].legend(); ax[0].set_title("Siciliano 2-link, sine reference, 1 kHz, same K and Lambda")
plt.show()

# %% [markdown]
# A system with a wrong port is refused with a one-line message naming it:

# %%
from pydrake.systems.framework import LeafSystem


class NoVelocityError(LeafSystem):  # forgot the v_error input
    def __init__(self, ctx):
        super().__init__()
        for name, size in (("x_d", 3 * ctx.n), ("q", ctx.n), ("v", ctx.n)):
            self.DeclareVectorInputPort(name, size)
        self.DeclareVectorOutputPort("u", ctx.n, lambda c, o: o.SetFromVector(np.zeros(ctx.n)))


try:
    rd.simulate(controller=NoVelocityError, **common)
except rd.RobustDrakeError as exc:
    print("error:", exc)
