"""Drive and structural flexibility as blocks added to any rigid arm.

Two elastic elements, both linear, both acting on the rigid plant through its
``applied_generalized_force`` port (the "plant-side effect" convention of BUILD_NOTES):

**Two-mass drive** (one per joint; Spong's flexible-joint model, Spong & Vidyasagar ch. 6,
with the rotor's gyroscopic coupling to the other links neglected)::

    J_m theta_m'' = u - k (theta_m - q) - d (theta_m' - q')          (F1)
    tau_link      =     k (theta_m - q) + d (theta_m' - q')          (F2)

theta_m [rad] rotor angle, q [rad] link angle, J_m [kg m^2] rotor inertia, k [N m/rad] torsional
stiffness of shaft + hub + coupling, d [N m s/rad] its damping, u [N m] the motor torque (the
saturated controller output). The rotor is no longer part of the plant: with k -> infinity the
arm behaves as the rigid arm with J_m added to each diagonal entry of M(q). With the link held
still the rotor rings at sqrt(k / J_m); with both free (single joint, link inertia J_l) the
drive's anti-phase mode has

    omega_F = sqrt(k (1/J_m + 1/J_l))                                (F3)

**Structural mode of a link** (a lightly damped modal appendage): a share J_s [kg m^2] of the
link's inertia about the joint axis sits on the link through an elastic element. With
phi [rad] its angle and eta = phi - q the modal coordinate (deflection angle)::

    J_s phi'' = -k_s eta - c_s eta'      <=>   eta'' + 2 zeta w eta' + w^2 eta = -q''      (F4)
    tau_link  =  k_s eta + c_s eta'                                   (F5)

with w = sqrt(k_s / J_s) [rad/s] (clamped-hub natural frequency) and zeta = c_s / (2 sqrt(k_s J_s)).
The coupling to the rest of the arm is the link's acceleration (F4), the reaction on the joint a
torque disturbance (F5); a joint encoder does not see eta (it is a bending of the link beyond the
joint), the tool does (``deflection`` output). Writing it in phi keeps the block free of q''
(no algebraic loop with the plant).

Both are LTI, so each block is a Drake ``LinearSystem`` (evaluated in C++: no Python
callback per integrator stage) wrapped in a small Diagram that exports named ports:

- :func:`make_two_mass_drive`: inputs ``u`` (n), ``state`` (2n plant state); outputs
  ``generalized_force`` (n, F2) and ``motor_state`` (2n, [theta_m, theta_m'], the input of a
  motor-side encoder, same layout as the plant state).
- :func:`make_structural_mode`: input ``state`` (2n); outputs ``generalized_force`` (n, F5 on the
  chosen joints, zero elsewhere) and ``deflection`` (one eta per mode).

:class:`FlexibilityConfig` is the option of ``ClosedLoopConfig.flexibility``;
:func:`add_flexibility` wires it into a closed loop; :func:`d2r2_flexibility` gives the D2R2's
physically estimated parameters (reasoning in BUILD_NOTES.md, "Flexible D2R2").
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from robust_drake.description import describe, packaged_description
from robust_drake.errors import RobustDrakeError


# ------------------------------------------------------------------------------ pure math
def _vec(x, n, what, positive=True):
    a = np.asarray(x, dtype=float)
    a = np.full(n, float(a)) if a.ndim == 0 else a
    if a.shape != (n,) or not np.all(np.isfinite(a)) or (np.any(a <= 0) if positive else np.any(a < 0)):
        kind = "positive" if positive else "non-negative"
        raise RobustDrakeError(f"{what} must be {n} {kind} numbers (got {x!r})")
    return a


def two_mass_drive_matrices(J_m, k, d):
    """(A, B, C, D) of eqs. F1-F2 for n joints (n = len(J_m)).

    State x = [theta_m, theta_m'] (2n); input w = [u, q, q'] (3n);
    output y = [tau_link (n), theta_m (n), theta_m' (n)].
    """
    J_m = np.asarray(J_m, dtype=float)
    n = J_m.size
    k = np.broadcast_to(np.asarray(k, dtype=float), (n,))
    d = np.broadcast_to(np.asarray(d, dtype=float), (n,))
    I, Z = np.eye(n), np.zeros((n, n))
    Ji = np.diag(1.0 / J_m)
    K, D = np.diag(k), np.diag(d)
    A = np.block([[Z, I], [-Ji @ K, -Ji @ D]])
    B = np.block([[Z, Z, Z], [Ji, Ji @ K, Ji @ D]])
    C = np.block([[K, D], [I, Z], [Z, I]])
    Dm = np.block([[Z, -K, -D], [Z, Z, Z], [Z, Z, Z]])
    return A, B, C, Dm


def structural_mode_matrices(n, joints, J_s, omega, zeta):
    """(A, B, C, D) of eqs. F4-F5 for modes on ``joints`` of an n-joint arm.

    State x = [phi (m), phi' (m)] (m = len(joints)); input w = [q, q'] (2n);
    output y = [tau (n; F5 on the mode's joint, summed if two modes share one), eta (m)].
    """
    joints = list(joints)
    m = len(joints)
    J_s = np.asarray(J_s, dtype=float)
    k_s, c_s = mode_stiffness_damping(J_s, np.asarray(omega, dtype=float), np.asarray(zeta, dtype=float))
    S = np.zeros((m, n))  # selects each mode's joint
    for i, j in enumerate(joints):
        S[i, j] = 1.0
    I, Z = np.eye(m), np.zeros((m, m))
    Ji = np.diag(1.0 / J_s)
    K, Cd = np.diag(k_s), np.diag(c_s)
    Zmn = np.zeros((m, n))
    A = np.block([[Z, I], [-Ji @ K, -Ji @ Cd]])
    B = np.block([[Zmn, Zmn], [Ji @ K @ S, Ji @ Cd @ S]])
    C = np.block([[S.T @ K, S.T @ Cd], [I, Z]])
    D = np.block([[-S.T @ K @ S, -S.T @ Cd @ S], [-S, np.zeros((m, n))]])
    return A, B, C, D


def mode_stiffness_damping(J_s, omega, zeta):
    """k_s = J_s w^2 [N m/rad], c_s = 2 zeta w J_s [N m s/rad] (eq. F4)."""
    return J_s * omega ** 2, 2.0 * zeta * omega * J_s


def drive_damping(k, J_m, J_l, zeta):
    """d giving the drive's mode (F3) the damping ratio zeta: d = 2 zeta sqrt(k J_red),
    J_red = J_m J_l / (J_m + J_l) (the mode's reduced inertia)."""
    J_red = J_m * J_l / (J_m + J_l)
    return 2.0 * zeta * np.sqrt(k * J_red)


def drive_frequency(k, J_m, J_l):
    """Eq. F3: omega_F = sqrt(k (1/J_m + 1/J_l)) [rad/s], rotor and link both free."""
    return np.sqrt(np.asarray(k, dtype=float) * (1.0 / np.asarray(J_m, dtype=float) + 1.0 / np.asarray(J_l, dtype=float)))


# ------------------------------------------------------------------------------ configuration
@dataclass
class StructuralMode:
    """One lightly damped structural mode on ``joint`` (0-based): modal inertia J_s [kg m^2]
    about the joint axis, clamped natural frequency ``omega`` [rad/s], damping ratio ``zeta``."""

    joint: int
    J_s: float
    omega: float
    zeta: float


@dataclass
class FlexibilityConfig:
    """Option ``ClosedLoopConfig.flexibility``.

    ``J_m``, ``k``, ``d``: per-joint two-mass drive (eqs. F1-F2), or ``J_m=None`` for rigid
    drives. ``modes``: structural modes (eqs. F4-F5). ``encoder``: ``"motor"`` (the encoder reads
    theta_m, as the D2R2's motor-integrated encoders do) or ``"link"`` (reads q).
    ``theta_decrement``: D2R2 only, eq. 14 parameters taken out of the rigid plant because the
    rotors / modal inertias now live in the flexible blocks (so the rigid limit keeps table 8/9
    inertias); None leaves the plant as it is (the blocks then add their inertia).
    ``max_step``: integrator step bound [s]; None = 0.25 / (fastest mode's frequency) (explicit
    RK2 is unstable on an undamped oscillator, growth 1 + (w h)^4 / 8 per step).
    """

    J_m: list | None = None
    k: list | None = None
    d: list | None = None
    modes: list = field(default_factory=list)
    encoder: str = "motor"
    theta_decrement: list | None = None
    max_step: float | None = None
    link_inertia: list | None = None  # J_l per joint used only for the step bound / reports

    def validate(self, n: int) -> None:
        if self.encoder not in ("motor", "link"):
            raise RobustDrakeError(f"flexibility encoder must be 'motor' or 'link' (got {self.encoder!r})")
        if self.J_m is not None:
            _vec(self.J_m, n, "rotor inertia J_m")
            _vec(self.k, n, "drive stiffness k")
            _vec(self.d if self.d is not None else 0.0, n, "drive damping d", positive=False)
        elif self.encoder == "motor":
            raise RobustDrakeError("a motor-side encoder needs a two-mass drive (J_m, k)")
        for mo in self.modes:
            mo = _mode(mo)
            if not (isinstance(mo.joint, int) and 0 <= mo.joint < n):
                raise RobustDrakeError(f"structural mode joint must be in 0..{n - 1} (got {mo.joint!r})")
            if not (mo.J_s > 0 and mo.omega > 0 and mo.zeta >= 0):
                raise RobustDrakeError(f"structural mode needs J_s > 0, omega > 0, zeta >= 0 (got {mo})")

    def fastest(self) -> float:
        """Highest natural frequency [rad/s] (drive: rotor against the link, F3; link inertia
        ``link_inertia`` if given, else the rotor alone against a clamped link)."""
        w = [0.0]
        if self.J_m is not None:
            J_m = np.asarray(self.J_m, float)
            J_l = np.asarray(self.link_inertia, float) if self.link_inertia is not None else np.full_like(J_m, np.inf)
            w.append(float(np.max(drive_frequency(self.k, J_m, J_l))))
        w += [_mode(m).omega for m in self.modes]
        return max(w)

    def integrator_step(self) -> float:
        if self.max_step is not None:
            return float(self.max_step)
        w = self.fastest()
        return 0.25 / w if w > 0 else math.inf

    def to_dict(self) -> dict:
        d = asdict(self)
        d["modes"] = [asdict(_mode(m)) for m in self.modes]
        return d


def _mode(m) -> StructuralMode:
    return m if isinstance(m, StructuralMode) else StructuralMode(**dict(m))


def as_flexibility(x) -> FlexibilityConfig | None:
    """Accept a FlexibilityConfig, a dict of its fields, or None."""
    if x is None or isinstance(x, FlexibilityConfig):
        return x
    if isinstance(x, dict):
        return FlexibilityConfig(**x)
    raise RobustDrakeError(f"flexibility must be a FlexibilityConfig, a dict or None (got {type(x).__name__})")


# ------------------------------------------------------------------------------ D2R2 parameters
#: Physical estimates for the D2R2 (robots/d2r2.yaml ``flexibility``, reasons in BUILD_NOTES.md
#: "Flexible D2R2"; never fitted to the tables).  Module names kept for readers and tests.
_D2R2 = packaged_description("d2r2")
D2R2_ROTOR_INERTIA = _D2R2.flexibility["rotor_inertia"]  # kg m^2
D2R2_DRIVE_STIFFNESS = _D2R2.flexibility["drive_stiffness"]  # N m/rad
D2R2_DRIVE_ZETA = _D2R2.flexibility["drive_zeta"]
D2R2_LINK2_EI = _D2R2.flexibility["last_link_EI"]  # N m^2
D2R2_LINK2_BEAM_MASS = _D2R2.flexibility["last_link_beam_mass"]  # kg
D2R2_PAYLOAD_IP = _D2R2.flexibility["payload_inertia"]  # kg m^2
D2R2_MODE_ZETA = _D2R2.flexibility["mode_zeta"]
D2R2_L2 = _D2R2.link_lengths[1]  # m


def d2r2_flexibility(load: str = "none", encoder: str = "motor", drive: bool = True, mode: bool = True,
                     robot="d2r2") -> FlexibilityConfig:
    """Two-mass drives on both joints + the first bending mode of link 2 (F1-F5), with the
    numbers of ``robot``'s description (``flexibility``, ``parameter_sets`` unloaded/loaded of
    JS eq. 14, ``link_lengths``): the D2R2's by default, or any 2-link arm described the same way.

    Link-2 bending: cantilever stiffness at the hub k_s = 3 EI / l2; modal inertia J_s = 0.24 m_beam
    l2^2 (Rayleigh's tip-mass equivalent, expressed as inertia about the joint) plus, loaded, the
    payload's own rotational inertia (its m d^2 stays in the rigid link, see BUILD_NOTES).
    The rigid plant gives up J_m1 from theta1 and J_m2 + J_s from theta2 (eq. 14), so the rigid
    limit keeps the table 8/9 inertias on the diagonal.
    """
    desc = describe(robot)
    f = desc.flexibility
    if f is None or desc.n != 2 or not {"unloaded", "loaded"} <= set(desc.parameter_sets):
        raise RobustDrakeError(f"robot {desc.name!r}: the flexible model needs a 2-link description with "
                               "'flexibility' and JS eq. 14 parameter_sets unloaded/loaded (the D2R2 has them)")
    J_m = list(f["rotor_inertia"]) if drive else None
    k = list(f["drive_stiffness"]) if drive else None
    modes = []
    dec = np.zeros(3)
    theta = desc.parameter_sets["unloaded" if load == "none" else "loaded"]  # tables 8/9: d22 = theta2
    L2 = desc.link_lengths[1]
    J_s = 0.24 * f["last_link_beam_mass"] * L2 ** 2 + (f["payload_inertia"] if load != "none" else 0.0)
    if mode:
        k_s = 3.0 * f["last_link_EI"] / L2
        modes.append(StructuralMode(joint=1, J_s=J_s, omega=math.sqrt(k_s / J_s), zeta=f["mode_zeta"]))
        dec[1] += J_s
    d = None
    J_l = None
    if drive:
        # link inertias the rotors see (joint 1: d11 at q2 = 90 deg, theta1 + theta2; joint 2: d22)
        J_l = [theta[0] + theta[1] - J_m[0] - J_m[1] - (J_s if mode else 0.0), theta[1] - J_m[1] - (J_s if mode else 0.0)]
        d = [float(x) for x in drive_damping(np.asarray(k), np.asarray(J_m), np.asarray(J_l), f["drive_zeta"])]
        dec[0] += J_m[0]
        dec[1] += J_m[1]
    return FlexibilityConfig(J_m=J_m, k=k, d=d, modes=modes, encoder=encoder if drive else "link",
                             theta_decrement=dec.tolist(), link_inertia=J_l)


# ------------------------------------------------------------------------------ Drake blocks
def _wrap(linear, inputs, outputs, name):
    """Diagram around a LinearSystem with named input/output ports (Multiplexer/Demultiplexer)."""
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import Demultiplexer, Multiplexer

    b = DiagramBuilder()
    sys = b.AddSystem(linear)
    mux = b.AddSystem(Multiplexer([s for _, s in inputs]))
    b.Connect(mux.get_output_port(0), sys.get_input_port(0))
    for i, (nm, _) in enumerate(inputs):
        b.ExportInput(mux.get_input_port(i), nm)
    demux = b.AddSystem(Demultiplexer([s for _, s in outputs]))
    b.Connect(sys.get_output_port(0), demux.get_input_port(0))
    for i, (nm, _) in enumerate(outputs):
        b.ExportOutput(demux.get_output_port(i), nm)
    diagram = b.Build()
    diagram.set_name(name)
    diagram.linear = sys
    return diagram


def make_two_mass_drive(J_m, k, d=0.0):
    """Eqs. F1-F2 as a block: inputs ``u`` (n), ``state`` (2n); outputs ``generalized_force``
    (n) and ``motor_state`` (2n). Its continuous state is [theta_m, theta_m'] (set it with
    :func:`set_drive_state`; zeros by default)."""
    from pydrake.systems.primitives import LinearSystem

    J_m = np.atleast_1d(np.asarray(J_m, dtype=float))
    n = J_m.size
    J_m = _vec(J_m, n, "rotor inertia J_m")
    k = _vec(k, n, "drive stiffness k")
    d = _vec(d, n, "drive damping d", positive=False)
    A, B, C, D = two_mass_drive_matrices(J_m, k, d)
    return _wrap(LinearSystem(A, B, C, D), [("u", n), ("state", 2 * n)],
                 [("generalized_force", n), ("motor_state", 2 * n)], "two_mass_drive")


def make_structural_mode(n, modes):
    """Eqs. F4-F5 for ``modes`` (list of :class:`StructuralMode`): input ``state`` (2n);
    outputs ``generalized_force`` (n) and ``deflection`` (eta, one per mode). State [phi, phi']
    (set with :func:`set_mode_state`)."""
    from pydrake.systems.primitives import LinearSystem

    modes = [_mode(m) for m in modes]
    if not modes:
        raise RobustDrakeError("make_structural_mode needs at least one mode")
    A, B, C, D = structural_mode_matrices(n, [m.joint for m in modes], [m.J_s for m in modes],
                                          [m.omega for m in modes], [m.zeta for m in modes])
    return _wrap(LinearSystem(A, B, C, D), [("state", 2 * n)],
                 [("generalized_force", n), ("deflection", len(modes))], "structural_mode")


def set_drive_state(block, root_context, theta_m, theta_m_dot=None):
    ctx = block.linear.GetMyMutableContextFromRoot(root_context)
    th = np.asarray(theta_m, dtype=float)
    thd = np.zeros_like(th) if theta_m_dot is None else np.asarray(theta_m_dot, dtype=float)
    ctx.SetContinuousState(np.concatenate([th, thd]))


def set_mode_state(block, root_context, phi, phi_dot=None):
    set_drive_state(block, root_context, phi, phi_dot)


class FlexibilityWiring:
    """What :func:`add_flexibility` added: ``encoder_state`` (port for the encoder's ``state``
    input), :meth:`forces` (connect the saturated command, return the force ports),
    :meth:`initialize` (rotor at the link angle, modes undeflected, plant theta decrement)."""

    def __init__(self, builder, plant, cfg: FlexibilityConfig, n: int):
        cfg.validate(n)
        self.cfg, self.n, self.plant = cfg, n, plant
        state = plant.get_state_output_port()
        self.drive = self.mode = None
        if cfg.J_m is not None:
            self.drive = builder.AddSystem(make_two_mass_drive(cfg.J_m, cfg.k, cfg.d if cfg.d is not None else 0.0))
            builder.Connect(state, self.drive.GetInputPort("state"))
        if cfg.modes:
            self.mode = builder.AddSystem(make_structural_mode(n, cfg.modes))
            builder.Connect(state, self.mode.GetInputPort("state"))
        self.encoder_state = self.drive.GetOutputPort("motor_state") if cfg.encoder == "motor" else state

    def forces(self, builder, tau) -> list:
        out = []
        if self.drive is not None:
            builder.Connect(tau, self.drive.GetInputPort("u"))
            out.append(self.drive.GetOutputPort("generalized_force"))
        else:
            out.append(tau)
        if self.mode is not None:
            out.append(self.mode.GetOutputPort("generalized_force"))
        return out

    def initialize(self, root_context, q0) -> None:
        """Call after the plant's state and parameters are set (true_theta, plant_setup)."""
        if self.cfg.theta_decrement is not None and any(self.cfg.theta_decrement):
            from robust_drake.models import set_d2r2_theta

            pc = self.plant.GetMyMutableContextFromRoot(root_context)
            q_now = self.plant.GetPositions(pc).copy()
            self.plant.SetPositions(pc, np.zeros(self.n))
            M = self.plant.CalcMassMatrix(pc)  # eq. 14 at q2 = 0: d22 = th2, d12 = th2 + th3
            self.plant.SetPositions(pc, q_now)
            theta = np.array([M[0, 0] - 2 * M[0, 1] + M[1, 1], M[1, 1], M[0, 1] - M[1, 1]])
            set_d2r2_theta(self.plant, pc, theta - np.asarray(self.cfg.theta_decrement, dtype=float))
        q0 = np.asarray(q0, dtype=float)
        if self.drive is not None:
            set_drive_state(self.drive, root_context, q0)
        if self.mode is not None:
            set_mode_state(self.mode, root_context, [q0[_mode(m).joint] for m in self.cfg.modes])


def add_flexibility(builder, plant, cfg, n: int) -> FlexibilityWiring:
    """Add the blocks of ``cfg`` (a :class:`FlexibilityConfig` or dict) to ``builder``."""
    return FlexibilityWiring(builder, plant, as_flexibility(cfg), n)
