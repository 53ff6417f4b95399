"""Export an identified model as a URDF (+ a sidecar YAML) that other tools and Drake read.

What goes where (``to_urdf``):
- the URDF (a copy of the robot's URDF, everything else kept): every moving link's
  ``<inertial>`` from the repair's physically consistent fit (``IdentifiedModel.consistent``,
  ``identification/consistency.py``: pseudo-inertia >= 0 per link), written as the URDF wants
  it: mass [kg], centre of mass c = h / m [m] as ``<origin xyz>`` (rpy 0) and the rotational
  inertia about the centre of mass, I_c = I_o - m (|c|^2 1 - c c^T) [kg m^2], in the link frame
  (17 significant digits, so Drake reads back the same doubles to ~1e-16);
- reflected rotor inertias (the URDF's ``Ia_<joint>`` extras and a chosen ``rotor_inertia``
  effect) as ``drake:rotor_inertia`` = Ia / G^2 on the joint's actuator (``drake:gear_ratio`` G
  kept; a transmission is added where the joint has none);
- joint friction as ``<dynamics damping="fv" friction="fc">`` (N m s/rad, N m).  Drake applies
  the damping as joint damping and ignores ``friction`` with a warning (MultibodyPlant has no
  joint Coulomb friction); a negative fitted level cannot be a URDF damping or friction and is
  written as 0 (the sidecar keeps the fitted value);
- the sidecar ``<stem>.identified.yaml``: Coulomb and viscous levels, every effect a URDF cannot
  hold (kind, joint, parameters, column coefficients in the repair's sign convention), the
  estimator and data summary; :func:`read_export` reads the pair back (``IdentifiedModel.from_export``).

The library's regressor of the exported URDF (``load_regressor``) leaves the URDF's joint damping
out and fits one viscous level per joint, so the loaded model's ``viscous`` is the whole fitted
level (damping included): its prediction Y theta + fc sgn(qd) + fv qd + effects equals the
consistent model's.

Refused (one line, :class:`RobustDrakeError`): a model without a consistent fit (the repair ran
with ``--no-consistent`` or its SDP failed), and a body that is not physically valid (negative
mass, an inertia about the centre of mass that is not positive semi-definite or breaks the
triangle inequality beyond round-off).
"""

from __future__ import annotations

import copy
import os
import xml.etree.ElementTree as ET

import numpy as np

from robust_drake.errors import RobustDrakeError

DRAKE_NS = "http://drake.mit.edu"
SIDECAR_SUFFIX = ".identified.yaml"
#: the sidecar's format; /2 numbers the configuration_dependent terms' joints from 1 (model.MODEL_VERSION),
#: /1 sidecars (from 0) are read and renumbered
FORMAT = "robust_drake.identified_model/2"
FORMAT_V1 = "robust_drake.identified_model/1"
#: relative round-off allowed in the validity checks of an exported body (eigenvalues of I_c,
#: triangle inequality), relative to the body's largest principal moment
VALIDITY_RTOL = 1e-9


def _r(x) -> str:
    return repr(float(x))


