"""Torques that depend on the configuration: a joint's own angle (``position_dependent``: a
harmonic of q, cogging; ``spring``: a linear spring about q = 0) and other joints' angles
(``configuration_dependent``, issue 21: cables and hoses, with its term grammar and the check that a
term is not a gravity term already in the rigid-body model).
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from robust_drake.effects.base import Effect, _limit_by, subsample_configurations
from robust_drake.errors import RobustDrakeError


class PositionDependent(Effect):
    """Position-periodic torque (cogging, ripple, cable): ``a sin(h q) + b cos(h q)``,
    harmonic h per revolution fixed per candidate. Parameters: ``amplitude`` A = hypot(a, b)
    [N m], ``phase`` phi with A sin(h q + phi), and the raw ``sin`` / ``cos`` coefficients."""

    kind = "position_dependent"
    coef_names = ("sin", "cos")
    default_shape = {"harmonic": 4}
    #: every harmonic 1-12 per revolution: cogging of a motor with S slots and P poles repeats
    #: lcm(S, P) times per motor revolution, torque ripple of a drive at multiples of the pole
    #: pairs / phases; 5/rev and 7/rev (the 6k -+ 1 harmonics of a three-phase drive) were missing
    #: from the earlier grid (2, 3, 4, 6, 8, 12), issue 21. On a joint whose gravity torque is a
    #: first harmonic of its own angle (the first horizontal axis) harmonic 1 lies in the
    #: rigid-body span and the fit rejects it as not identifiable.
    shape_grid = [{"harmonic": h} for h in range(1, 13)]

    def _features(self, j, q, qd, qdd, tau, taud):
        h = self.shape["harmonic"]
        return np.stack([np.sin(h * q[:, j]), np.cos(h * q[:, j])], axis=1)

    def _parameters_one(self, c):
        a, b = float(c[0]), float(c[1])
        return {"amplitude": math.hypot(a, b), "phase": math.atan2(b, a), "sin": a, "cos": b}

    def admissible(self, parameters, context=None):
        """Cogging / ripple amplitude <= the largest torque the joint carried in the data."""
        return _limit_by(self, parameters, "amplitude", context, "tau_max", "max |tau|")

    def _coef_one(self, p):
        if "sin" in p and "cos" in p:
            return [float(p["sin"]), float(p["cos"])]
        A, phi = float(p["amplitude"]), float(p.get("phase", 0.0))
        return [A * math.cos(phi), A * math.sin(phi)]


class Spring(Effect):
    """Joint-space spring (cables, balancing spring): the plant gets ``-stiffness q_j`` (rest at
    the joint zero; a rest-angle offset shows up as a separate torque_offset). [N m/rad]"""

    kind = "spring"
    coef_names = ("stiffness",)
    #: a passive spring restores (k >= 0); a negative stiffness would feed energy in
    bounds = {"stiffness": (0.0, math.inf)}
    shape_grid = [{}]

    def _features(self, j, q, qd, qdd, tau, taud):
        return q[:, j:j + 1]


#: term letter -> label; ``{k}`` is the joint NUMBER from 1 (``sin(q1)``: the first joint, as the
#: CSV column ``q1``); the parsed tuples (:func:`parse_terms`) hold 0-based indices
_TERM_LABELS = {"s": "sin(q{k})", "c": "cos(q{k})", "l": "q{k}", "p": "q{k}^2"}


def term_tokens(terms: list[tuple[str, int]]) -> str:
    """Parsed terms (0-based joint indices) as the token text (``"s1,c1"``, joints from 1)."""
    return ",".join(f"{f}{k + 1}" for f, k in terms)


def configuration_terms(n: int, joint: int, prismatic=()) -> list[str]:
    """The default basis of :class:`ConfigurationDependent` on ``joint`` (0-based index) of an
    n-joint arm, as tokens whose number is the joint NUMBER from 1 (``s1`` = sin of the first
    joint's angle, the CSV column ``q1``):
    for every other revolute joint k, ``s<k>`` = sin q_k and ``c<k>`` = cos q_k [1]; for a
    prismatic joint k, ``l<k>`` = q_k [m] and ``p<k>`` = q_k^2 [m^2] (its own prismatic joint:
    only ``p<j>``, q_j is the ``spring`` kind). Own revolute angle left out: sin q_j, cos q_j
    are the first harmonic of ``position_dependent`` and q_j is ``spring``; the constant is
    ``torque_offset``. At most 2 (n - 1) + 1 columns."""
    out = []
    for k in range(n):
        if k in prismatic:
            out += ([] if k == joint else [f"l{k + 1}"]) + [f"p{k + 1}"]
        elif k != joint:
            out += [f"s{k + 1}", f"c{k + 1}"]
    return out


def parse_terms(terms) -> list[tuple[str, int]]:
    """[(function letter, 0-based joint index)] of a term list ``"s1,c1,l3"`` (or a list of
    tokens) whose numbers are joint numbers from 1 (``s1`` = sin q1, the first joint)."""
    tokens = [t.strip() for t in (terms.split(",") if isinstance(terms, str) else terms) if str(t).strip()]
    out = []
    for t in tokens:
        f, k = t[:1], t[1:]
        if f not in _TERM_LABELS or not k.isdigit() or int(k) < 1:
            raise RobustDrakeError(f"configuration_dependent: bad term {t!r}: use s<k> (sin q_k), c<k> "
                                   "(cos q_k), l<k> (q_k) or p<k> (q_k^2), k a joint number from 1")
        out.append((f, int(k) - 1))
    if not out:
        raise RobustDrakeError("configuration_dependent: no terms")
    return out


def term_values(terms: list[tuple[str, int]], q) -> np.ndarray:
    """Pure: the basis functions phi_i(q) (N, m) of parsed ``terms`` at configurations q (N, n)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if max(k for _, k in terms) >= q.shape[1]:
        raise RobustDrakeError(f"configuration_dependent: a term names joint {max(k for _, k in terms) + 1} "
                               f"of a {q.shape[1]}-joint arm")
    fun = {"s": np.sin, "c": np.cos, "l": lambda x: x, "p": np.square}
    return np.stack([fun[f](q[:, k]) for f, k in terms], axis=1)


class ConfigurationDependent(Effect):
    """A torque on joint j that is a low-order function of the configuration: a cable or hose
    dragged by the other links, a spring coupled across joints, a counterbalance acting through
    another joint's linkage. Offered only where the baseline residual of joint j depends on
    another joint's angle (``residual.configuration_dependence``).

    Model (eq. CD1)::

        f_e,j(q) = -sum_i c_i phi_i(q),     phi in {sin q_k, cos q_k : k != j revolute}
                                                 + {q_k, q_k^2 : k prismatic}

    f_e the torque [N m] the effect adds to joint j (plant side), c_i [N m] (per m, m^2 on a
    prismatic joint) the coefficients of the columns phi_i(q) on joint j's equation; as
    everywhere in this module, ``columns @ c`` is the torque the motor supplies because of the
    effect. A first harmonic per joint is the lowest order that is periodic in a revolute
    angle (a cable's or spring's geometry repeats every turn); with the constant (the
    ``torque_offset`` kind) and j's own sin/cos (``position_dependent`` harmonic 1) and q_j
    (``spring``) left out it has 2 (n - 1) columns -- 4 on a 3-joint arm, 12 on a 7-joint one;
    products q_k q_l would give n^2 columns for the few hundred independent samples of a log.

    Shape ``terms``: the basis as tokens numbered from 1 like the joints in every label
    (``"s1,c1,s2,c2"``: sin q1, cos q1, ... of the first two joints); None is
    :func:`configuration_terms` of the arm. ``joint=None`` (the excitation designer's
    ``--for-effects``): the default basis on every joint, separate coefficients ``"j<j>:sin(q1)"`` (j the joint number from 1).
    :meth:`candidates` drops every term that lies in the
    span of the rigid-body gravity columns of joint j (:func:`gravity_aliases`), so the
    candidate never duplicates gravity: on a serial arm joint j's gravity torque depends on its
    own angle in every term (the first joint of a vertical-plane arm: a sin q_0 + b cos q_0 +
    ...), so single other-joint terms are rarely aliases, but a linkage (parallelogram,
    counterbalance) can make joint j's gravity a function of another joint's angle alone. What
    is not an exact alias but nearly collinear on the data is rejected by the fit's
    identifiability check (``selection._trial``).

    Parameters (:meth:`parameters`): each coefficient by its term (``"sin(q1)"``: c [N m]),
    ``terms``, and over the configurations of the data the columns were first built on (the fit
    data in the repair) ``explained_rms`` = RMS_t |f_e,j(q(t))| and ``peak`` = max_t |f_e,j|
    [N m]. Admissible: the peak over the data within the joint's torque range (max |tau_j|).
    Block: :class:`ConfigurationDependentBlock`."""

    kind = "configuration_dependent"
    default_shape = {"terms": None}

    def __init__(self, joint: int | None = None, **shape):
        super().__init__(joint, **shape)
        if self.shape["terms"] is not None:
            if self.joint is None:
                raise RobustDrakeError("configuration_dependent: terms need a joint (joint=None takes the "
                                       "default basis on every joint)")
            self.shape["terms"] = term_tokens(parse_terms(self.shape["terms"]))
            if any(f in "sc" and k == self.joint for f, k in parse_terms(self.shape["terms"])):
                raise RobustDrakeError("configuration_dependent: sin / cos of the joint's own angle are the "
                                       "position_dependent kind (harmonic 1), not a term of this one")
        self.reference_q = None  # configurations of the first data the columns were built on

    def terms(self, n: int) -> list[tuple[str, int]]:
        """The parsed basis of the effect's joint (joint given)."""
        t = self.shape["terms"]
        return parse_terms(t) if t is not None else parse_terms(configuration_terms(n, self.joint))

    def layout(self, n: int) -> list[tuple[int, list[tuple[str, int]]]]:
        """[(joint, parsed terms)]: one entry, or with joint=None the default basis of every joint
        (separate coefficients per joint, as the library's per-joint kinds)."""
        if self.joint is None:
            return [(j, parse_terms(configuration_terms(n, j))) for j in range(n)] if n > 1 else []
        self.joints(n)
        return [(self.joint, self.terms(n))]

    def term_labels(self, n: int) -> list[str]:
        """Coefficient names: the term's label (``"sin(q1)"``), ``"j<j>:"`` (from 1) before it with joint=None."""
        pre = (lambda j: f"j{j + 1}:") if self.joint is None else (lambda j: "")
        return [pre(j) + _TERM_LABELS[f].format(k=k + 1) for j, ts in self.layout(n) for f, k in ts]

    def num_coef(self, n: int) -> int:
        return sum(len(ts) for _, ts in self.layout(n))

    def column_names(self, n: int) -> list[str]:
        labels = iter(self.term_labels(n))
        return [f"{self.kind}[{j + 1}]:{next(labels).split(':')[-1]}" for j, ts in self.layout(n) for _ in ts]

    def evaluate_columns(self, q, qd=None, qdd=None, tau=None, taud=None) -> np.ndarray:
        """(N, n, m) columns: phi(q) (eq. CD1) on joint j's rows, zero elsewhere."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        N, n = q.shape
        cols = np.zeros((N, n, self.num_coef(n)))
        i = 0
        for j, ts in self.layout(n):
            cols[:, j, i:i + len(ts)] = term_values(ts, q)
            i += len(ts)
        return cols

    def columns(self, data):
        if self.reference_q is None:
            self.reference_q = subsample_configurations(data.q)
        return super().columns(data)

    def _n_from(self, coef) -> int:
        if self.shape["terms"] is not None:
            return max([k for _, k in self.terms(0)] + [self.joint]) + 1
        m = len(coef)  # default basis: 2 (n - 1) terms per joint (all n joints with joint=None)
        return m // 2 + 1 if self.joint is not None else int(round((1 + math.sqrt(1 + 2 * m)) / 2))

    def torque(self, coef, q) -> np.ndarray:
        """Pure: the plant-side torque f_e(q) (N, n) [N m] at configurations q (N, n) (eq. CD1)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        return -(self.evaluate_columns(q) @ np.asarray(coef, dtype=float))

    def parameters(self, coef, q=None) -> dict:
        """Coefficients by term, ``terms``, and ``explained_rms`` / ``peak`` [N m] over ``q``
        (default: :attr:`reference_q`, the data the columns were first built on)."""
        coef = np.asarray(coef, dtype=float).ravel()
        n = self._n_from(coef) if q is None else np.atleast_2d(q).shape[1]
        labels = self.term_labels(n)
        if len(coef) != len(labels):
            raise RobustDrakeError(f"{self.name}: expected {len(labels)} coefficients, got {len(coef)}")
        out = {lab: float(c) for lab, c in zip(labels, coef)}
        if self.joint is not None:
            out["terms"] = term_tokens(self.terms(n))
        q = self.reference_q if q is None else q
        if q is not None and np.atleast_2d(q).shape[1] == n:
            f = self.torque(coef, q)[:, [j for j, _ in self.layout(n)]]
            rms, peak = np.sqrt(np.mean(f**2, axis=0)), np.max(np.abs(f), axis=0)
            one = self.joint is not None
            out.update(explained_rms=float(rms[0]) if one else rms.tolist(),
                       peak=float(peak[0]) if one else peak.tolist())
        return out

    def coef_from_parameters(self, parameters: dict, n: int) -> np.ndarray:
        missing = [lab for lab in self.term_labels(n) if lab not in parameters]
        if missing:
            raise RobustDrakeError(f"{self.name}: parameters lack {missing}")
        return np.asarray([float(parameters[lab]) for lab in self.term_labels(n)])

    def admissible(self, parameters, context=None):
        """The peak of f_e,j over the data's configurations (``context.configurations``) <= max
        |tau_j| the joint carried (every acting joint)."""
        if context is None or context.tau_max is None or context.configurations is None:
            return ""
        q = context.configurations
        js = [j for j, _ in self.layout(q.shape[1])]
        peak = np.max(np.abs(self.torque(self.coef_from_parameters(parameters, q.shape[1]), q)[:, js]), axis=0)
        lim = np.asarray(context.tau_max, float)[js]
        if np.all(peak <= lim + 1e-12):
            return ""
        return f"peak torque {np.round(peak, 4).tolist()} N m above max |tau| {np.round(lim, 4).tolist()} N m"

    def block(self, n, parameters, **kw):
        return ConfigurationDependentBlock(self, n, self.coef_from_parameters(parameters, n))

    @classmethod
    def candidates(cls, n_joints, diagnostics=None, robot=None, **context):
        """One candidate per joint where ``residual.configuration_dependence`` fired (rows
        ``test == "configuration_dependence"`` in ``diagnostics``), its basis without the terms in
        the span of that joint's gravity columns (``robot`` given: :func:`gravity_aliases`)."""
        joints = sorted({d["joint"] for d in diagnostics or [] if d.get("test") == "configuration_dependence"})
        prismatic, reg = _joint_kinds(robot, n_joints) if joints else ((), None)
        out = []
        for j in joints:
            terms = configuration_terms(n_joints, j, prismatic)
            if reg is not None:
                drop = set(gravity_aliases(reg, j, terms))
                terms = [t for t in terms if t not in drop]
            if terms:
                out.append(cls(joint=j, terms=",".join(terms)))
        return out


def _joint_kinds(robot, n: int):
    """(prismatic joint indices, regressor) of ``robot`` (((), None) without a robot)."""
    if robot is None:
        return (), None
    from robust_drake.regressor import InverseDynamicsRegressor

    reg = InverseDynamicsRegressor.from_robot(robot)  # gravity columns only: the URDF damping is moot
    joints = [reg.plant.get_joint(ji) for ji in reg.plant.GetJointIndices()
              if reg.plant.get_joint(ji).num_velocities() == 1]
    prismatic = tuple(jt.velocity_start() for jt in joints if "prismatic" in jt.type_name())
    return prismatic, (reg if reg.n == n else None)


def gravity_aliases(regressor, joint: int, terms, samples: int = 256, seed: int = 0) -> list[str]:
    """Terms of ``terms`` (tokens) that lie in the span of the rigid-body gravity columns of
    ``joint`` (and of the terms kept before them): Y_j(q, 0, 0) of the base regressor at
    ``samples`` random configurations (revolute angles uniform in [-pi, pi], prismatic positions
    in their limits or [-1, 1] m); a term whose least-squares residual on those columns is below
    ``regressor.RANK_TOL`` of its norm is an identity of the model (noise free), not a fit."""
    from robust_drake.regressor import RANK_TOL

    n = regressor.n
    rng = np.random.default_rng(seed)
    prismatic = {k for f, k in parse_terms(terms) if f in "lp"}
    Q = rng.uniform(-math.pi, math.pi, (samples, n))
    for k in prismatic:
        jt = [regressor.plant.get_joint(ji) for ji in regressor.plant.GetJointIndices()
              if regressor.plant.get_joint(ji).num_velocities() == 1][k]
        lo, hi = float(jt.position_lower_limits()[0]), float(jt.position_upper_limits()[0])
        lo, hi = (lo, hi) if np.isfinite(lo) and np.isfinite(hi) else (-1.0, 1.0)
        Q[:, k] = rng.uniform(lo, hi, samples)
    zero = np.zeros_like(Q)
    span = np.asarray(regressor.evaluate(Q, zero, zero), float)[:, joint, :]
    span = span[:, np.linalg.norm(span, axis=0) > 0]
    drop = []
    for tok in (terms.split(",") if isinstance(terms, str) else terms):
        phi = term_values(parse_terms([tok]), Q)
        if span.shape[1]:
            resid = phi - span @ np.linalg.lstsq(span, phi, rcond=None)[0]
        else:
            resid = phi
        if np.linalg.norm(resid) <= RANK_TOL * np.linalg.norm(phi):
            drop.append(tok)
        else:
            span = np.hstack([span, phi])
    return drop


class ConfigurationDependentBlock(LeafSystem):
    """Stateless block of :class:`ConfigurationDependent`: input ``state`` (2n), output
    ``generalized_force`` (n), zero except on the acting joint(s) j: -sum_i c_i phi_i(q) [N m]
    (eq. CD1).
    Its output depends on the state input only (no time, no torque)."""

    def __init__(self, effect: ConfigurationDependent, n: int, coef):
        super().__init__()
        self.n = n
        self.coef = np.asarray(coef, dtype=float).copy()
        if len(self.coef) != effect.num_coef(n):
            raise RobustDrakeError(f"{effect.name}: {effect.num_coef(n)} coefficients expected, got {len(self.coef)}")
        fun = {"s": math.sin, "c": math.cos, "l": float, "p": lambda x: x * x}
        terms = [(j, fun[f], k) for j, ts in effect.layout(n) for f, k in ts]
        self._fun = [(j, f, k, float(c)) for (j, f, k), c in zip(terms, self.coef)]
        self.set_name(f"effect_{effect.kind}_{'all' if effect.joint is None else effect.joint + 1}")
        self._state = self.DeclareVectorInputPort("state", 2 * n)
        self.DeclareVectorOutputPort("generalized_force", n, self._calc,
                                     prerequisites_of_calc={self.input_port_ticket(self._state.get_index())})

    def _calc(self, context, output):
        x = self._state.Eval(context)
        out = np.zeros(self.n)
        for j, f, k, c in self._fun:
            out[j] -= c * f(float(x[k]))
        output.SetFromVector(out)
