"""Independent dynamics references shared by the regressor tests: M(q) and dM/dq by AutoDiff
through Drake's CalcMassMatrix, and C(q, qd) from the Christoffel symbols of dM/dq."""

import numpy as np


def mass_matrix_and_derivative(ad_plant, ad_ctx, q):
    """M(q) and dM/dq (n, n, n) by AutoDiff through Drake's CalcMassMatrix
    (``ad_plant = plant.ToAutoDiffXd()``, ``ad_ctx`` its context)."""
    from pydrake.autodiffutils import InitializeAutoDiff

    ad_plant.SetPositions(ad_ctx, InitializeAutoDiff(q).ravel())
    Mad = ad_plant.CalcMassMatrix(ad_ctx)
    n = len(q)
    M = np.array([[Mad[i, j].value() for j in range(n)] for i in range(n)])
    dM = np.array([[Mad[i, j].derivatives() for j in range(n)] for i in range(n)])
    return M, dM


def christoffel_C(dM, qd):
    """C_ij = sum_k 1/2 (dM_ij/dq_k + dM_ik/dq_j - dM_jk/dq_i) qd_k."""
    c = 0.5 * (dM + np.transpose(dM, (0, 2, 1)) - np.transpose(dM, (2, 0, 1)))
    return c @ qd


def damped_siciliano_urdf(tmp_path, damping: float = 0.7):
    """Path of a copy of the Siciliano 2-link URDF whose joint2 has viscous joint damping [N m s/rad]."""
    from robust_drake.models import resolve_urdf

    src = resolve_urdf("siciliano_2link").read_text()
    damped = src.replace('<joint name="joint2" type="continuous">',
                         f'<joint name="joint2" type="continuous">\n    <dynamics damping="{damping:g}"/>')
    assert damped != src, "joint2 not found in the Siciliano URDF"
    path = tmp_path / "damped.urdf"
    path.write_text(damped)
    return path