def consistent_model(model):
    """The :class:`IdentifiedModel` with the consistent fit's base parameters, friction and effect
    coefficients (effect parameters recomputed from them); RobustDrakeError when it carries none.

    The SDP's bodies satisfy J >= 0 to the solver's round-off (C.1: the triangle inequality of
    link 1's central inertia broken by 6e-10 kg m^2, its pseudo-inertia eigenvalue -3e-10): a
    body within the acceptance of ``identification.consistency`` (1e-6 x max(1, |pi_i|)) gets the
    smallest isotropic addition to its central inertia that makes it a rigid body Drake accepts
    (``consistent["inflated"]`` [kg m^2] per link), and the base parameters are recomputed from
    those bodies (theta = K pi), so the URDF written and this model are the same arm.  Beyond
    that tolerance the model is refused."""
    from robust_drake.regressor import InverseDynamicsRegressor

    c = model.consistent
    if not c or "bodies" not in c or "base_values" not in c:
        raise RobustDrakeError(
            "the identified model carries no physically consistent fit (repair without --no-consistent; "
            "a model from a report of an older version: repair again); no URDF can hold it")
    reg = InverseDynamicsRegressor.from_robot(model.robot)
    names = list(reg.standard_names)
    pi = np.zeros(len(names))
    bodies, inflated = {}, {}
    for name, b in c["bodies"].items():
        if f"m_{name}" not in names:
            raise RobustDrakeError(f"the model's link {name!r} is not a moving link of {model.robot}: the model was "
                                   "identified on another URDF")
        m, com, I_c = body_inertial(b)
        scale = max(1.0, m, float(np.abs(m * com).max()), float(np.abs(b["inertia_origin"]).max()))
        I_c, delta = valid_inertia(name, m, I_c, 1e-6 * scale)
        if delta:
            inflated[name] = delta
        I_o = I_c + m * (np.dot(com, com) * np.eye(3) - np.outer(com, com))
        k = names.index(f"m_{name}")
        pi[k:k + 10] = [m, *(m * com), I_o[0, 0], I_o[1, 1], I_o[2, 2], I_o[0, 1], I_o[0, 2], I_o[1, 2]]
        bodies[name] = {"mass": m, "com": com.tolist(),
                        "inertia_origin": [float(I_o[0, 0]), float(I_o[1, 1]), float(I_o[2, 2]), float(I_o[0, 1]),
                                           float(I_o[0, 2]), float(I_o[1, 2])]}
    for key, val in (c.get("extras") or {}).items():
        if key in names:
            pi[names.index(key)] = float(val)
    theta = reg.base_from_standard(pi)
    given = np.asarray(c["base_values"], float)
    if theta.shape != given.shape or not np.allclose(theta, given, rtol=1e-6, atol=1e-6 * max(1.0, np.abs(given).max())):
        raise RobustDrakeError(f"the consistent bodies do not reproduce the model's base parameters on {model.robot} "
                               "(identified on another URDF?)")
    effs = []
    coefs = c.get("effect_coefficients") or [[] for _ in model.effects]
    for e, co in zip(model.effects, coefs):
        eff = e.effect(model.robot)
        params = _plain(eff.parameters(co))
        effs.append({"kind": e.kind, "joint": e.joint, "parameters": params, "coefficients": [float(x) for x in co]})
    cons = {**copy.deepcopy(c), "bodies": bodies, "base_values": theta.tolist(), "inflated": inflated}
    d = model.to_json()  # the same class, rebuilt from JSON (no import of model.py: it imports this module)
    d.update(base={"names": list(model.base_names), "values": theta.tolist(), "covariance": None},
             friction={"coulomb": list(map(float, c["coulomb"])), "viscous": list(map(float, c["viscous"]))},
             effects=effs, estimator=f"physically consistent ({c.get('solver', '?')}, from {model.estimator})",
             consistent=cons)
    return type(model).from_json(d)


def body_inertial(body: dict) -> tuple[float, np.ndarray, np.ndarray]:
    """(m [kg], c [m], I_c (3, 3) [kg m^2] about the centre of mass) of a consistent body
    ``{"mass", "com", "inertia_origin": [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] about the link origin}``."""
    m = float(body["mass"])
    c = np.asarray(body["com"], float)
    Ixx, Iyy, Izz, Ixy, Ixz, Iyz = (float(x) for x in body["inertia_origin"])
    I_o = np.array([[Ixx, Ixy, Ixz], [Ixy, Iyy, Iyz], [Ixz, Iyz, Izz]])
    I_c = I_o - m * (np.dot(c, c) * np.eye(3) - np.outer(c, c))
    return m, c, I_c


