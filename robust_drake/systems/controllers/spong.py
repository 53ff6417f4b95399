"""Spong's robust passivity-based controllers SP1 and SP2, and the PD baseline.

Jaritz & Spong (JS) section 3.1, after Spong (1992):

- error terms (eq. 11): q~ = q - q_d, r = q~' + Lambda q~, v = qd_d - Lambda q~, a = v';
- nominal law (eqs. 9-10): tau_0 = Y(q, q', v, a) theta_0 - K r;
- robust law (eq. 12): tau = Y (theta_0 + u) - K r with
  SP1 (eq. 18): u = -rho Y^T r / ||Y^T r|| outside the boundary layer ||Y^T r|| > epsilon,
  -(rho / epsilon) Y^T r inside; SP2 (eq. SP2): the same per component, rho_i, epsilon_i.

The PD baseline is the same law without model terms, tau = -K r = -K q~' - K Lambda q~,
with the same K and Lambda (what SP1/SP2 must beat).

D2R2 numbers (appendix 12.1): theta_0 = table 11, rho = 0.1062 (SP1; the Euclidean norm of
theta_0 - theta_unloaded; eq. 17 prints the sum without squares), rho_i = table 10 (SP2),
K = diag(30, 10), Lambda = diag(50, 20) (section 8), epsilon from table 1 (SP1: 1, SP2: 0.5).

Any other URDF arm (serial7, siciliano_2link, ...): Y is the Drake-derived Slotine-Li regressor
(:meth:`robust_drake.regressor.InverseDynamicsRegressor.slotine_li`, gravity included), theta_0 the
URDF's base parameters, the uncertainty set a box |theta_i - theta0_i| <= rel_bound |theta0_i| +
abs_bound (:func:`box_uncertainty`; SP1's rho = ||b||_2, SP2's rho_i = b_i), gains from
:func:`default_gains` and boundary layers from :func:`default_epsilon` (the smallest layer the sampled
loop tolerates, :func:`sampled_epsilon`, with the predicted ultimate bound per joint,
:func:`spong_ultimate_bound`, in ``uncertainty['epsilon_rule']``).  Which robots have a
closed form is said by its description (``closed_form_regressor``, a key of
:data:`CLOSED_FORM_SLOTINE_LI`).
The controller systems are thin wrappers: ``compute`` is :func:`spong_law`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Multiplexer

from robust_drake.description import packaged_description
from robust_drake.errors import RobustDrakeError
from robust_drake.systems.controllers.base import DiscreteController, diag_gain

# JS appendix 12.1 / table 10 / section 8, from the D2R2's description (robots/d2r2.yaml)
_D2R2_DESIGN = packaged_description("d2r2").controller_design
D2R2_RHO_SP1 = _D2R2_DESIGN.rho_sp1
D2R2_RHO_SP2 = _D2R2_DESIGN.rho_sp2
D2R2_K = _D2R2_DESIGN.K
D2R2_LAMBDA = _D2R2_DESIGN.Lambda
# JS table 1
EPSILON_SP1 = 1.0
EPSILON_SP2 = 0.5


# --------------------------------------------------------------------------- pure math
def spong_error_terms(q_d, qd_d, qdd_d, q, v_error, Lambda):
    """JS eq. 11: returns (q_tilde, r, v, a) with a = qdd_d - Lambda q~'.

    ``v_error`` is the (estimated) velocity error q~' = q' - qd_d.
    """
    q_tilde = np.asarray(q) - np.asarray(q_d)
    qt_dot = np.asarray(v_error)
    r = qt_dot + Lambda * q_tilde
    v = np.asarray(qd_d) - Lambda * q_tilde
    a = np.asarray(qdd_d) - Lambda * qt_dot
    return q_tilde, r, v, a


def sp1_robust_input(xi, rho: float, epsilon: float):
    """JS eq. 18: u = -rho xi/||xi|| if ||xi|| > epsilon else -(rho/epsilon) xi, xi = Y^T r.

    ``xi`` a numpy array gives an array (n-joint path); a list or tuple gives a list computed in
    scalar Python math (the 2500 Hz D2R2 path on 3-vectors).
    """
    if isinstance(xi, np.ndarray):
        norm = math.sqrt(float(xi @ xi))
        g = rho / norm if norm > epsilon else rho / epsilon
        return -g * xi
    ss = 0.0
    for x in xi:  # a plain loop: same sum, in the same order, as sum(x * x for x in xi)
        ss += x * x
    norm = math.sqrt(ss)
    g = rho / norm if norm > epsilon else rho / epsilon
    return [-g * x for x in xi]


def sp2_robust_input(xi, rho, epsilon):
    """JS eq. (SP2): componentwise u_i = -rho_i sgn(xi_i) outside |xi_i| <= epsilon_i, linear inside.

    Array in, array out; list in, list out (as :func:`sp1_robust_input`)."""
    if isinstance(xi, np.ndarray):
        rho, epsilon = np.asarray(rho, dtype=float), np.asarray(epsilon, dtype=float)
        return np.where(np.abs(xi) > epsilon, -rho * np.sign(xi), -(rho / epsilon) * xi)
    out = []
    for x, r, e in zip(xi, rho, epsilon):
        out.append(-r * math.copysign(1.0, x) if abs(x) > e else -(r / e) * x)
    return out


def spong_torque(Y, theta0, u, K, r) -> np.ndarray:
    """JS eq. 12: tau = Y (theta_0 + u) - K r (u = 0 gives the nominal law, eq. 10)."""
    return Y @ (np.asarray(theta0) + u) - K * r


def spong_law(regressor, robust_input, theta0, K, Lambda, q_d, qd_d, qdd_d, q, v_hat, v_error) -> np.ndarray:
    """One sample of SP1/SP2 (JS eqs. 11, 12 with u from eq. 18 or SP2), composed of
    :func:`spong_error_terms`, the regressor Y(q, q', v, a), xi = Y^T r, ``robust_input(xi)`` and
    :func:`spong_torque`.  ``v_hat`` is the velocity estimate used as q' in Y; returns tau [N m]."""
    _, r, v, a = spong_error_terms(q_d, qd_d, qdd_d, q, v_error, Lambda)
    Y = np.asarray(regressor(q, v_hat, v, a), dtype=float)
    u = np.asarray(robust_input(Y.T @ r), dtype=float)
    return spong_torque(Y, theta0, u, K, r)


def scalar_law_source(n: int, p: int, Lam, K, theta0, robust: str, packed: bool = False,
                      regressor_source=None) -> str:
    """Python source of one SP1/SP2 sample for n joints and p parameters, straight-line (no loop,
    list or generator per sample): JS eq. 11 (q~, r, v, a), Y = regressor(q, q', v, a) (n x p nested
    lists), xi = Y^T r, the robust input u (``robust`` "sp1": eq. 18 with ``self.rho``,
    ``self.epsilon``; "sp2": componentwise; "call": ``self.robust_input(xi)``), eq. 12 tau = Y (theta_0
    + u) - K r.  Lambda, K, theta_0 are written as literals (repr round-trips floats); every sum
    starts from 0.0 and adds in index order, as :func:`spong_law`'s loops.  The function is
    ``f(self, q_d, qd_d, qdd_d, q, v, v_error) -> list of n torques``, or with ``packed``
    ``f(self, x)`` on the one list x = [q_d, qd_d, qdd_d, q, v, v_error] (6n) that the fused input
    port delivers (same operations in the same order, so the same floats).  ``regressor_source``
    (the regressor's ``scalar_source``, e.g. :func:`d2r2_regressor_source`) writes Y inline instead of
    the call: ``regressor_source(q, qd, v, a)`` -> (source lines, n x p entry expressions), the same
    operations as the regressor (no call, no nested lists per sample)."""
    if packed:
        L = ["def _law(self, x):"]
        q_d, qd_d, qdd_d, q, vh, ve = (lambda j, o=o: f"x[{o * n + j}]" for o in (0, 1, 2, 3, 4, 5))
        if regressor_source is None:
            L += [f"    q = x[{3 * n}:{4 * n}]", f"    v = x[{4 * n}:{5 * n}]"]
    else:
        L = ["def _law(self, q_d, qd_d, qdd_d, q, v, ve):"]
        q_d, qd_d, qdd_d, q, vh, ve = (lambda j, s=s: f"{s}[{j}]" for s in ("q_d", "qd_d", "qdd_d", "q", "v", "ve"))
    for j in range(n):
        lam = repr(float(Lam[j]))
        L += [f"    qt{j} = {q(j)} - {q_d(j)}", f"    r{j} = {ve(j)} + {lam} * qt{j}",
              f"    vr{j} = {qd_d(j)} - {lam} * qt{j}", f"    a{j} = {qdd_d(j)} - {lam} * {ve(j)}"]
    rs, vrs, as_ = (", ".join(f"{x}{j}" for j in range(n)) for x in ("r", "vr", "a"))
    if regressor_source is None:
        L.append(f"    Y = self.regressor(q, v, [{vrs}], [{as_}])")
        L += [f"    Y{i} = Y[{i}]" for i in range(n)]
        Y = [[f"Y{i}[{k}]" for k in range(p)] for i in range(n)]
    else:
        lines, Y = regressor_source([q(j) for j in range(n)], [vh(j) for j in range(n)],
                                    [f"vr{j}" for j in range(n)], [f"a{j}" for j in range(n)])
        L += [f"    {line}" for line in lines]
    L += [f"    x{k} = 0.0 + " + " + ".join(f"{Y[i][k]} * r{i}" for i in range(n)) for k in range(p)]
    if robust == "sp1":
        L += ["    rho, eps = self.rho, self.epsilon",
              "    norm = _sqrt(0.0 + " + " + ".join(f"x{k} * x{k}" for k in range(p)) + ")",
              "    g = rho / norm if norm > eps else rho / eps"]
        L += [f"    w{k} = {repr(float(theta0[k]))} + -g * x{k}" for k in range(p)]
    elif robust == "sp2":
        L.append("    rho, eps = self.rho, self.epsilon")
        L += [f"    w{k} = {repr(float(theta0[k]))} + (-rho[{k}] * _copysign(1.0, x{k}) if abs(x{k}) > eps[{k}] "
              f"else -(rho[{k}] / eps[{k}]) * x{k})" for k in range(p)]
    else:
        L.append("    u = self.robust_input([" + ", ".join(f"x{k}" for k in range(p)) + "])")
        L += [f"    w{k} = {repr(float(theta0[k]))} + u[{k}]" for k in range(p)]
    L.append("    return [" + ", ".join(
        "0.0 + " + " + ".join(f"{Y[i][k]} * w{k}" for k in range(p)) + f" - {repr(float(K[i]))} * r{i}"
        for i in range(n)) + "]")
    return "\n".join(L) + "\n"


def compile_scalar_law(ctrl, packed: bool = False):
    """:func:`scalar_law_source` for controller ``ctrl`` (its n, theta_0, K, Lambda; the robust
    input inlined for :class:`SpongSP1Controller` / :class:`SpongSP2Controller` unless a subclass
    overrides ``robust_input``), compiled; tests/test_slotine_li.py and tests/test_compiled_blocks.py
    check both forms against :func:`spong_law`."""
    robust = "call"
    if type(ctrl).robust_input is SpongSP1Controller.robust_input:
        robust = "sp1"
    elif type(ctrl).robust_input is SpongSP2Controller.robust_input:
        robust = "sp2"
    src = scalar_law_source(ctrl.n, len(ctrl._theta0), ctrl._Lam, ctrl._K, ctrl._theta0, robust, packed,
                            getattr(ctrl.regressor, "scalar_source", None))
    ns = {"_sqrt": math.sqrt, "_copysign": math.copysign, "_cos": math.cos, "_sin": math.sin}
    exec(compile(src, f"<{type(ctrl).__name__} law>", "exec"), ns)
    f = ns["_law"]
    f.source = src
    return f


# --------------------------------------------------------------------------- systems
class PDController(DiscreteController):
    """PD baseline with Spong's gains: tau = -K (q~' + Lambda q~)."""

    def __init__(self, n, period, K, Lambda):
        super().__init__(n, period, name="PDController")
        self.K = diag_gain(K, n, "K")
        self.Lambda = diag_gain(Lambda, n, "Lambda")
        self._K, self._Lam = self.K.tolist(), self.Lambda.tolist()

    def compute(self, t, q_d, qd_d, qdd_d, q, v, v_error):
        K, Lam = self._K, self._Lam
        return [-K[j] * (v_error[j] + Lam[j] * (q[j] - q_d[j])) for j in range(self.n)]


class _SpongController(DiscreteController):
    """Thin wrapper: :meth:`compute` is :func:`spong_law` with this controller's regressor,
    theta_0, K, Lambda and robust input.  ``scalar_fast_path=True`` (closed-form 2-joint
    regressors such as JS eq. 15) runs the same eqs. 11-12 in scalar Python math instead, as
    straight-line code compiled once per controller (:func:`scalar_law_source`);
    tests/test_slotine_li.py and tests/test_compiled_blocks.py check it gives :func:`spong_law`'s torque."""

    def __init__(self, n, period, regressor, theta0, K, Lambda, name, scalar_fast_path=False):
        super().__init__(n, period, name=name)
        self.regressor = regressor
        self.theta0 = np.asarray(theta0, dtype=float)
        self.K = diag_gain(K, n, "K")
        self.Lambda = diag_gain(Lambda, n, "Lambda")
        self._Lam, self._K, self._theta0 = self.Lambda.tolist(), self.K.tolist(), self.theta0.tolist()
        self.scalar_fast_path = bool(scalar_fast_path)
        self.uncertainty = None  # the parameter set rho comes from (set by the factories)

    def robust_input(self, xi):  # pragma: no cover - abstract
        raise NotImplementedError

    def compute(self, t, q_d, qd_d, qdd_d, q, v, v_error):
        if self.scalar_fast_path:
            return self.compute_scalar(q_d, qd_d, qdd_d, q, v, v_error)
        return spong_law(self.regressor, self.robust_input, self.theta0, self.K, self.Lambda,
                         q_d, qd_d, qdd_d, q, v, v_error)

    def compute_scalar(self, q_d, qd_d, qdd_d, q, v, v_error):
        """eqs. 11 and 12 in scalar Python (same math as :func:`spong_law`), for small n."""
        return self._scalar_law(q_d.tolist(), qd_d.tolist(), qdd_d.tolist(), q.tolist(), v.tolist(),
                                v_error.tolist())

    def _scalar_law(self, q_d, qd_d, qdd_d, q, v, v_error):
        """:meth:`compute_scalar` on lists (the per-tick path), by :func:`scalar_law_source`'s
        straight-line code for this n, p (compiled once per controller)."""
        f = self.__dict__.get("_law")
        if f is None:
            f = self._law = compile_scalar_law(self)
        return f(self, q_d, qd_d, qdd_d, q, v, v_error)

    def _update(self, context, discrete_state):
        """Per-tick update: the scalar path reads every input once as a list (the numpy path is
        :meth:`DiscreteController._update`)."""
        if not self.scalar_fast_path:
            return DiscreteController._update(self, context, discrete_state)
        n = self.n
        if self._inputs_port is not None:  # one Eval of [x_d, q, v, v_error]
            x = self._inputs_port.Eval(context).tolist()
            law = self.__dict__.get("_packed_law")
            if law is None:
                law = self._packed_law = compile_scalar_law(self, packed=True)
            u = law(self, x)
            if self._feedforward:
                qa, va = np.array(x[3 * n:4 * n]), np.array(x[4 * n:5 * n])
                u = np.asarray(u, dtype=float) + sum(np.asarray(f(qa, va), dtype=float) for f in self._feedforward)
            self.write_u(discrete_state, u)
            return
        x_d = self._x_d_port.Eval(context).tolist()
        u = self._scalar_law(x_d[:n], x_d[n:2 * n], x_d[2 * n:], self._q_port.Eval(context).tolist(),
                             self._v_port.Eval(context).tolist(), self._v_error_port.Eval(context).tolist())
        if self._feedforward:
            u = self.with_feedforward(context, u)
        self.write_u(discrete_state, u)


class FusedInputController(Diagram):
    """The controller block of a :class:`DiscreteController` ``law`` (SP1/SP2, CI): ports ``x_d``, ``q``, ``v``,
    ``v_error`` -> ``u`` as the contract says, gathered inside by one C++ Multiplexer into the law's
    ``inputs`` port, so the per-tick Python update reads one port instead of four (about 3 us per
    2500 Hz tick, BUILD_NOTES "Speed of the 2500 Hz loop"); same torque
    (tests/test_compiled_blocks.py).  The law's attributes (``rho``, ``theta0``, ``uncertainty``,
    ``compute``, ``add_feedforward``, ...) are read through this block; ``law`` is the LeafSystem."""

    def __init__(self, law):
        super().__init__()
        n = law.n
        law.enable_fused_input()
        b = DiagramBuilder()
        b.AddSystem(law)
        mux = b.AddSystem(Multiplexer([3 * n, n, n, n]))
        mux.set_name("controller_inputs")
        for i, name in enumerate(("x_d", "q", "v", "v_error")):
            b.ExportInput(mux.get_input_port(i), name)
        b.Connect(mux.get_output_port(0), law.GetInputPort("inputs"))
        b.ExportOutput(law.GetOutputPort("u"), "u")
        b.BuildInto(self)
        self.set_name(law.get_name())
        self.__dict__["law"] = law

    def __getattr__(self, name):
        law = self.__dict__.get("law")
        if law is None or name.startswith("__"):
            raise AttributeError(name)
        return getattr(law, name)


class SpongSP1Controller(_SpongController):
    """SP1 (JS eqs. 9-12, 18): a single uncertainty bound rho and boundary layer epsilon."""

    def __init__(self, n, period, regressor, theta0, rho, epsilon, K, Lambda, scalar_fast_path=False):
        super().__init__(n, period, regressor, theta0, K, Lambda, "SpongSP1Controller", scalar_fast_path)
        if rho < 0 or epsilon <= 0:
            raise RobustDrakeError(f"SP1 needs rho >= 0 and epsilon > 0 (got {rho}, {epsilon})")
        self.rho = float(rho)
        self.epsilon = float(epsilon)

    def robust_input(self, xi):
        return sp1_robust_input(xi, self.rho, self.epsilon)


class SpongSP2Controller(_SpongController):
    """SP2 (JS eqs. 9-12, SP2): per-parameter bounds rho_i and boundary layers epsilon_i."""

    def __init__(self, n, period, regressor, theta0, rho, epsilon, K, Lambda, scalar_fast_path=False):
        super().__init__(n, period, regressor, theta0, K, Lambda, "SpongSP2Controller", scalar_fast_path)
        p = self.theta0.shape[0]
        self.rho = np.broadcast_to(np.asarray(rho, dtype=float), (p,)).tolist()
        self.epsilon = np.broadcast_to(np.asarray(epsilon, dtype=float), (p,)).tolist()
        if min(self.rho) < 0 or min(self.epsilon) <= 0:
            raise RobustDrakeError("SP2 needs rho_i >= 0 and epsilon_i > 0")
        self._rho_np, self._eps_np = np.array(self.rho), np.array(self.epsilon)

    def robust_input(self, xi):
        if isinstance(xi, np.ndarray):
            return sp2_robust_input(xi, self._rho_np, self._eps_np)
        return sp2_robust_input(xi, self.rho, self.epsilon)


# --------------------------------------------------------------------------- factories
def d2r2_regressor_single(q, qd, v, a) -> list:
    """JS eq. 15 for one sample in scalar math, as nested lists (the per-tick path; the
    vectorised implementation is :func:`robust_drake.regressor.d2r2_regressor`)."""
    c2 = math.cos(q[1])
    s2 = math.sin(q[1])
    a1, a2 = a[0], a[1]
    y13 = c2 * (2.0 * a1 + a2) - s2 * (qd[0] * v[1] + qd[1] * (v[0] + v[1]))
    y23 = c2 * a1 + s2 * qd[0] * v[0]
    return [[a1, a1 + a2, y13], [0.0, a1 + a2, y23]]


def d2r2_regressor_source(q, qd, v, a) -> tuple[list, list]:
    """:func:`d2r2_regressor_single` as straight-line source for :func:`scalar_law_source`: ``q``,
    ``qd``, ``v``, ``a`` are the expressions (strings) of the entries; returns (lines, Y) with Y the
    2 x 3 entry expressions.  Same operations in the same order as the function (so the same
    floats; tests/test_compiled_blocks.py), with ``_cos``/``_sin`` = math.cos/math.sin."""
    lines = [f"_c2 = _cos({q[1]})", f"_s2 = _sin({q[1]})", f"_y12 = {a[0]} + {a[1]}",
             f"_y13 = _c2 * (2.0 * {a[0]} + {a[1]}) - _s2 * ({qd[0]} * {v[1]} + {qd[1]} * ({v[0]} + {v[1]}))",
             f"_y23 = _c2 * {a[0]} + _s2 * {qd[0]} * {v[0]}"]
    return lines, [[a[0], "_y12", "_y13"], ["0.0", "_y12", "_y23"]]


d2r2_regressor_single.scalar_source = d2r2_regressor_source


@dataclass(frozen=True)
class ClosedFormSlotineLi:
    """A robot whose Slotine-Li regressor is printed in closed form, with the paper's design.

    ``regressor(q, qd, v, a)`` returns the n x p matrix for one sample (nested lists, scalar math);
    ``theta0``, ``rho_sp1`` (bound on ||theta~||_2), ``rho_sp2`` (bounds on |theta~_i|), gains
    ``K``, ``Lambda`` and a JSON-able description of the uncertainty set."""

    regressor: Callable
    theta0: tuple
    rho_sp1: float
    rho_sp2: tuple
    K: tuple
    Lambda: tuple
    uncertainty: dict


def _d2r2_closed_form() -> ClosedFormSlotineLi:
    from robust_drake.models import D2R2_THETA0, D2R2_THETA_LOADED, D2R2_THETA_UNLOADED

    return ClosedFormSlotineLi(
        regressor=d2r2_regressor_single, theta0=tuple(D2R2_THETA0), rho_sp1=D2R2_RHO_SP1,
        rho_sp2=D2R2_RHO_SP2, K=D2R2_K, Lambda=D2R2_LAMBDA,
        uncertainty={
            "kind": "box", "source": "Jaritz & Spong appendix 12.1 (eq. 93 load intervals, tables 8-11)",
            "parameters": ["m1 lc1^2 + m2 l1^2 + I1", "m2 lc2^2 + I2", "m2 l1 lc2"],
            "theta0": list(D2R2_THETA0), "bounds": list(D2R2_RHO_SP2),
            "theta_unloaded": list(D2R2_THETA_UNLOADED), "theta_loaded": list(D2R2_THETA_LOADED),
        })


#: Closed-form Slotine-Li regressors by name; a robot's description names its one
#: (``closed_form_regressor``).  Every other URDF arm uses the Drake-derived one.
CLOSED_FORM_SLOTINE_LI: dict[str, Callable[[], ClosedFormSlotineLi]] = {"d2r2": _d2r2_closed_form}


def closed_form_for(robot) -> Callable[[], ClosedFormSlotineLi] | None:
    """The closed-form design of ``robot`` named by its description, or None."""
    from robust_drake.description import describe

    return CLOSED_FORM_SLOTINE_LI.get(describe(robot).closed_form_regressor)

#: Defaults for arms without published gains (see :func:`default_gains`).
DEFAULT_LAMBDA = 20.0  # 1/s, bandwidth of q~ on the sliding surface r = 0
DEFAULT_K_BANDWIDTH = 20.0  # 1/s, K = this * diag(M(0)): bandwidth of r under K alone
DEFAULT_REL_BOUND = 0.2  # box half-width relative to |theta0_i|


def default_gains(ctx):
    """(K, Lambda) for the loop in ``ctx``: JS section 8's diag(30, 10), diag(50, 20) for robots
    with a closed-form design (the D2R2); otherwise Lambda = 20 I [1/s] and
    K = 20 [1/s] * diag(M(0)) [N m s/rad], so every joint's r decays at about 20 1/s under K
    alone whatever its inertia (M from the URDF at q = 0, reflected rotor inertia included)."""
    cf = closed_form_for(ctx.robot)
    if cf is not None:
        d = cf()
        return d.K, d.Lambda
    return _mass_matrix_gains(str(ctx.robot), ctx.load), (DEFAULT_LAMBDA,) * ctx.n


@functools.lru_cache(maxsize=32)
def _mass_matrix_gains(robot, load):
    from robust_drake.models import make_plant, resolve_urdf

    plant = make_plant(str(resolve_urdf(robot, load)))
    M0 = plant.CalcMassMatrix(plant.CreateDefaultContext())
    return tuple(DEFAULT_K_BANDWIDTH * np.diag(M0))


def box_uncertainty(theta0, names, rel_bound=DEFAULT_REL_BOUND, abs_bound=0.0) -> dict:
    """The box {theta : |theta_i - theta0_i| <= b_i}, b_i = rel_bound |theta0_i| + abs_bound.

    SP1's rho bounds ||theta~||_2 (JS eqs. 8, 17-18); over the box its maximum is attained at a
    vertex and equals ||b||_2 exactly.  SP2's rho_i bound |theta~_i| (eq. 8): rho_i = b_i.
    Returns a JSON-able dict with ``theta0``, ``bounds`` (b), ``rho_sp1``, ``rho_sp2``."""
    if not (np.isfinite(rel_bound) and rel_bound >= 0 and np.isfinite(abs_bound) and abs_bound >= 0):
        raise RobustDrakeError(f"rel_bound and abs_bound must be finite and >= 0 (got {rel_bound}, {abs_bound})")
    th = np.asarray(theta0, dtype=float)
    b = rel_bound * np.abs(th) + abs_bound
    return {"kind": "box", "source": "URDF base parameters +- rel_bound |theta0_i| + abs_bound",
            "rel_bound": float(rel_bound), "abs_bound": float(abs_bound), "parameters": list(names),
            "theta0": th.tolist(), "bounds": b.tolist(), "rho_sp1": float(np.linalg.norm(b)),
            "rho_sp2": b.tolist()}


def reference_regressor_norm(ctx, reg, samples: int = 200) -> float:
    """max over the loop's reference of the spectral norm ||Y(q_d, qd_d, qd_d, qdd_d)||_2
    (Y: the Slotine-Li regressor at zero tracking error, ``samples`` instants); nan if the loop
    has no reference to sample."""
    from robust_drake.trajectories import make_reference

    cfg = ctx.config
    if cfg is None or not hasattr(cfg, "trajectory"):
        return float("nan")
    ref = make_reference(ctx.arm, cfg.trajectory, **dict(getattr(cfg, "trajectory_params", {}) or {}))
    duration = float(getattr(cfg, "duration", None) or ref.duration)
    q, qd, qdd = (np.asarray(x, float).reshape(-1, ctx.n) for x in ref(np.linspace(0.0, duration, samples)))
    Y = reg.evaluate(q, qd, qdd)
    return float(np.linalg.norm(Y, ord=2, axis=(1, 2)).max())


#: JS eq. 18 boundary layer for arms without a published one: stability margin of the sampled
#: loop, h lambda_max(M^-1 (K + (rho/epsilon) Y Y^T)) <= SAMPLED_BETA (explicit-Euler limit 2;
#: measured on serial7 and siciliano_2link at 2500 Hz: the torque chatters from beta ~ 2 on)
SAMPLED_BETA = 0.5


@dataclass(frozen=True)
class ReferenceTube:
    """What the boundary-layer rule needs from the loop's reference (q_d, qd_d, qdd_d) sampled at
    ``samples`` instants, Y = Y(q_d, qd_d, qd_d, qdd_d) the Slotine-Li regressor, M = M(q_d):

    g_max = max ||M^-1/2 Y||_2^2 [1/(kg m^2) x (regressor units)^2], k_max = max lambda_max(M^-1 K)
    and kappa = min lambda_min(M^-1 K) [1/s], minv = max diag(M^-1) per joint [1/(kg m^2)]."""

    g_max: float
    k_max: float
    kappa: float
    minv: tuple
    samples: int


def reference_tube(ctx, reg, K, samples: int = 200) -> ReferenceTube | None:
    """:class:`ReferenceTube` of the loop in ``ctx`` (None without a reference to sample)."""
    from scipy.linalg import eigh

    from robust_drake.models import make_plant, resolve_urdf
    from robust_drake.trajectories import make_reference

    cfg = ctx.config
    if cfg is None or not hasattr(cfg, "trajectory"):
        return None
    ref = make_reference(ctx.arm, cfg.trajectory, **dict(getattr(cfg, "trajectory_params", {}) or {}))
    duration = float(getattr(cfg, "duration", None) or ref.duration)
    q, qd, qdd = (np.asarray(x, float).reshape(-1, ctx.n) for x in ref(np.linspace(0.0, duration, samples)))
    Y = reg.slotine_li(q, qd, qd, qdd)
    plant = make_plant(str(resolve_urdf(ctx.robot, ctx.load)))
    pc = plant.CreateDefaultContext()
    Kd = np.diag(np.broadcast_to(np.asarray(K, float), (ctx.n,)))
    g, kmax, kap, minv = 0.0, 0.0, np.inf, np.zeros(ctx.n)
    for Yk, qk in zip(Y, q):
        plant.SetPositions(pc, qk)
        M = plant.CalcMassMatrix(pc)
        w, V = np.linalg.eigh(M)
        Mih = (V / np.sqrt(w)) @ V.T
        g = max(g, float(np.linalg.norm(Mih @ Yk, 2)) ** 2)
        lam = eigh(Kd, M, eigvals_only=True)
        kmax, kap = max(kmax, float(lam[-1])), min(kap, float(lam[0]))
        minv = np.maximum(minv, np.diag((V / w) @ V.T))
    return ReferenceTube(g, kmax, kap, tuple(minv.tolist()), int(len(q)))


def sampled_epsilon(rho, tube: ReferenceTube, period: float, beta: float = SAMPLED_BETA) -> float:
    """SP1's boundary layer (JS eq. 18) on ||xi|| = ||Y^T r|| for arms without a published one (units
    of Y^T r, N m rad/s per parameter unit): the smallest epsilon the sampled loop tolerates, which gives the smallest ultimate
    bound (:func:`spong_ultimate_bound`, linear in rho epsilon).

    Inside the layer eq. 18 adds the gain (rho/epsilon) Y Y^T to K on r, so M r' = -(K + (rho/
    epsilon) Y Y^T) r + ...; sampled with period h the loop needs h lambda_max(M^-1 (K + (rho/
    epsilon) Y Y^T)) below 2 (explicit Euler). With beta = SAMPLED_BETA (4x margin) and the
    tube's bounds lambda_max(M^-1 Y Y^T) <= g_max, lambda_max(M^-1 K) <= k_max:

        epsilon = rho g_max h / (beta - h k_max).

    SP2 with epsilon_i = epsilon rho_i / ||rho|| has the same in-layer gain and the same bound
    (sum_i rho_i epsilon_i = ||rho|| epsilon). Returns 1 when rho = 0 (u = 0) or no tube."""
    rho = float(rho)
    if tube is None or rho <= 0 or tube.g_max <= 0:
        return 1.0
    room = beta - period * tube.k_max
    if room <= 0:
        raise RobustDrakeError(f"sample period {period} s too long for K alone (h lambda_max(M^-1 K) = "
                               f"{period * tube.k_max:.3g} >= {beta}); lower K or raise the rate")
    return rho * tube.g_max * period / room


def spong_ultimate_bound(rho_epsilon: float, tube: ReferenceTube, Lambda) -> list:
    """Ultimate bound on |q~_j| [rad] per joint for SP1/SP2 (JS eqs. 13, 18, SP2, 20; Spong [11]).

    With V = 1/2 r^T M r, eq. 13 and the skew symmetry of M' - 2C (eq. 6), V' = -r^T K r +
    r^T Y (theta~ + u). Inside SP1's layer r^T Y (theta~ + u) <= rho ||xi|| - (rho/epsilon)
    ||xi||^2 <= rho epsilon / 4, outside it is <= 0 (SP2: sum_i rho_i epsilon_i / 4). With
    r^T K r >= kappa r^T M r (kappa = min lambda_min(M^-1 K)): V' <= -2 kappa V + rho epsilon / 4,
    so ultimately r^T M r <= rho epsilon / (4 kappa) and |r_j| <= sqrt((M^-1)_jj rho epsilon /
    (4 kappa)); q~_j is r_j through a first-order filter with pole -Lambda_j, so
    |q~_j| <= |r_j| / Lambda_j. M over the reference tube (valid once the error is small)."""
    lam = np.broadcast_to(np.asarray(Lambda, float), (len(tube.minv),))
    r = np.sqrt(np.asarray(tube.minv) * float(rho_epsilon) / (4.0 * tube.kappa))
    return (r / lam).tolist()


def default_epsilon(rho, tube: ReferenceTube | None, period: float):
    """(epsilon, rho epsilon) for SP1 (scalar rho) or SP2 (rho_i): :func:`sampled_epsilon` of
    ||rho||; SP2 splits it as epsilon_i = epsilon rho_i / ||rho|| (1 where rho_i = 0, u_i = 0)."""
    r = np.asarray(rho, dtype=float)
    e = sampled_epsilon(float(np.linalg.norm(r)), tube, period)
    if r.ndim == 0:
        return e, float(r) * e
    nr = float(np.linalg.norm(r))
    ei = np.where(r > 0, e * r / nr if nr > 0 else 1.0, 1.0)
    return ei, float(np.sum(r * ei))


def _spong_design(ctx, params, which):
    """(regressor, theta0, rho, uncertainty, scalar_fast_path) for SP1 (which=0) or SP2 (1).

    Order: a user ``regressor`` (with ``theta0``/``rho`` from params, else D2R2 values as
    before); a closed-form design for the robot (JS for the D2R2) unless ``rel_bound`` or
    ``abs_bound`` ask for a box around its theta0; else the Drake-derived Slotine-Li regressor of
    the URDF (:meth:`InverseDynamicsRegressor.slotine_li_single`) with theta0 = the URDF's base
    parameters and rho from :func:`box_uncertainty`."""
    box = {k: params.pop(k) for k in ("rel_bound", "abs_bound") if k in params}
    if "model" in params:  # an identified model: theta0 and rho from its confidence set
        return _identified_design(ctx, params, which, box)
    if "regressor" in params:
        from robust_drake.models import D2R2_THETA0

        reg = params.pop("regressor")
        theta0 = params.pop("theta0", D2R2_THETA0)
        rho = params.pop("rho", (D2R2_RHO_SP1, D2R2_RHO_SP2)[which])
        return reg, theta0, rho, {"kind": "user", "theta0": np.asarray(theta0, float).tolist()}, False
    cf = closed_form_for(ctx.robot)
    if cf is not None:
        d = cf()
        theta0 = params.pop("theta0", d.theta0)
        if box:
            unc = box_uncertainty(theta0, d.uncertainty["parameters"], **box)
            rho = params.pop("rho", (unc["rho_sp1"], unc["rho_sp2"])[which])
        else:
            unc = dict(d.uncertainty, rho_sp1=d.rho_sp1, rho_sp2=list(d.rho_sp2))
            rho = params.pop("rho", (d.rho_sp1, d.rho_sp2)[which])
        return d.regressor, theta0, rho, unc, True
    from robust_drake.regressor import InverseDynamicsRegressor

    reg = InverseDynamicsRegressor.from_robot(ctx.robot, ctx.load)
    if reg.n != ctx.n:
        raise RobustDrakeError(f"regressor of {ctx.robot!r} has {reg.n} joints, the loop has {ctx.n}")
    theta0 = np.asarray(params.pop("theta0", reg.base_parameters()), dtype=float)
    if theta0.shape != (reg.p_base,):
        raise RobustDrakeError(f"theta0 must have the {reg.p_base} base parameters of {ctx.robot!r} "
                               f"(InverseDynamicsRegressor.base_names), got shape {theta0.shape}")
    unc = box_uncertainty(theta0, reg.base_names, **box)
    rho = params.pop("rho", (unc["rho_sp1"], unc["rho_sp2"])[which])
    _epsilon_rule(ctx, params, reg, rho, unc)
    return reg.slotine_li_single, theta0, rho, unc, False


def _identified_design(ctx, params, which, box):
    """:func:`_spong_design` for ``model=`` (an IdentifiedModel or a report / model path): theta0 =
    its base parameters, SP1's rho = sqrt(lambda_max(P)) and SP2's rho_i = sqrt(P_ii) of its
    1 - ``alpha`` confidence set E(P, theta0) (the largest ||theta~||_2 and |theta~_i| over it),
    or the box of ``rel_bound``/``abs_bound`` around its theta0; boundary layer by the same rule."""
    from robust_drake.identification.model import as_identified_model, controller_set
    from robust_drake.regressor import InverseDynamicsRegressor

    model = as_identified_model(params.pop("model"))
    alpha = float(params.pop("alpha", 0.01))
    reg = InverseDynamicsRegressor.from_robot(ctx.robot, ctx.load)
    theta0, _, unc = controller_set(model, reg, alpha) if not box else (None, None, None)
    if box:
        theta0 = np.asarray(model.base_values, float)
        unc = box_uncertainty(theta0, reg.base_names, **box)
        unc["source"] = "identified base parameters +- rel_bound |theta0_i| + abs_bound"
    else:
        unc.update(rho_sp1=unc["rho"], rho_sp2=unc["rho_i"])
    rho = params.pop("rho", (unc["rho_sp1"], unc["rho_sp2"])[which])
    _epsilon_rule(ctx, params, reg, rho, unc)
    params["_model"] = model
    return reg.slotine_li_single, theta0, rho, unc, False


def _epsilon_rule(ctx, params, reg, rho, unc) -> None:
    """The boundary layer for an arm without a published one (:func:`default_epsilon`), into
    ``params["epsilon"]`` unless given, and its record into ``unc["epsilon_rule"]``."""
    if "epsilon" not in params:
        K, Lam = params.get("K", default_gains(ctx)[0]), params.get("Lambda", default_gains(ctx)[1])
        tube = reference_tube(ctx, reg, K)
        eps, rho_eps = default_epsilon(rho, tube, ctx.period)
        params["epsilon"] = eps
        unc["epsilon_rule"] = {
            "rule": "sampled-loop margin: epsilon = rho g_max h / (beta - h k_max), SP2 epsilon_i = "
                    "epsilon rho_i / ||rho|| (spong.sampled_epsilon)",
            "beta": SAMPLED_BETA, "g_max": None if tube is None else tube.g_max,
            "epsilon": np.asarray(eps).tolist(),
            "error_bound": None if tube is None else spong_ultimate_bound(rho_eps, tube, Lam)}


def _make_spong(ctx, params, which):
    params = dict(params)
    reg, theta0, rho, unc, fast = _spong_design(ctx, params, which)
    model = params.pop("_model", None)
    K, Lam = default_gains(ctx) if not ("K" in params and "Lambda" in params) else (None, None)
    p = dict(theta0=theta0, rho=rho, epsilon=(EPSILON_SP1, EPSILON_SP2)[which], K=K, Lambda=Lam)
    p.update(params)
    if K is not None and "K" not in params:
        p["K"] = K
    cls = (SpongSP1Controller, SpongSP2Controller)[which]
    try:
        c = cls(ctx.n, ctx.period, reg, scalar_fast_path=fast, **p)
    except (ValueError, TypeError) as exc:
        raise RobustDrakeError(f"{('sp1', 'sp2')[which]}: {exc}") from None
    c.uncertainty = unc
    if model is not None:  # its friction and effects fed forward, stateful ones as blocks
        from robust_drake.identification.model import attach_compensation

        attach_compensation(c, model)
    return FusedInputController(c)


def make_pd(ctx, K=None, Lambda=None):
    """PD baseline with the same default gains as SP1/SP2 (:func:`default_gains`)."""
    if K is None or Lambda is None:
        K0, L0 = default_gains(ctx)
        K = K0 if K is None else K
        Lambda = L0 if Lambda is None else Lambda
    try:
        return PDController(ctx.n, ctx.period, K, Lambda)
    except ValueError as exc:
        raise RobustDrakeError(f"pd: {exc}") from None


def make_sp1(ctx, **params):
    """Registry factory ``sp1``: JS eqs. 9-12, 18 for any URDF arm (see :func:`_spong_design`).
    Params: ``rel_bound``, ``abs_bound`` (uncertainty box), ``theta0``, ``rho``, ``epsilon``,
    ``K``, ``Lambda``, ``regressor``; ``model`` (an identified model or a report / model path:
    theta0, rho from its ``alpha`` (0.01) confidence set, its compensation) and ``alpha``."""
    return _make_spong(ctx, params, 0)


def make_sp2(ctx, **params):
    """Registry factory ``sp2``: JS eqs. 9-12, (SP2) for any URDF arm; as :func:`make_sp1`."""
    return _make_spong(ctx, params, 1)
