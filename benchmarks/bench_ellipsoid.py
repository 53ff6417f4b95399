"""Confidence-ellipsoid SDP (CI sections 3-5): setup and solve times per sample count, per
solver and backend, the full (dense null-space) and the chordal formulations side by side.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_ellipsoid.py [--samples 5,20,100,1000] [--full 5,8]

Prints one row per run: samples, formulation, backend/solver, LMI sizes, variables, setup and
solve seconds, trace(P), certificate (inside/tested, max radius), and the chordal/full trace
ratio where both ran (the conservatism of the head-only multiplier), and the closed-form
``energy`` bound (no solver) with its trace ratio to the chordal SDP where both ran.

    PYTHONPATH=. python benchmarks/bench_ellipsoid.py --samples 5,20,100,300,1000,3000 --runs drake:clarabel \
        --chordal-max 1000        # the energy-vs-chordal table of BUILD_NOTES

``--relax 20:10,15,19`` measures the idea of constraint generation over samples: the optimal trace when
only k of the n samples keep their uncertainty (their LMIs; the others' deltas fixed at 0, a relaxation),
as a ratio to the full SDP.

CSDP is not in the default runs: it works on a dense Schur complement of the program's (doubled: free
variables become two slacks) variables, ~2.5 (2 nv)^2 doubles (measured 19-21 GB at 200 samples, nv =
16k, killed by the kernel). Asked for with ``--runs ...,drake:csdp`` it runs only where that estimate is
below ``--csdp-gb`` (default 2 GB).
"""

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from robust_drake.errors import RobustDrakeError  # noqa: E402
from robust_drake.experiments.calafiore import simulate_identification  # noqa: E402
from robust_drake.uncertainty.ellipsoid import solve_ellipsoid  # noqa: E402
from robust_drake.uncertainty.regression import CI_BOUNDS, build_uncertainty_model  # noqa: E402
from robust_drake.regressor import imi_scara_regressor  # noqa: E402


def csdp_gb(model, form) -> float:
    """CSDP's memory estimate [GB] for this program: 2.5 dense (2 nv)^2 matrices of doubles."""
    from robust_drake.uncertainty import ellipsoid as E

    scaled, scl = E._scaled_model(model)
    w = np.ones(model.n_params)
    data = E.build_chordal_sdp(scaled, w) if form == "chordal" else E.build_full_sdp(scaled, w)
    return 2.5 * (2 * data.nv) ** 2 * 8 / 1e9


def relaxation(n: int, ks: list) -> None:
    """Optimal trace with only k of the n samples' uncertainties (their chordal LMIs) kept, the other
    samples' deltas fixed at 0: the relaxation that constraint generation over samples would start
    from. Ratio 1 would mean the left-out samples' LMIs are not binding."""
    from robust_drake.uncertainty.regression import UncertaintyModel

    data = simulate_identification(n, seed=0)
    model = build_uncertainty_model(imi_scara_regressor, data["q"], data["qd"], data["qdd"], data["tau"], CI_BOUNDS)
    full = solve_ellipsoid(model, backend="direct", certify_draws=0).trace
    print(f"n = {n}: full chordal SDP trace {full:.6g}")
    rng = np.random.default_rng(0)
    for k in ks:
        keep = rng.choice(n, k, replace=False)
        coeffs = np.zeros_like(model.coeffs)
        coeffs[keep] = model.coeffs[keep]
        sub = UncertaintyModel(model.D0, model.tau0, coeffs, model.scalar_names, model.delta_max)
        tr = solve_ellipsoid(sub, backend="direct", certify_draws=0).trace
        print(f"  {k:>5} of {n} samples' LMIs: trace {tr:.6g}, ratio {tr / full:.4f}", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", default="5,10,20,50,100,200,500,1000")
    ap.add_argument("--full", default="5", help="sample counts for the dense full formulation")
    ap.add_argument("--runs", default="drake:clarabel,direct:clarabel,cvxpy:clarabel,drake:scs")
    ap.add_argument("--csdp-gb", type=float, default=2.0,
                    help="skip CSDP where its estimated memory 2.5 (2 nv)^2 doubles exceeds this [GB]")
    ap.add_argument("--max-seconds", type=float, default=120.0, help="skip a backend after a slower run")
    ap.add_argument("--draws", type=int, default=1000)
    ap.add_argument("--chordal-max", type=int, default=100000, help="largest sample count for the chordal SDP")
    ap.add_argument("--no-energy", action="store_true", help="skip the closed-form energy bound")
    ap.add_argument("--relax", default="", help="n:k1,k2,..: relaxation with k of n samples' LMIs")
    a = ap.parse_args()
    if a.relax:
        n, ks = a.relax.split(":")
        relaxation(int(n), [int(k) for k in ks.split(",")])
        return
    counts = [int(x) for x in a.samples.split(",")]
    full_counts = {int(x) for x in a.full.split(",") if x}
    runs = [tuple(r.split(":")) for r in a.runs.split(",")]
    slow = set()
    print(f"{'n_m':>5} {'form':>8} {'backend/solver':>16} {'max LMI':>7} {'#LMI':>5} {'vars':>7} "
          f"{'setup s':>8} {'solve s':>8} {'trace':>10} {'inside':>10} {'max r':>6} {'ratio':>6}")
    for n in counts:
        data = simulate_identification(n, seed=0)
        t0 = time.perf_counter()
        model = build_uncertainty_model(imi_scara_regressor, data["q"], data["qd"], data["qdd"], data["tau"], CI_BOUNDS)
        t_model = time.perf_counter() - t0
        traces = {}
        forms = (["full"] if n in full_counts else []) + (["chordal"] if n <= a.chordal_max else [])
        forms += [] if a.no_energy else ["energy"]
        for form in forms:
            for backend, solver in (runs[:1] if form == "energy" else runs):
                key = (form, backend, solver)
                if key in slow:
                    continue
                if form == "full" and backend == "drake" and solver == "clarabel" and n > 5:
                    continue
                if solver == "csdp" and form != "energy":
                    gb = csdp_gb(model, form)
                    if gb > a.csdp_gb:
                        print(f"{n:>5} {form:>8} {backend + '/' + solver:>16}  skipped: needs ~{gb:.1f} GB "
                              f"(> --csdp-gb {a.csdp_gb:g})")
                        continue
                try:
                    r = solve_ellipsoid(model, solver=solver, formulation=form, backend=backend, certify_draws=a.draws)
                except RobustDrakeError as exc:
                    print(f"{n:>5} {form:>8} {backend + '/' + solver:>16}  FAILED: {str(exc)[:90]}")
                    continue
                traces.setdefault(form, r.trace)
                ratio = float("nan")
                if form == "chordal" and "full" in traces:
                    ratio = r.trace / traces["full"]
                elif form == "energy" and "chordal" in traces:
                    ratio = r.trace / traces["chordal"]
                if form == "energy":
                    backend, solver = "none", "closed-form"
                c = r.certificate
                print(f"{n:>5} {form:>8} {backend + '/' + solver:>16} {max(r.lmi_sizes, default=0):>7} {len(r.lmi_sizes):>5} "
                      f"{r.n_variables:>7} {r.setup_seconds + t_model:>8.2f} {r.solve_seconds:>8.2f} {r.trace:>10.4g} "
                      f"{c['inside']:>5}/{c['tested']:<4} {c['max_radius']:>6.3f} {ratio:>6.3f}", flush=True)
                if r.solve_seconds > a.max_seconds:
                    slow.add(key)


if __name__ == "__main__":
    main()