def valid_inertia(name: str, m: float, I_c: np.ndarray, tol: float) -> tuple[np.ndarray, float]:
    """(I_c', delta): I_c' = I_c + delta 1 with the smallest delta >= 0 that makes the principal
    moments >= 0 and satisfy the triangle inequality with a margin of 1e-12 of the largest;
    RobustDrakeError when the mass is not positive or delta would exceed ``tol`` [kg m^2]."""
    if not (np.isfinite(m) and m > 0) or not np.all(np.isfinite(I_c)):
        raise RobustDrakeError(f"no physically consistent body for link {name!r}: mass {m:.4g} kg; the "
                               "identified model cannot be written as a URDF")
    I_c = 0.5 * (I_c + I_c.T)
    a, b, cc = np.sort(np.linalg.eigvalsh(I_c))
    margin = 1e-12 * max(abs(cc), 1e-300)
    # adding delta to every moment raises a by delta and a + b - c by delta
    delta = max(0.0, -a + margin, (cc - a - b) + margin)
    if delta > tol:
        raise RobustDrakeError(f"no physically consistent body for link {name!r}: principal moments "
                               f"{[round(float(x), 8) for x in (a, b, cc)]} kg m^2 about its centre of mass are not a "
                               "rigid body's (>= 0, triangle inequality); the identified model cannot be written as a URDF")
    return (I_c + delta * np.eye(3), float(delta)) if delta > 0 else (I_c, 0.0)


def check_body(name: str, m: float, I_c: np.ndarray) -> None:
    """RobustDrakeError unless (m, I_c) is a physical rigid body (within VALIDITY_RTOL)."""
    ev = np.linalg.eigvalsh(0.5 * (I_c + I_c.T))
    valid_inertia(name, m, I_c, VALIDITY_RTOL * max(float(np.abs(ev).max()), 1e-300))


def _ns(tag: str) -> str:
    return f"{{{DRAKE_NS}}}{tag}"


def _set_inertial(link, m, c, I):
    for old in link.findall("inertial"):
        link.remove(old)
    inert = ET.Element("inertial")
    ET.SubElement(inert, "origin", xyz=" ".join(_r(x) for x in c), rpy="0 0 0")
    ET.SubElement(inert, "mass", value=_r(m))
    ET.SubElement(inert, "inertia", ixx=_r(I[0, 0]), iyy=_r(I[1, 1]), izz=_r(I[2, 2]),
                  ixy=_r(I[0, 1]), ixz=_r(I[0, 2]), iyz=_r(I[1, 2]))
    link.insert(0, inert)


def _actuator_of(root, joint_name):
    """(transmission, actuator) elements of the joint's transmission, created if absent."""
    for tr in root.findall("transmission"):
        j = tr.find("joint")
        if j is not None and j.get("name") == joint_name:
            act = tr.find("actuator")
            if act is None:
                act = ET.SubElement(tr, "actuator", name=f"motor_{joint_name}")
            return tr, act
    tr = ET.SubElement(root, "transmission", name=f"transmission_{joint_name}")
    ET.SubElement(tr, "type").text = "transmission_interface/SimpleTransmission"
    ET.SubElement(tr, "joint", name=joint_name)
    return tr, ET.SubElement(tr, "actuator", name=f"motor_{joint_name}")


def _gear_ratio(act) -> float:
    g = act.find(_ns("gear_ratio"))
    return 1.0 if g is None else float(g.get("value"))


