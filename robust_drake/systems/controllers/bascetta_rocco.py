"""Robust inverse dynamics of Bascetta & Rocco (BR): Case A (section II, eqs. 12-13) and
Case B (section IV, eqs. 17-20), as discrete controllers on the project's port convention.

Law (BR eqs. 2, 5):

    u = M_hat y + n_hat(q, qd),   y = qdd_d + K_D (qd_d - qd) + K_P (q_d - q) + w,
    w = rho(||e||) z / max(||z||, eps_z),   z = B^T P e,   rho = beta_0 + beta_1 ||e|| + beta_2 ||e||^2

with e = (q_d - q, qd_d - qd). Case A: P from ``A^T P + P A = -Q`` (Q = I), beta from eq. 13.
Case B: P = bdiag(Pi, ..., Pi), Pi = delta Bb P0 Bb (Lemma 4) with P0 from eq. 17, beta from
eq. 20. In e ordering, z_i = Pi[1, 0] q~_i + Pi[1, 1] q~dot_i.

Boundary layer: ``eps_z = boundary * ||B^T P||_2`` so the layer is ``boundary`` wide in error
units (rad, rad/s) for both cases (their P differ in scale); inside it w = rho z / eps_z is a
continuous high-gain feedback, which keeps the 2500 Hz loop from chattering. Default
``max(0.01, beta_0 T)`` (:func:`default_boundary`): 0.01 in the case study.

Model used by the controller (the case study, BR section V):
* M_hat = diag(M(q = 0)) of the *nominal* model (the plant itself) (``mass_model="diag_q0"``);
* n_hat(q, qd) = C qd + g of a *perturbed* model: the URDF with the masses (and, with them, the
  rotational inertias: SetMass keeps the unit inertia) of the bodies in ``perturbation`` scaled;
  default: every body named ``link<k>`` 20 % heavier (for the Siciliano arm ``{"link1": 1.2,
  "link2": 1.2}``, 60 kg instead of 50 kg).
  Evaluated with Drake (CalcBiasTerm - CalcGravityGeneralizedForces) on a cached context.

Any other URDF arm (n joints): the same law, with ``mass_model="model"`` by default, i.e.
M_hat(q) = the perturbed model's full mass matrix (BR eq. 2 allows M_hat(q); a constant diagonal
M_hat gives alpha >= 1 on serial7, so eq. 13 would have no solution). The bounds of eqs. 9-11
(alpha, B_M, Q_M, alpha_0..2) are sampled over the tube around the loop's own reference with
the Drake plant (:func:`robust_drake.analysis.bascetta_bounds.compute_bounds`); Case A's P solves
the 2n x 2n Lyapunov equation, Case B's is the per-joint Riccati block Pi repeated n times
(Lemma 4; BR section IV needs K_P = omega_n^2 I, K_D = 2 zeta omega_n I).

Extra outputs: ``w`` (n, the robust term, held) and ``rho`` (1, held), for logging.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.multibody.tree import BodyIndex

from robust_drake.errors import RobustDrakeError
from robust_drake.systems.controllers.base import DiscreteController, diag_gain

DEFAULT_PERTURBATION = {"link1": 1.2, "link2": 1.2}
#: BR section V's constant M_hat = diag(M(0)) is chosen by the robot's description
#: (``controller_design.br_mass_model: diag_q0``, the Siciliano case-study arm); other arms use M_hat(q).


def default_perturbation(robot: str, load: str = "none", factor: float = 1.2) -> dict:
    """Every body named ``link<k>`` with positive mass scaled by ``factor`` (the controller's model)."""
    from robust_drake.models import make_plant

    plant = make_plant(robot, load)
    out = {}
    for i in range(plant.num_bodies()):
        b = plant.get_body(BodyIndex(i))
        if b.name().startswith("link") and b.name()[4:].isdigit() and b.default_mass() > 0:
            out[b.name()] = factor
    return out or dict(DEFAULT_PERTURBATION)


# --------------------------------------------------------------------------- models
class ModelDynamics:
    """``M(q)`` and ``n(q, qd) = C(q, qd) qd + g(q)`` of a Drake plant, on one cached context.

    ``mass_scale`` maps body names to mass factors applied to the context (the perturbed model).
    """

    def __init__(self, robot: str, mass_scale: dict | None = None, load: str = "none", setup=None):
        from robust_drake.models import make_plant

        self.plant = make_plant(robot, load)
        self.context = self.plant.CreateDefaultContext()
        self.n = self.plant.num_velocities()
        self.mass_scale = dict(mass_scale or {})
        for body, k in self.mass_scale.items():
            try:
                b = self.plant.GetBodyByName(body)
            except RuntimeError as exc:
                raise RobustDrakeError(f"perturbation names unknown body {body!r} of {robot}: {exc}") from None
            if not k > 0:
                raise RobustDrakeError(f"mass factor for {body!r} must be positive (got {k})")
            b.SetMass(self.context, b.get_mass(self.context) * float(k))
        if setup is not None:  # e.g. an identified rigid body (IdentifiedModel / plant_draws.plant_setup)
            setup(self.plant, self.context)
        self._x = np.zeros(2 * self.n)

    def M(self, q):
        """M(q) of the model; NaN for a non-finite q (Drake aborts the process on one, so a blown-up
        loop would die here instead of being reported as diverged)."""
        if not np.all(np.isfinite(q)):
            return np.full((self.n, self.n), np.nan)
        self.plant.SetPositions(self.context, q)
        return self.plant.CalcMassMatrix(self.context)

    def n_term(self, q, v):
        x = self._x
        x[:self.n] = q
        x[self.n:] = v
        if not np.all(np.isfinite(x)):  # as in M: NaN torque, reported as a diverged run
            return np.full(self.n, np.nan)
        self.plant.SetPositionsAndVelocities(self.context, x)
        return self.plant.CalcBiasTerm(self.context) - self.plant.CalcGravityGeneralizedForces(self.context)

    __call__ = n_term


# --------------------------------------------------------------------------- pure law
def robust_term(e, BtP, beta, eps_z):
    """``(w, rho, z)`` of BR (w = rho z/||z|| with the boundary layer eps_z; eqs. 12, 19)."""
    en = math.sqrt(float(np.dot(e, e)))
    rho = beta[0] + beta[1] * en + beta[2] * en * en
    z = BtP @ e
    zn = math.sqrt(float(np.dot(z, z)))
    w = (rho / max(zn, eps_z)) * z
    return w, rho, z


def inverse_dynamics_law(q_d, qd_d, qdd_d, q, v, kp, kd, M_hat, n_hat_value, BtP, beta, eps_z):
    """BR eqs. 2 and 5 with the robust term: returns ``(u, w, rho)``."""
    e_q = q_d - q
    e_v = qd_d - v
    e = np.concatenate([e_q, e_v])
    w, rho, _ = robust_term(e, BtP, beta, eps_z)
    y = qdd_d + kd * e_v + kp * e_q + w
    return M_hat @ y + n_hat_value, w, rho


class BascettaRoccoController(DiscreteController):
    """Robust inverse dynamics (Case A or B, by the P and beta passed in); see the module docstring."""

    def __init__(self, n, period, K_P, K_D, M_hat, n_hat, BtP, beta, boundary=0.01, name=None,
                 design=None):
        super().__init__(n, period, name)
        self.kp = diag_gain(K_P, n, "K_P")
        self.kd = diag_gain(K_D, n, "K_D")
        # a constant matrix, or a function M_hat(q) (BR eq. 2), e.g. ModelDynamics.M
        self.M_hat_fn = M_hat if callable(M_hat) else None
        self.M_hat = None if callable(M_hat) else np.asarray(M_hat, float).reshape(n, n)
        self.n_hat = n_hat
        self.BtP = np.asarray(BtP, float).reshape(n, 2 * n)
        self.beta = [float(b) for b in beta]
        if len(self.beta) != 3 or min(self.beta) < 0:
            raise RobustDrakeError(f"beta must be three non-negative numbers (got {beta})")
        if not boundary > 0:
            raise RobustDrakeError("boundary layer width must be positive")
        self.boundary = float(boundary)
        self.eps_z = self.boundary * float(np.linalg.norm(self.BtP, 2))
        self.design = design or {}
        self._w_index = self.DeclareDiscreteState(n)
        self._rho_index = self.DeclareDiscreteState(1)
        self.DeclareStateOutputPort("w", self._w_index)
        self.DeclareStateOutputPort("rho", self._rho_index)

    def compute(self, t, q_d, qd_d, qdd_d, q, v, v_error):
        M_hat = self.M_hat_fn(q) if self.M_hat_fn is not None else self.M_hat
        return inverse_dynamics_law(q_d, qd_d, qdd_d, q, v, self.kp, self.kd, M_hat,
                                    self.n_hat(q, v), self.BtP, self.beta, self.eps_z)

    def _update(self, context, discrete_state):
        n = self.n
        x_d = self._x_d_port.Eval(context)
        u, w, rho = self.compute(context.get_time(), x_d[:n], x_d[n:2 * n], x_d[2 * n:],
                                 self._q_port.Eval(context), self._v_port.Eval(context), None)
        discrete_state.get_mutable_vector(self._u_index).get_mutable_value()[:] = self.with_feedforward(context, u)
        discrete_state.get_mutable_vector(self._w_index).get_mutable_value()[:] = w
        discrete_state.get_mutable_vector(self._rho_index).get_mutable_value()[0] = rho


# --------------------------------------------------------------------------- design
_DESIGN_CACHE: dict = {}
_BOUNDS_CACHE: dict = {}


def case_study_design(robot="siciliano_2link", trajectory="line", trajectory_params=None, K_P=25.0,
                      K_D=5.0, perturbation=None, region="trajectory", tube=0.1, n_time=None,
                      Q=None, delta=None, gamma=None, margin=1.1, load="none", mass_model=None):
    """Everything Cases A and B need (cached): M_hat, the bounds, beta (eqs. 13, 20), P (A and B).

    Bounds are taken over ``region`` ("trajectory": a +-``tube`` rad grid around q_d at ``n_time``
    instants; "workspace": all of [-pi, pi]^n) and the reference sampled every 1 ms.
    ``mass_model``: "diag_q0" (M_hat = diag(M(0)) of the nominal model, BR section V; default for
    the case-study arm) or "model" (M_hat(q) = the perturbed model's mass matrix; default for
    every other arm). ``n_time`` defaults to 120 instants for n <= 3 joints, 40 above.
    """
    from robust_drake.analysis.bascetta_bounds import (
        beta_case_a,
        beta_case_b,
        compute_bounds,
        sample_configurations,
    )
    from robust_drake.analysis.lyapunov import lyapunov_design
    from robust_drake.analysis.riccati import design_riccati
    from robust_drake.models import get_arm
    from robust_drake.trajectories import make_reference

    perturbation = default_perturbation(robot, load) if perturbation is None else dict(perturbation)
    trajectory_params = dict(trajectory_params or {})
    if mass_model is None:
        from robust_drake.description import describe

        mass_model = describe(robot).controller_design.br_mass_model or "model"
    if mass_model not in ("diag_q0", "model"):
        raise RobustDrakeError(f"mass_model must be 'diag_q0' or 'model' (got {mass_model!r})")
    key = repr((robot, load, trajectory, sorted(trajectory_params.items()), np.asarray(K_P).tolist(),
                np.asarray(K_D).tolist(), sorted(perturbation.items()), region, tube, n_time,
                None if Q is None else np.asarray(Q).tolist(), delta, gamma, margin, mass_model))
    if key in _DESIGN_CACHE:
        return _DESIGN_CACHE[key]
    bkey = repr((robot, load, trajectory, sorted(trajectory_params.items()), sorted(perturbation.items()),
                 region, tube, n_time, mass_model))
    if bkey not in _BOUNDS_CACHE:
        arm = get_arm(robot)
        ref = make_reference(arm, trajectory, **trajectory_params)
        nominal = ModelDynamics(robot, None, load)
        perturbed = ModelDynamics(robot, perturbation, load)
        n = nominal.n
        if mass_model == "diag_q0":
            M_hat = np.diag(np.diag(nominal.M(np.zeros(n))))
        else:
            M_hat = perturbed.M
        nt = n_time if n_time is not None else (120 if n <= 3 else 40)
        t = np.arange(0.0, ref.duration + 1e-12, 1e-3)
        q_d, qd_d, qdd_d = ref(t)
        idx = np.linspace(0, len(t) - 1, nt).round().astype(int)
        configs = sample_configurations(region, n, q_d=q_d[idx], tube=tube)
        _BOUNDS_CACHE[bkey] = (M_hat, compute_bounds(nominal.M, nominal.n_term, perturbed.n_term, M_hat, configs,
                                                     qd_d, qdd_d, region=region), n)
    M_hat, bounds, n = _BOUNDS_CACHE[bkey]
    kp = diag_gain(K_P, n, "K_P")
    kd = diag_gain(K_D, n, "K_D")
    lyap = lyapunov_design(np.diag(kp), np.diag(kd), Q)
    ric = design_riccati(np.diag(kp), np.diag(kd), alpha=bounds.alpha, delta=delta, gamma=gamma, margin=margin)
    out = {
        "M_hat": M_hat, "bounds": bounds, "lyapunov": lyap, "riccati": ric,
        "beta_A": beta_case_a(bounds, np.diag(kp), np.diag(kd)), "beta_B": beta_case_b(bounds),
        "perturbation": perturbation, "K_P": kp, "K_D": kd, "region": region, "tube": tube,
        "mass_model": mass_model,
    }
    _DESIGN_CACHE[key] = out
    return out


#: Smallest boundary layer [error units] (the case study's value).
DEFAULT_BOUNDARY = 0.01


def default_boundary(beta0: float, period: float) -> float:
    """Boundary layer width: inside it w = rho z / eps_z is a feedback of gain rho / boundary on
    the (normalised) error; capping that gain at 1/T keeps the sampled loop from chattering
    (measured: serial7 Case A at 1 kHz, rho ~ 41, boundary 0.01 -> gain 4100 1/s, error 9e-3 rad
    chattering vs 2e-4 for Case B). boundary = max(0.01, beta_0 T); the case study at 2500 Hz
    (beta_0 ~ 3.7) keeps 0.01."""
    return max(DEFAULT_BOUNDARY, float(beta0) * float(period))


def identified_design(ctx, model, K_P=25.0, K_D=5.0, region="trajectory", tube=0.1, n_time=None, Q=None,
                      delta=None, gamma=None, margin=1.1, alpha=0.01, truths=6):
    """What Cases A and B need when the controller's model is an identified one (``model=``): M_hat(q)
    and n_hat(q, qd) = C qd + g of the identified rigid body (``IdentifiedModel`` realised as URDF
    inertias), and the bounds of BR eqs. 9-11 as the worst over candidate true plants of its
    1 - ``alpha`` confidence set: the centre and ``truths`` plants drawn on the set's boundary
    (``uncertainty.plant_draws``, seed 0), each physically valid (sampled, not certified: a plant
    inside the set between them is not checked)."""
    import dataclasses as dc

    from robust_drake.analysis.bascetta_bounds import beta_case_a, beta_case_b, compute_bounds, sample_configurations
    from robust_drake.analysis.lyapunov import lyapunov_design
    from robust_drake.analysis.riccati import design_riccati
    from robust_drake.uncertainty.plant_draws import draw_plants
    from robust_drake.identification.model import as_identified_model, controller_set, realise_base_parameters
    from robust_drake.uncertainty.plant_draws import plant_setup
    from robust_drake.models import get_arm
    from robust_drake.regressor import InverseDynamicsRegressor
    from robust_drake.trajectories import make_reference

    m = as_identified_model(model)
    reg = InverseDynamicsRegressor.from_robot(ctx.robot, ctx.load)
    theta0, P, unc = controller_set(m, reg, alpha)
    centre = plant_setup(reg, realise_base_parameters(m, reg)[0])
    hat = ModelDynamics(ctx.robot, None, ctx.load, setup=centre)
    c = ctx.config
    ref = make_reference(get_arm(ctx.robot) if isinstance(ctx.robot, str) else ctx.arm, c.trajectory,
                         **dict(c.trajectory_params))
    t = np.arange(0.0, ref.duration + 1e-12, 1e-3)
    q_d, qd_d, qdd_d = ref(t)
    nt = n_time if n_time is not None else (120 if hat.n <= 3 else 40)
    configs = sample_configurations(region, hat.n, q_d=q_d[np.linspace(0, len(t) - 1, nt).round().astype(int)], tube=tube)
    draws, _ = draw_plants(reg, theta0, P, int(truths), np.random.default_rng(0), boundary_share=1.0)
    all_b = [compute_bounds(true.M, true.n_term, hat.n_term, hat.M, configs, qd_d, qdd_d, region=region)
             for true in [hat] + [ModelDynamics(ctx.robot, None, ctx.load, setup=d.setup) for d in draws]]
    G, L, cq = (max(getattr(b, k) for b in all_b) for k in ("G", "L", "c"))
    b0 = all_b[0]
    bounds = dc.replace(b0, alpha=max(b.alpha for b in all_b), B_m=min(b.B_m for b in all_b),
                        B_M=max(b.B_M for b in all_b), G=G, L=L, c=cq, alpha_0=G + L * b0.V_M + cq * b0.V_M ** 2,
                        alpha_1=L + 2 * cq * b0.V_M, alpha_2=cq, n_configs=b0.n_configs * len(all_b))
    kp, kd = diag_gain(K_P, hat.n, "K_P"), diag_gain(K_D, hat.n, "K_D")
    return {"M_hat": hat.M, "bounds": bounds, "lyapunov": lyapunov_design(np.diag(kp), np.diag(kd), Q),
            "riccati": design_riccati(np.diag(kp), np.diag(kd), alpha=bounds.alpha, delta=delta, gamma=gamma,
                                      margin=margin),
            "beta_A": beta_case_a(bounds, np.diag(kp), np.diag(kd)), "beta_B": beta_case_b(bounds),
            "perturbation": {}, "K_P": kp, "K_D": kd, "region": region, "tube": tube, "mass_model": "model",
            "identified": {"model": m, "setup": centre, "set": unc, "truths": 1 + len(draws)}}


def _make(ctx, case, K_P=25.0, K_D=5.0, perturbation=None, boundary=None, region="trajectory",
          tube=0.1, Q=None, delta=None, gamma=None, beta=None, mass_model=None, n_time=None, model=None,
          alpha=0.01):
    c = ctx.config
    if model is not None:
        if perturbation is not None or mass_model not in (None, "model"):
            raise RobustDrakeError(f"bascetta_{case.lower()}: with 'model' the controller's model is the identified "
                                   "one (no 'perturbation' or mass_model)")
        d = identified_design(ctx, model, K_P, K_D, region, tube, n_time, Q, delta, gamma, alpha=alpha)
    else:
        d = case_study_design(ctx.robot, c.trajectory, c.trajectory_params, K_P, K_D, perturbation, region, tube,
                              n_time=n_time, Q=Q, delta=delta, gamma=gamma, load=ctx.load, mass_model=mass_model)
    BtP = d["lyapunov"].BtP if case == "A" else d["riccati"].BtP
    beta = beta if beta is not None else (d["beta_A"] if case == "A" else d["beta_B"])
    if boundary is None:
        boundary = default_boundary(beta[0], ctx.period)
    ident = d.get("identified")
    n_hat = ModelDynamics(ctx.robot, d["perturbation"], ctx.load,  # own context per controller
                          setup=None if ident is None else ident["setup"])
    M_hat = n_hat.M if d["mass_model"] == "model" else d["M_hat"]
    ctrl = BascettaRoccoController(ctx.n, ctx.period, d["K_P"], d["K_D"], M_hat, n_hat, BtP, beta,
                                   boundary, name=f"bascetta_{case.lower()}", design=d)
    b = d["bounds"]
    ctrl.uncertainty = {
        "kind": "bascetta_bounds", "source": f"sampled over the {d['region']} region (tube {d['tube']} rad) "
        "with the Drake plant; controller model = URDF with masses scaled by 'perturbation'",
        "perturbation": d["perturbation"], "mass_model": d["mass_model"], "bounds": b.to_dict(),
        "beta": [float(x) for x in beta], "case": case, "boundary": float(boundary)}
    ctrl.rho = float(beta[0])  # rho(||e||) at e = 0; the full polynomial is in uncertainty["beta"]
    if ident is not None:  # the identified model: its set and its friction / effects compensated
        from robust_drake.identification.model import attach_compensation

        ctrl.uncertainty.update(source="sampled over the trajectory region against the identified model's "
                                f"{1 - alpha:g} set (its centre and {ident['truths'] - 1} boundary plants); "
                                "controller model = the identified rigid body", identified_set=ident["set"])
        attach_compensation(ctrl, ident["model"])
    return ctrl


def make_bascetta_a(ctx, **params):
    """Registry factory: Case A (classical Lyapunov design, BR eqs. 12-13)."""
    return _make(ctx, "A", **params)


def make_bascetta_b(ctx, **params):
    """Registry factory: Case B (Riccati design, BR eqs. 17-20). ``model`` (an identified model or a
    report / model path): M_hat, n_hat of its rigid body, bounds over its ``alpha`` set
    (:func:`identified_design`), its friction and effects compensated."""
    return _make(ctx, "B", **params)
