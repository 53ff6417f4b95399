"""Plausibility checks of repair input that a per-file column check cannot see.

Each check returns warnings (strings) or raises :class:`~robust_drake.errors.DataError` /
:class:`~robust_drake.errors.RobustDrakeError` with one line naming the cause:

* :func:`check_distinct_files` -- one file given twice, or the same file as fit and validation
  data (compared by resolved path *and* SHA-256 of the content), is refused: the validation
  error would be a fit error.
* :func:`check_urdf_inertials` -- every ``<inertial>`` of a URDF has a finite mass > 0 and a
  physically valid rotational inertia (eigenvalues >= 0, triangle inequality), read with
  ``xml.etree`` before Drake sees the file (Drake replaces a zero or negative mass by 1 kg).
* :func:`prismatic_warnings` -- a prismatic joint's position column is taken as metres.
* :func:`torque_scale_check` -- physical consistency of units: the measured torque against the
  URDF's inverse dynamics (nominal parameters) plus per-joint friction and offset,
  ``tau_j ~ s * tau_URDF_j + fc_j sign(qd_j) + fv_j qd_j + c_j`` with one scale ``s`` pooled
  over all joints. A correct model of the right robot in SI units gives ``s`` near 1 (measured
  on the DFKI logs 2026-12-01: 0.48-1.37 per file for C.1, 0.61-0.89 for A.0, both torque columns); torques in mN m give
  ~1000, positions in degrees make the inertial and gravity terms meaningless (``s`` far from
  1 or no fit at all). Outside ``[SCALE_LOW, SCALE_HIGH]`` -> warning.
* :func:`sample_budget` -- effective samples per identified parameter (rule below).
"""

from __future__ import annotations

import hashlib
import math
import os
import xml.etree.ElementTree as ET

import numpy as np

from robust_drake.errors import DataError, RobustDrakeError

#: pooled torque scale outside this range -> units warning (see module docstring)
SCALE_LOW, SCALE_HIGH = 0.2, 5.0
#: the scaled URDF model + friction must explain at least this share of the torque variance
#: (measured on the DFKI logs: 0.66-0.98 per file, both torque columns)
MIN_EXPLAINED = 0.2
#: effective samples (N_eff = N * min(1, 2 f_c dt) per joint, data.n_effective) per
#: identified baseline parameter: below MIN_ROWS_PER_PARAM -> error, below WARN_ROWS_PER_PARAM
#: -> warning (the fit error then says little about the validation error)
MIN_ROWS_PER_PARAM = 5.0
WARN_ROWS_PER_PARAM = 20.0


def n_effective(data: "IdentData") -> float:
    """Effective (independent) samples per joint, N_eff = N min(1, 2 f_c dt): the low-pass at
    f_c [Hz] leaves about 2 f_c independent samples per second of data sampled every dt [s]."""
    fc = data.filter.cutoff_hz
    if fc is None:
        return float(data.N)
    return float(data.N) * min(1.0, 2.0 * fc * data.dt)