def to_urdf(model, path) -> dict:
    """Write ``path`` (URDF) and ``<stem>.identified.yaml`` for ``model`` (module docstring);
    returns ``{"urdf": path, "sidecar": path, "effects_in_sidecar": [...], "notes": [...]}``."""
    import yaml

    from robust_drake.models import resolve_urdf

    path = str(path)
    if not path.lower().endswith(".urdf"):
        raise RobustDrakeError(f"the export is a URDF: give a file name ending in .urdf (got {path!r})")
    cm = consistent_model(model)
    c = cm.consistent
    bodies = {}
    for name, b in c["bodies"].items():
        m, com, I_c = body_inertial(b)
        check_body(name, m, I_c)
        bodies[name] = (m, com, I_c)
    ET.register_namespace("drake", DRAKE_NS)
    src = resolve_urdf(model.robot)
    tree = ET.parse(src)
    root = tree.getroot()
    links = {ln.get("name"): ln for ln in root.findall("link")}
    missing = [b for b in bodies if b not in links]
    if missing:
        raise RobustDrakeError(f"the model's links {missing} are not in {src}: the model was identified on another URDF")
    for name, (m, com, I_c) in bodies.items():
        _set_inertial(links[name], m, com, I_c)
    joints = {j.get("name"): j for j in root.findall("joint")}
    sidecar_effects = _write_rotor_inertias(root, joints, cm, c, src)
    damping, notes = _write_friction(joints, cm, src)
    root.insert(0, ET.Comment(
        f" exported by robust_drake from the identified model of {model.robot!r} ({cm.estimator}): link "
        "inertials of the physically consistent fit (inertia about the centre of mass), reflected rotor "
        "inertias as drake:rotor_inertia, joint friction as dynamics damping/friction (Drake ignores "
        f"'friction'); effects a URDF cannot hold: {os.path.basename(_sidecar(path))} "))
    os.makedirs(os.path.dirname(os.path.abspath(path)) or ".", exist_ok=True)
    tree.write(path, xml_declaration=True, encoding="utf-8")
    side = {
        "format": FORMAT, "urdf": os.path.basename(path), "robot": str(model.robot),
        "joint_names": list(model.joint_names), "estimator": cm.estimator,
        "friction": {"coulomb": [float(x) for x in cm.coulomb], "viscous": [float(x) for x in cm.viscous],
                     "viscous_in_urdf_damping": [float(x) for x in damping]},
        "effects": [{"kind": e.kind, "joint": e.joint, "parameters": _plain(e.parameters),
                     "coefficients": [float(x) for x in e.coefficients]} for e in sidecar_effects],
        "sign_convention": "tau = Y theta + fc sgn(qd) + fv qd + sum_k Phi_k c_k (identification/model.py)",
        "consistent": {"solver": c.get("solver"), "min_pseudo_inertia_eig": c.get("min_pseudo_inertia_eig")},
        "data": _plain(dict(model.data)), "notes": notes,
    }
    with open(_sidecar(path), "w") as fh:
        yaml.safe_dump(side, fh, sort_keys=False)
    return {"urdf": path, "sidecar": _sidecar(path), "effects_in_sidecar": [e.kind for e in sidecar_effects],
            "notes": notes}


def _write_rotor_inertias(root, joints, cm, c, src) -> list:
    """drake:rotor_inertia = Ia / G^2 from the URDF's Ia extras plus a chosen rotor_inertia
    effect; returns the effects left for the sidecar."""
    reflected = {k[3:]: float(v) for k, v in (c.get("extras") or {}).items() if k.startswith("Ia_")}
    sidecar_effects = []
    for e in cm.effects:
        if e.kind != "rotor_inertia":
            sidecar_effects.append(e)
            continue
        vals = e.parameters["reflected_inertia"]
        js = list(range(cm.n)) if e.joint is None else [e.joint]
        vals = list(vals) if isinstance(vals, (list, tuple)) else [vals] * len(js)
        for j, v in zip(js, vals):
            jn = cm.joint_names[j]
            reflected[jn] = reflected.get(jn, 0.0) + float(v)
    for jn, Ia in reflected.items():
        if jn not in joints:
            raise RobustDrakeError(f"rotor inertia of joint {jn!r}: no such joint in {src}")
        if Ia < 0:
            raise RobustDrakeError(f"no physically consistent model: reflected rotor inertia of joint {jn!r} is {Ia:.4g} "
                                   "kg m^2 < 0")
        _, act = _actuator_of(root, jn)
        G = _gear_ratio(act)
        el = act.find(_ns("rotor_inertia"))
        if el is None:
            el = ET.SubElement(act, _ns("rotor_inertia"))
        el.set("value", _r(Ia / (G * G)))
    return sidecar_effects


