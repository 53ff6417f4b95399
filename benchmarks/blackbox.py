"""Black-box check of the repair (issue 21): is there structure in the baseline residual that
the effect library does not reach?

On one simulated six-axis case (``arm_battery.generate``, default the UR5 with a 10x-noise
cogging on a wrist joint at 500 Hz), the repair's BASELINE model (rigid body + Coulomb/viscous,
``IdentifiedModel.from_report(rep, "baseline")``) gives the residual r = tau - tau_hat per joint
on the fit and the validation run.  A gradient-boosting model per joint learns r from the
features q, qd, qdd of all joints plus qd lagged by LAGS_S, trained on time blocks of the FIT
rows only:

- held-out blocks: the fit run is cut into BLOCKS time blocks; each block is predicted by a
  booster trained on the other blocks minus a GAP_S guard band on either side (the 8 Hz filter
  and the motion correlate neighbouring rows), its setting (GRID, or no booster: predict 0)
  chosen by leave-one-block-out error inside those training blocks (nested, so the held-out
  figure is not the tuning's own);
- validation: the booster tuned and trained on all fit rows predicts the validation run.

Printed per joint: RMS of r before and after subtracting the booster's prediction [N m], on
the held-out blocks and on the validation run, and the three features the booster leans on
most (impurity importances of the all-fit-rows model).  A large cut where the repair kept
nothing is structure the loop does not reach.

Needs scikit-learn (the ``bench`` extra); without it the script prints how to install it and
exits 0.

Usage (from the repository root):
    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python benchmarks/blackbox.py [--arm ur5]
        [--case cogging_10x] [--rate 500] [--duration 10] [--seed 0]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time

import numpy as np

BLOCKS = 4
GAP_S = 0.25  # s removed on either side of a held-out block from the training rows
LAGS_S = (0.05, 0.1, 0.2)  # s, lags of qd
STRIDE_S = 0.02  # s between the rows given to the booster (the residual is filtered at 8 Hz: 3x oversampled)


def features(data, lags_s=LAGS_S):
    """(X (N, 3n + n len(lags)), names): q, qd, qdd of every joint and qd lagged by ``lags_s``
    (the first rows of each segment repeat its first value)."""
    q, qd, qdd, t = (np.asarray(getattr(data, k), float) for k in ("q", "qd", "qdd", "t"))
    n = q.shape[1]
    dt = float(np.median(np.diff(t)))
    cols, names = [q, qd, qdd], [f"{v}[{j}]" for v in ("q", "qd", "qdd") for j in range(n)]
    for lag in lags_s:
        k = max(1, int(round(lag / dt)))
        lagged = np.vstack([np.repeat(qd[:1], k, axis=0), qd[:-k]])
        cols.append(lagged)
        names += [f"qd[{j}](t-{lag:g}s)" for j in range(n)]
    return np.hstack(cols), names


#: booster settings tried (n_estimators, max_depth); the choice, or no booster at all (predict
#: 0: the baseline), is made per joint by leave-one-block-out error on the training rows only
GRID = ((100, 2), (200, 3))


def _booster(n_estimators, max_depth):
    from sklearn.ensemble import GradientBoostingRegressor

    return GradientBoostingRegressor(n_estimators=n_estimators, max_depth=max_depth, learning_rate=0.05,
                                     subsample=0.8, min_samples_leaf=20, random_state=0)


def _block_masks(t, rows, blocks, gap_s):
    """[(train, test)] boolean masks: each time block of ``rows`` against the rest of ``rows``
    farther than ``gap_s`` from it."""
    tt = t[rows]
    edges = np.linspace(tt.min(), tt.max() + 1e-9, blocks + 1)
    out = []
    for b in range(blocks):
        test = rows & (t >= edges[b]) & (t < edges[b + 1])
        train = rows & ((t < edges[b] - gap_s) | (t >= edges[b + 1] + gap_s))
        out.append((train, test))
    return out


def tuned_fit(X, y, t, rows, blocks=BLOCKS - 1, gap_s=GAP_S):
    """The booster of :data:`GRID` with the least leave-one-block-out RMS on ``rows``, fitted on
    all of ``rows``; None when no setting beats predicting 0 (the baseline residual itself)."""
    folds = _block_masks(t, rows, blocks, gap_s)
    best, best_err = None, np.sqrt(np.mean(np.concatenate([y[te] for _, te in folds]) ** 2))
    for cfg in GRID:
        e = np.concatenate([y[te] - _booster(*cfg).fit(X[tr], y[tr]).predict(X[te]) for tr, te in folds])
        err = np.sqrt(np.mean(e ** 2))
        if err < best_err:
            best, best_err = cfg, err
    return None if best is None else _booster(*best).fit(X[rows], y[rows])


def heldout_blocks(X, r, t, blocks=BLOCKS, gap_s=GAP_S):
    """Out-of-block predictions of r (N, n): each time block predicted by the booster tuned and
    trained (:func:`tuned_fit`, inner blocks) on the rows farther than ``gap_s`` from it."""
    pred = np.zeros_like(r)
    for train, test in _block_masks(t, np.ones(len(t), bool), blocks, gap_s):
        for j in range(r.shape[1]):
            m = tuned_fit(X, r[:, j], t, train)
            pred[test, j] = 0.0 if m is None else m.predict(X[test])
    return pred


def _rms(x):
    return np.sqrt(np.mean(np.asarray(x) ** 2, axis=0))


def _load(paths, model):
    from robust_drake.identification.data import load

    flt = dict((model.data or {}).get("filter") or {})
    return load(paths, robot=model.robot, n_joints=model.n, cutoff_hz=flt.get("cutoff_hz", 8.0),
                order=flt.get("order") or 4, joint_names=model.joint_names, quiet=True)


def run(arm, case, rate, duration, seed):
    from robust_drake.synthetic import arm_battery as AB
    from robust_drake.identification.model import IdentifiedModel
    from robust_drake.model_repair.pipeline import RepairOptions, run_repair

    out = tempfile.mkdtemp(prefix="blackbox_")
    fits, vals, truth = AB.generate(arm, case, out, rate_hz=rate, duration=duration, seed=seed)
    t0 = time.perf_counter()
    rep = run_repair(fits, RepairOptions(robot=truth["fit_robot"], consistent=False, replay=False, plots=False),
                     validate_paths=vals)
    t_rep = time.perf_counter() - t0
    base = IdentifiedModel.from_report(rep, "baseline")
    res = {}
    for role, paths in (("fit", fits), ("validate", vals)):
        p, d = base.predict(paths), _load(paths, base)
        stride = max(1, int(round(STRIDE_S / float(np.median(np.diff(d.t))))))
        X, names = features(d)
        res[role] = (X[::stride], p.residual[::stride], d.t[::stride])
    Xf, rf, tf = res["fit"]
    held = heldout_blocks(Xf, rf, tf)
    Xv, rv, _ = res["validate"]
    full = [tuned_fit(Xf, rf[:, j], tf, np.ones(len(tf), bool), blocks=BLOCKS) for j in range(rf.shape[1])]
    pv = np.column_stack([np.zeros(len(Xv)) if m is None else m.predict(Xv) for m in full])
    top = [[] if m is None else [names[i] for i in np.argsort(m.feature_importances_)[::-1][:3]] for m in full]
    imp = [[] if m is None else np.sort(m.feature_importances_)[::-1][:3] for m in full]
    return dict(truth=truth, claimed=AB.claimed(rep), t_repair=t_rep, held=(_rms(rf), _rms(rf - held)),
                val=(_rms(rv), _rms(rv - pv)), top=top, imp=imp)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arm", default="ur5")
    ap.add_argument("--case", default="cogging_10x")
    ap.add_argument("--rate", type=float, default=500.0)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    try:
        import sklearn  # noqa: F401
    except ImportError:
        print("blackbox.py needs scikit-learn: pip install -c requirements.lock scikit-learn "
              "(or the 'bench' extra: pip install 'robust_drake[bench]')")
        return 0
    r = run(a.arm, a.case, a.rate, a.duration, a.seed)
    t = r["truth"]
    print(f"# Black-box check: {a.arm} {a.case} ({a.rate:g} Hz, {a.duration:g} s runs, seed {a.seed})\n")
    print(f"hidden: {t.get('effects') or t.get('setup_change') or 'nothing'}; repair kept: {r['claimed'] or 'nothing'} "
          f"(repair {r['t_repair']:.1f} s)\n")
    print("| joint | held-out blocks: baseline -> booster [N m] | cut | validation: baseline -> booster [N m] | cut "
          "| leans on (importance) |")
    print("|---|---|---|---|---|---|")
    for j in range(len(r["top"])):
        hb, ha = r["held"][0][j], r["held"][1][j]
        vb, va = r["val"][0][j], r["val"][1][j]
        lean = ", ".join(f"{n} ({w:.2f})" for n, w in zip(r["top"][j], r["imp"][j])) or "no booster beat 0"
        print(f"| {j} | {hb:.4g} -> {ha:.4g} | {1 - ha / hb:+.0%} | {vb:.4g} -> {va:.4g} | {1 - va / vb:+.0%} | {lean} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