def _digest(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def check_distinct_files(fit_paths, validate_paths=None) -> None:
    """Refuse a file used twice (same resolved path or same content) among fit/validation files."""
    seen: dict[str, str] = {}
    for role, paths in (("fit", fit_paths or []), ("validation", validate_paths or [])):
        for p in paths:
            if not isinstance(p, (str, os.PathLike)) or not os.path.isfile(p):
                continue  # missing files are reported by the reader
            real = os.path.realpath(p)
            for key in (f"path:{real}", f"sha:{_digest(real)}"):
                if key in seen:
                    how = "the same file" if key.startswith("path") else "identical content"
                    raise DataError(
                        f"{p} ({role}) and {seen[key]} are {how}: "
                        + ("the validation error would be a fit error; validate on other runs "
                           "(or give no validation files to hold out the tail of every fit file)"
                           if role == "validation" or "(validation)" in seen[key]
                           else "a fit file given twice counts its samples twice; give each run once")
                    )
                seen[key] = f"{p} ({role})"


def check_urdf_inertials(urdf_path) -> None:
    """Every link's ``<inertial>``: finite mass > 0, inertia PSD with the triangle inequality."""
    path = os.fspath(urdf_path)
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise RobustDrakeError(f"{path}: cannot parse the URDF ({exc})") from exc
    for link in root.iter("link"):
        name = link.get("name", "?")
        inertial = link.find("inertial")
        if inertial is None:
            continue
        mass = inertial.find("mass")
        try:
            m = float(mass.get("value")) if mass is not None else math.nan
        except (TypeError, ValueError):
            m = math.nan
        if not (math.isfinite(m) and m > 0.0):
            raise RobustDrakeError(
                f"{path}: link {name!r} has mass {mass.get('value') if mass is not None else '(missing)'}: "
                "every <inertial> needs a finite mass > 0 (Drake would silently use 1 kg)"
            )
        el = inertial.find("inertia")
        if el is None:
            continue
        try:
            v = {k: float(el.get(k, "0")) for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")}
        except ValueError as exc:
            raise RobustDrakeError(f"{path}: link {name!r}: non-numeric inertia ({exc})") from exc
        if not all(math.isfinite(x) for x in v.values()):
            raise RobustDrakeError(f"{path}: link {name!r} has a non-finite inertia entry")
        inertia = np.array([[v["ixx"], v["ixy"], v["ixz"]], [v["ixy"], v["iyy"], v["iyz"]],
                            [v["ixz"], v["iyz"], v["izz"]]])
        ev = np.linalg.eigvalsh(inertia)
        tol = 1e-9 * max(1.0, float(np.abs(ev).max()))
        if ev.min() < -tol or ev.max() > ev.sum() - ev.max() + tol:
            raise RobustDrakeError(
                f"{path}: link {name!r} has a physically impossible rotational inertia "
                f"(principal moments {np.round(ev, 9).tolist()} kg m^2: each must be >= 0 and no "
                "larger than the sum of the other two)"
            )


def prismatic_warnings(plant) -> list[str]:
    """A warning per prismatic joint: its position column is read as metres, its torque as N."""
    from pydrake.multibody.tree import JointIndex

    out = []
    for i in range(plant.num_joints()):
        j = plant.get_joint(JointIndex(i))
        if j.type_name() == "prismatic":
            k = j.velocity_start() + 1
            out.append(f"joint {j.name()!r} is prismatic: position column {k} is taken as metres and "
                       f"torque column {k} as a force in N (if the log holds a rotation there, the "
                       "URDF does not match the robot)")
    return out


def torque_scale_check(data, regressor) -> tuple[dict, list[str]]:
    """Pooled scale of the measured torque against the URDF's inverse dynamics (module docstring).

    Returns ``({"scale", "explained"}, warnings)``. Joints whose torque is constant (unpowered)
    are left out.
    """
    tn = regressor.torque(data.q, data.qd, data.qdd)
    N, n = data.tau.shape
    powered = [j for j in range(n) if np.ptp(data.tau[:, j]) > 0]
    if not powered:
        return {"scale": None, "explained": None}, []
    rows, cols = len(powered) * N, 1 + 3 * len(powered)
    A = np.zeros((rows, cols))
    b = np.zeros(rows)
    for k, j in enumerate(powered):
        r = slice(k * N, (k + 1) * N)
        A[r, 0] = tn[:, j]
        A[r, 1 + 3 * k] = np.sign(data.qd[:, j])
        A[r, 2 + 3 * k] = data.qd[:, j]
        A[r, 3 + 3 * k] = 1.0
        b[r] = data.tau[:, j]
    coef, *_ = np.linalg.lstsq(A, b, rcond=None)
    s = float(coef[0])
    resid = b - A @ coef
    centred = np.concatenate([data.tau[:, j] - data.tau[:, j].mean() for j in powered])
    explained = float(1.0 - resid @ resid / max(centred @ centred, 1e-300))
    warns = []
    if s < 0 and explained >= MIN_EXPLAINED:
        warns.append(f"units: the measured torque is {s:.3g} x the URDF model's inverse dynamics (expected near 1): "
                     "a negative ratio is a sign flip: the torque's sign (or the positions') is the opposite of the "
                     "URDF's joint axes (flip the torque columns, or q and qd)")
    elif not SCALE_LOW <= s <= SCALE_HIGH:
        if s > SCALE_HIGH:
            cause = (f"torques look ~{s:.3g} times too large (in mN m or N mm, i.e. x1000?)" if s > 100
                     else "torques in other units than N m, or the wrong robot/URDF?")
        else:
            cause = ("positions in degrees (the model's accelerations and gravity then do not match "
                     "the torque), torques scaled down, q and tau columns swapped, or the wrong robot/URDF?")
        warns.append(f"units: the measured torque is {s:.3g} x the URDF model's inverse dynamics "
                     f"(expected near 1; accepted [{SCALE_LOW:g}, {SCALE_HIGH:g}]): {cause}")
    elif explained < MIN_EXPLAINED:
        warns.append(f"units: the URDF model (scaled, with friction) explains only {explained:.0%} of the "
                     "torque variance: positions in degrees, wrong joint order (swapped columns), or the wrong robot/URDF?")
    return {"scale": s, "explained": explained}, warns


#: pooled gain of the validation torque against the fitted model's prediction outside this band ->
#: warning (:func:`transfer_check`). Measured on the DFKI logs (fit on one file, validate on
#: another, both torque columns): 0.54-1.65 for every pair whose fit file excites both joints;
#: 0.09-0.46 when the validation file is the other DFKI arm's (a model of C.1 on A.0 logs and back)
TRANSFER_LOW, TRANSFER_HIGH = 0.5, 2.0


def transfer_check(tau: np.ndarray, predicted: np.ndarray, fit_rms, label: str = "validation files") -> list[str]:
    """Plausibility of validation data against the model fitted on the fit data: one pooled gain
    ``s`` (per-joint offsets free) of the measured torque against the prediction, ``tau_j ~ s
    pred_j + c_j``, and the share of the torque variance it explains. The same arm in the same
    units gives ``s`` near 1; another robot, other units or swapped columns in the validation
    files land outside [TRANSFER_LOW, TRANSFER_HIGH] or explain < MIN_EXPLAINED (warning).
    Returns warnings (one line)."""
    tau, predicted = np.asarray(tau, float), np.asarray(predicted, float)
    N, n = tau.shape
    powered = [j for j in range(n) if np.ptp(tau[:, j]) > 0 and np.ptp(predicted[:, j]) > 0]
    if not powered or N < 2:
        return []
    A = np.zeros((len(powered) * N, 1 + len(powered)))
    b = np.zeros(len(powered) * N)
    for k, j in enumerate(powered):
        r = slice(k * N, (k + 1) * N)
        A[r, 0], A[r, 1 + k], b[r] = predicted[:, j], 1.0, tau[:, j]
    coef, *_ = np.linalg.lstsq(A, b, rcond=None)
    s = float(coef[0])
    resid = b - A @ coef
    centred = np.concatenate([tau[:, j] - tau[:, j].mean() for j in powered])
    explained = float(1.0 - resid @ resid / max(centred @ centred, 1e-300))
    if TRANSFER_LOW <= s <= TRANSFER_HIGH and explained >= MIN_EXPLAINED:
        return []
    val_rms = np.sqrt(np.mean((tau - predicted) ** 2, axis=0))
    ratio = val_rms / np.maximum(np.asarray(fit_rms, float), 1e-300)
    return [f"{label}: the model fitted on the fit files predicts their torque with a pooled gain {s:.3g} "
            f"(expected near 1; accepted [{TRANSFER_LOW:g}, {TRANSFER_HIGH:g}]) explaining {explained:.0%} of its "
            f"variance; residual {np.round(ratio, 1).tolist()} x the fit's: a log of another robot or setup, other "
            "units or swapped columns, or fit data that do not excite what the validation motion does? The "
            "validation errors (and the verdict) then say little about this arm"]


def sample_budget(data, n_params: int) -> tuple[float, str | None]:
    """Effective rows per parameter: ``n * N_eff / p`` (N_eff = N min(1, 2 f_c dt)).

    Below :data:`MIN_ROWS_PER_PARAM` -> DataError (the fit can match noise exactly and its error
    says nothing); below :data:`WARN_ROWS_PER_PARAM` -> a warning string.
    """
    rows = data.n * n_effective(data)
    per = rows / max(n_params, 1)
    rule = (f"{data.N} samples x {data.n} joints at {data.dt * 1e3:.3g} ms, filtered at "
            f"{data.filter.cutoff_hz} Hz = {rows:.0f} independent rows for {n_params} parameters "
            f"({per:.1f} per parameter")
    if per < MIN_ROWS_PER_PARAM:
        raise DataError(f"too little fit data: {rule}; need >= {MIN_ROWS_PER_PARAM:g}): record longer runs "
                        "or give more files")
    if per < WARN_ROWS_PER_PARAM:
        return per, f"little fit data: {rule}; >= {WARN_ROWS_PER_PARAM:g} recommended): the fit error understates the real one"
    return per, None