def _write_friction(joints, cm, src):
    """<dynamics damping friction> per joint (negative levels written as 0); (damping, notes)."""
    damping, notes = np.zeros(cm.n), []
    for j, jn in enumerate(cm.joint_names):
        if jn not in joints:
            raise RobustDrakeError(f"joint {jn!r} of the model is not in {src}")
        fv, fc = float(cm.viscous[j]), float(cm.coulomb[j])
        damping[j] = max(fv, 0.0)
        if fv < 0 or fc < 0:
            notes.append(f"joint {j + 1} ({jn}): fitted {'viscous' if fv < 0 else 'Coulomb'} level "
                         f"{fv if fv < 0 else fc:.4g} < 0 written as 0 in the URDF (kept in the sidecar)")
        for old in joints[jn].findall("dynamics"):
            joints[jn].remove(old)
        ET.SubElement(joints[jn], "dynamics", damping=_r(damping[j]), friction=_r(max(fc, 0.0)))
    return damping, notes


def _sidecar(urdf_path: str) -> str:
    stem = urdf_path[:-5] if urdf_path.lower().endswith(".urdf") else urdf_path
    return stem + SIDECAR_SUFFIX


def _plain(d):
    if isinstance(d, dict):
        return {str(k): _plain(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [_plain(v) for v in d]
    if isinstance(d, np.ndarray):
        return d.tolist()
    if isinstance(d, np.generic):
        return d.item()
    return d


def read_export(path) -> dict:
    """The ``IdentifiedModel`` JSON (``IdentifiedModel.to_json`` form) of an export, from the URDF
    or its sidecar: robot = the exported URDF (absolute path), base parameters = its regressor's
    values (rigid bodies, rotor inertias; the URDF's joint damping is in the viscous level, as
    :func:`load_regressor` fits it), friction and effects from the sidecar
    (module docstring).  ``IdentifiedModel.from_export(path)`` turns it into the model."""
    import yaml

    from robust_drake.identification.least_squares import load_regressor

    path = str(path)
    if path.endswith(SIDECAR_SUFFIX):
        side_path = path
        if not os.path.isfile(side_path):
            raise RobustDrakeError(f"sidecar {side_path} not found")
        urdf = os.path.join(os.path.dirname(path), str((yaml.safe_load(open(path)) or {}).get("urdf", "")))
    else:
        urdf, side_path = path, _sidecar(path)
    if not os.path.isfile(urdf):
        raise RobustDrakeError(f"exported URDF {urdf} not found")
    if not os.path.isfile(side_path):
        raise RobustDrakeError(f"{urdf} has no sidecar {os.path.basename(side_path)} (not written by "
                               "IdentifiedModel.to_urdf / repair --export-urdf)")
    side = yaml.safe_load(open(side_path))
    if not isinstance(side, dict) or side.get("format") not in (FORMAT, FORMAT_V1):
        raise RobustDrakeError(f"{side_path} is not an identified-model sidecar ({FORMAT})")
    urdf = os.path.abspath(urdf)
    # the library's regressor of a URDF (load_regressor) drops <dynamics damping> columns and fits
    # the level as fv_j: the model then carries the whole viscous level, as every other model does
    reg = load_regressor(urdf)
    fr = side["friction"]
    viscous = np.asarray(fr["viscous"], float)
    return {"robot": urdf, "joint_names": list(side["joint_names"]),
            "base": {"names": list(reg.base_names), "values": np.asarray(reg.base_parameters(), float).tolist(),
                     "covariance": None},
            "friction": {"coulomb": [float(x) for x in fr["coulomb"]], "viscous": viscous.tolist()},
            "effects": [{"kind": e["kind"], "joint": e["joint"], "parameters": dict(e["parameters"]),
                         "coefficients": list(e["coefficients"])} for e in side.get("effects") or []],
            "estimator": str(side.get("estimator", "exported")), "data": dict(side.get("data") or {}),
            "version": 1 if side["format"] == FORMAT_V1 else 2}
