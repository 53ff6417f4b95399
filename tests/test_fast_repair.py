"""The repair's fast paths give the answers of the straightforward computations they replace.

The references here are kept deliberately naive: the joined (N, n, p) regressor, least squares
by ``numpy.linalg.lstsq`` on the stacked training rows, a fresh least-squares solve for every
span projection, the filter over all columns at once, the regressor over all samples at once.
The optimised code (``fitting.ColumnCache``: memoised per-block Gram matrices, predictions on
row-block views; ``nominal.SpanBasis``; ``parallel_filter`` in column blocks;
``rigid_body_columns`` in row blocks) must agree to round-off (1e-9 relative), on data with two
segments so the row blocks cross a segment boundary, with an implicit (torque-dependent) effect
among the candidates.
"""

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from fourier_motion import fourier_motion
from robust_drake.identification.data import FilterSettings, IdentData, zero_phase_lowpass
from robust_drake.identification.fitting import ColumnCache, predict_tau
from robust_drake.identification.least_squares import (
    FILTER_COLUMNS, REGRESSOR_ROWS, load_regressor, parallel_filter, rigid_body_columns, solve_ls,
)
from robust_drake.effects import make_effect
from robust_drake.model_repair.selection import blocked_folds, cv_score, forward_select

ROBOT = "dfki_double_pendulum_c1"
RTOL = 1e-9


@pytest.fixture(scope="module")
def reg():
    return load_regressor(ROBOT)


def _segment(N, dt, seed, t0):
    t = t0 + np.arange(N) * dt
    return (t, *fourier_motion(t, np.random.default_rng(seed), 0.3))


def _data(reg, seed=0, noise=0.01, cutoff=8.0):
    """Two segments (600 and 500 samples, 4 ms) of a 2-joint arm with a planted spring on joint 1
    and an offset on joint 0; columns parallel-filtered at ``cutoff``."""
    parts = []
    for s, (N, t0) in enumerate(((600, 0.0), (500, 10.0))):
        t, q, qd, qdd = _segment(N, 0.004, seed + s, t0)
        tau = reg.evaluate(q, qd, qdd) @ reg.base_parameters() + 0.1 * np.sign(qd) + 0.01 * qd
        tau[:, 1] += 0.3 * q[:, 1]
        tau[:, 0] += 0.05
        tau += noise * np.random.default_rng(100 + seed + s).standard_normal(tau.shape)
        parts.append(IdentData(t=t, q=q, qd=qd, qdd=qdd, tau=tau, dt=0.004, robot=ROBOT,
                               filter=FilterSettings(cutoff_hz=cutoff, order=4)))
    return IdentData.concatenate(parts)


def _test_masks(data, k):
    """The held-out masks of ``blocked_folds`` (they partition the rows)."""
    return [test for test, _ in blocked_folds(data, k)]


def _candidates():
    return [make_effect("torque_offset", 0), make_effect("torque_offset", 1), make_effect("spring", 1),
            make_effect("spring", 0), make_effect("stribeck", 0, stribeck_velocity=0.2),
            make_effect("torque_scale", 1)]


def _close(a, b, rtol=RTOL):
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = np.maximum(np.abs(a), np.abs(b)).max(initial=0.0)
    return a.shape == b.shape and bool(np.all(np.abs(a - b) <= rtol * max(scale, 1e-300)))


# ------------------------------------------------------------------ naive references
def naive_predict(cache, effects, theta, rows=None):
    """tau_hat on ``rows`` from the joined columns (implicit effects by the same fixed point)."""
    Y, _, slices = cache.model(effects)
    rows = slice(None) if rows is None else rows
    imp = [(e, sl) for e, sl in zip(effects, slices) if e.needs_tau and not getattr(e, "uses_taud", False)]
    mask = np.ones(Y.shape[2], bool)
    for _, sl in imp:
        mask[sl] = False
    m = Y[rows][:, :, mask] @ theta[mask]
    d, tau_hat = cache.data, m.copy()
    for _ in range(30):
        new = m + sum(e.evaluate_columns(d.q[rows], d.qd[rows], d.qdd[rows], tau_hat) @ theta[sl] for e, sl in imp)
        if cache.keep is not None:  # rows left out (stiction) predict 0, as their zeroed torque
            new = new * cache.keep[rows]
        done = np.max(np.abs(new - tau_hat)) < 1e-10
        tau_hat = new
        if done:
            break
    return tau_hat


def naive_cv_score(cache, effects, weights, folds, icache=None, per_joint=False):
    """Blocked cross validation the plain way: for every fold, least squares (or IV) on the
    stacked training rows, then the output error on the held-out rows."""
    Y, _, _ = cache.model(effects)
    Z = Y if icache is None else icache.model(effects)[0]
    tau, w, p = cache.data.tau, np.asarray(weights, float), Y.shape[2]
    total, count = 0.0, 0
    for fold in folds:  # (test, train) pairs, or a test mask alone (train = its complement)
        test, train = fold if isinstance(fold, tuple) else (fold, ~fold)
        A = (Y[train] * w[None, :, None]).reshape(-1, p)
        b = (tau[train] * w[None, :]).reshape(-1)
        if icache is None:
            theta = np.linalg.lstsq(A, b, rcond=None)[0]
        else:
            B = (Z[train] * w[None, :, None]).reshape(-1, p)
            theta = np.linalg.solve(B.T @ A, B.T @ b)
        r = (tau[test] - naive_predict(cache, effects, theta, test)) * w[None, :]
        total = total + (np.sum(r**2, axis=0) if per_joint else float(np.sum(r**2)))
        count += r.size
    return total if per_joint else total / count


class NaiveCache(ColumnCache):
    """ColumnCache with its fast paths replaced by the computations on the joined columns."""

    def gram(self, effects, weights, masks, left=None):
        Y = self.model(effects)[0]
        Z = Y if left is None else left.model(effects)[0]
        w = np.asarray(weights, float)
        Yw, Zw, bw = Y * w[None, :, None], Z * w[None, :, None], self.data.tau * w[None, :]
        return ([np.einsum("nip,niq->pq", Zw[m], Yw[m]) for m in masks],
                [np.einsum("nip,ni->p", Zw[m], bw[m]) for m in masks])

    def explicit_prediction(self, effects, theta, mask=None, rows=None, joints=None):
        Y = self.model(effects)[0]
        mask = np.ones(Y.shape[2], bool) if mask is None else np.asarray(mask, bool)
        rows = slice(None) if rows is None else rows
        return Y[rows][:, :, mask] @ np.asarray(theta)[mask]

    def joint_gram(self, effects, masks):
        Y, tau = self.model(effects)[0], self.data.tau
        return (np.array([np.einsum("nip,niq->ipq", Y[m], Y[m]) for m in masks]),
                np.array([np.einsum("nip,ni->ip", Y[m], tau[m]) for m in masks]),
                np.array([np.sum(tau[m] ** 2, axis=0) for m in masks]))

    def fit_ls(self, effects, weights=None, parts=None, warn=True, residual=True):
        Y, names, _ = self.model(effects)
        return solve_ls(Y, self.data.tau, names, weights=weights, warn=warn)


# ------------------------------------------------------------------ tests
def test_cv_score_equals_plain_least_squares_per_fold(reg):
    data = _data(reg)
    cache = ColumnCache(data, reg)
    folds = blocked_folds(data, 4)
    w = np.array([1.0 / 0.02, 1.0 / 0.05])
    cands = _candidates()
    for effects in ([], [cands[2]], [cands[2], cands[0]], [cands[2], cands[4], cands[5]]):
        fast = cv_score(cache, effects, w, folds)
        again = cv_score(cache, effects, w, folds)  # from the memo
        assert _close(fast, naive_cv_score(cache, effects, w, folds)), effects
        assert again == fast


class CrossTorque(make_effect("torque_scale", 0).__class__):
    """An implicit kind whose joint-j column reads another joint's torque (not ``own_joint_tau``)."""

    kind = "cross_torque_test"
    own_joint_tau = False

    def _features(self, j, q, qd, qdd, tau, taud):
        return -0.1 * tau[:, 1 - j:2 - j]


def test_heldout_sse_per_joint_equals_the_residual_path_and_plain_folds(reg):
    """Per joint, the Gram-product held-out error (explicit joints) and the joint-restricted
    prediction (implicit joints) equal the plain folds' residuals: explicit models, an own-joint
    implicit effect (torque scale, dead zone), one that reads the other joint's torque (every
    joint predicted), with a gap between the folds, with instruments and with stiction rows left out."""
    from robust_drake.model_repair.selection import heldout_residuals, heldout_sse

    data = _data(reg)
    folds = blocked_folds(data, 4, gap=7)
    w = np.array([1.0 / 0.02, 1.0 / 0.05])
    cands = _candidates()
    dz = make_effect("dead_zone", 0, threshold=0.05)
    exclude = np.zeros((data.N, data.n), bool)
    exclude[100:160, 0] = True
    caches = [(ColumnCache(data, reg), None), (ColumnCache(data, reg, exclude=exclude), None),
              (ColumnCache(data, reg), ColumnCache(_data(reg, cutoff=4.0), reg))]
    for cache, icache in caches:
        for effects in ([], [cands[2]], [cands[2], cands[5]], [dz, cands[3]], [CrossTorque(joint=0)]):
            sse, rows = heldout_sse(cache, effects, w, folds, icache)
            R, held = heldout_residuals(cache, effects, w, folds, icache)
            assert rows == int(held.sum())
            assert _close(sse, np.sum(R**2, axis=0)), effects
            if icache is None:
                assert _close(sse, naive_cv_score(cache, effects, w, folds, per_joint=True)), effects


def test_cv_score_with_instruments_equals_plain_iv(reg):
    data = _data(reg)
    zdata = _data(reg, cutoff=4.0)  # same rows, columns low-passed lower: the instruments
    cache, icache = ColumnCache(data, reg), ColumnCache(zdata, reg)
    folds = blocked_folds(data, 4)
    w = np.array([30.0, 12.0])
    effects = [_candidates()[2], _candidates()[0]]
    assert _close(cv_score(cache, effects, w, folds, icache), naive_cv_score(cache, effects, w, folds, icache))


def test_iv_fit_from_blocks_equals_solve_iv_on_the_joined_model(reg):
    from robust_drake.identification.instruments import fit_iv_blocks, solve_iv

    data, zdata = _data(reg), _data(reg, cutoff=4.0)
    cache, icache = ColumnCache(data, reg), ColumnCache(zdata, reg)
    effects = [_candidates()[2], _candidates()[4]]
    w = np.array([25.0, 9.0])
    ref = solve_iv(cache.model(effects)[0], icache.model(effects)[0], data.tau, cache.names(effects), w, 0.3,
                   data=cache.data)
    fast = fit_iv_blocks(cache, icache, effects, w, parts=_test_masks(data, 4), n_eff_factor=0.3)
    for attr in ("theta", "residual", "rms", "cov_homoscedastic"):
        assert _close(getattr(fast, attr), getattr(ref, attr)), attr
    assert _close(fast.cov, ref.cov_homoscedastic)  # the selection's fits: homoscedastic
    robust = fit_iv_blocks(cache, icache, effects, w, parts=_test_masks(data, 4), n_eff_factor=0.3, robust=True)
    assert robust.covariance == ref.covariance == "filter-aware sandwich"
    assert _close(robust.cov, ref.cov) and _close(robust.se, ref.se)  # the sandwich from the blocks
    # the plain IV solve itself: (Z^T W Y)^-1 Z^T W tau on the stacked rows
    Y, Z = cache.model(effects)[0], icache.model(effects)[0]
    A, B = ((M * w[None, :, None]).reshape(-1, Y.shape[2]) for M in (Y, Z))
    assert _close(ref.theta, np.linalg.solve(B.T @ A, B.T @ (data.tau * w).reshape(-1)))


def test_fit_and_prediction_from_blocks_equal_the_joined_model(reg):
    data = _data(reg)
    cache = ColumnCache(data, reg)
    effects = [_candidates()[2], _candidates()[5]]  # spring + an implicit torque_scale
    w = np.array([20.0, 10.0])
    Y, names, _ = cache.model(effects)
    ref = solve_ls(Y, data.tau, names, weights=w, warn=False)
    fast = cache.fit_ls(effects, w, parts=_test_masks(data, 4), warn=False)
    for attr in ("theta", "se", "residual", "rms"):
        assert _close(getattr(fast, attr), getattr(ref, attr)), attr
    assert fast.rank == ref.rank and fast.unidentifiable == ref.unidentifiable
    rows = _test_masks(data, 3)[1] | (np.arange(data.N) % 7 == 0)  # several runs, across segments
    for r in (None, rows, np.nonzero(rows)[0]):
        assert _close(predict_tau(cache, effects, ref.theta, r), naive_predict(cache, effects, ref.theta, r))
    with pytest.raises(ValueError, match="partition"):
        cache.fit_ls(effects, w, parts=_test_masks(data, 4)[:3])


def test_forward_selection_equals_the_naive_selection(reg):
    data = _data(reg)
    fast = forward_select(ColumnCache(data, reg), _candidates(), min_gain=0.01)
    slow = forward_select(NaiveCache(data, reg), _candidates(), min_gain=0.01)
    assert [(e.kind, e.joint) for e in fast.chosen] == [(e.kind, e.joint) for e in slow.chosen]
    assert ("spring", 1) in [(e.kind, e.joint) for e in fast.chosen]
    assert len(fast.steps) == len(slow.steps)
    for a, b in zip(fast.steps, slow.steps):
        assert (a.label, a.accepted, a.reason.split(" ")[0]) == (b.label, b.accepted, b.reason.split(" ")[0])
        for k in ("score_after", "gain", "bic_after"):
            assert _close(getattr(a, k), getattr(b, k)), k
    assert [r["label"] for r in fast.ranking] == [r["label"] for r in slow.ranking]
    assert _close([r["score"] or 0.0 for r in fast.ranking], [r["score"] or 0.0 for r in slow.ranking])


def test_forward_selection_with_instruments_equals_the_naive_selection(reg):
    data, zdata = _data(reg, noise=0.02), _data(reg, noise=0.02, cutoff=4.0)
    fast = forward_select(ColumnCache(data, reg), _candidates(), min_gain=0.01, icache=ColumnCache(zdata, reg))
    slow = forward_select(NaiveCache(data, reg), _candidates(), min_gain=0.01, icache=NaiveCache(zdata, reg))
    assert [(e.kind, e.joint) for e in fast.chosen] == [(e.kind, e.joint) for e in slow.chosen]
    assert fast.chosen and len(fast.steps) == len(slow.steps)
    for a, b in zip(fast.steps, slow.steps):
        assert a.label == b.label and a.accepted == b.accepted
        assert _close([a.score_after, a.gain, a.bic_after], [b.score_after, b.gain, b.bic_after])


def test_repair_report_equals_the_naive_pipeline(reg, tmp_path, monkeypatch):
    """The whole repair (selection, never-worse guard, nominal comparison) on a small simulated
    case: effects, parameters and RMS errors of the report equal the naive pipeline's."""
    from robust_drake.model_repair import nominal as NM
    from robust_drake.model_repair import stages
    from robust_drake.model_repair.pipeline import RepairOptions, run_repair
    from robust_drake.synthetic.simulated import simulate_experiment

    paths = []
    for role, seed in (("fit", 0), ("val", 1)):
        paths.append(str(tmp_path / f"{role}.csv"))
        simulate_experiment(ROBOT, [("spring", 1, {"stiffness": 0.3})], duration=8, seed=seed, out_csv=paths[-1])
    opts = dict(robot=ROBOT, consistent=False, replay=False, plots=False)
    fast = run_repair(paths[:1], RepairOptions(**opts), validate_paths=paths[1:])

    class NaiveBasis:
        def __init__(self, Yb):
            self.Yb = Yb

        def direction(self, Phi):
            A, B = self.Yb.reshape(-1, self.Yb.shape[-1]), Phi.reshape(-1, Phi.shape[-1])
            d = np.linalg.lstsq(A, B, rcond=None)[0]
            return d, float(np.linalg.norm(B - A @ d) / np.linalg.norm(B))

    monkeypatch.setattr(stages, "ColumnCache", NaiveCache)
    monkeypatch.setattr(NM, "SpanBasis", NaiveBasis)
    slow = run_repair(paths[:1], RepairOptions(**opts), validate_paths=paths[1:])
    assert fast["effects"] and [(e["kind"], e["joint"]) for e in fast["effects"]] == \
        [(e["kind"], e["joint"]) for e in slow["effects"]]
    assert fast["verdict"] == slow["verdict"]
    for e, f in zip(fast["effects"], slow["effects"]):
        num = [k for k, v in e["parameters"].items() if isinstance(v, float)]
        assert _close([e["parameters"][k] for k in num], [f["parameters"][k] for k in num])
        assert _close(e["rms_validate_after"], f["rms_validate_after"])
    for key in ("baseline", "final"):
        for part in ("rms_fit", "rms_validate"):
            assert _close(fast[key][part], slow[key][part]), (key, part)
    assert _close(list(fast["final"]["parameters"].values()), list(slow["final"]["parameters"].values()))
    spans = lambda r: [(c["label"], c["accepted"]) for c in r["nominal"]["span_candidates"]]  # noqa: E731
    assert spans(fast) == spans(slow)
    assert _close([c["chi2_after"] for c in fast["nominal"]["span_candidates"]],
                  [c["chi2_after"] for c in slow["nominal"]["span_candidates"]])


def test_span_basis_equals_lstsq_on_a_rank_deficient_base():
    from robust_drake.model_repair.nominal import SpanBasis, span_direction

    rng = np.random.default_rng(3)
    Yb = rng.normal(size=(400, 3, 9))
    Yb[:, :, 4] = 2.0 * Yb[:, :, 1] - Yb[:, :, 7]  # one null direction
    inside = Yb[:, :, :3] @ rng.normal(size=(3, 2))
    outside = rng.normal(size=(400, 3, 1))
    basis = SpanBasis(Yb)
    A = Yb.reshape(-1, 9)
    for Phi in (inside, outside, np.concatenate([inside, outside], axis=2)):
        B = Phi.reshape(-1, Phi.shape[-1])
        d0 = np.linalg.lstsq(A, B, rcond=None)[0]
        d, rel = span_direction(basis, Phi)
        assert _close(d, d0)
        assert rel == pytest.approx(np.linalg.norm(B - A @ d0) / np.linalg.norm(B), rel=RTOL, abs=1e-13)
    assert span_direction(Yb, inside)[1] < 1e-12 < 0.5 < span_direction(Yb, outside)[1]


def test_filter_in_column_blocks_is_the_whole_filter_bit_for_bit(reg):
    data = _data(reg)
    Y = np.random.default_rng(4).normal(size=(data.N, data.n, FILTER_COLUMNS + 37))
    out = parallel_filter(data, Y)
    for s in np.unique(data.segment):
        m = data.segment == s
        ref = zero_phase_lowpass(Y[m].reshape(m.sum(), -1), data.segment_period(s), data.filter.cutoff_hz,
                                 data.filter.order).reshape(Y[m].shape)
        assert np.array_equal(out[m], ref)


def test_regressor_in_row_blocks_is_the_regressor_on_all_rows(reg):
    N = 2 * REGRESSOR_ROWS + 333
    t, q, qd, qdd = _segment(N, 0.004, 5, 0.0)
    data = IdentData(t=t, q=q, qd=qd, qdd=qdd, tau=np.zeros((N, 2)), dt=0.004, robot=ROBOT)
    Y, names = rigid_body_columns(reg, data)
    assert names == list(reg.base_names)
    assert np.array_equal(Y, np.asarray(reg.evaluate(q, qd, qdd), float))


def test_envelope_keeps_every_extreme_in_time_order():
    from robust_drake.plotting import envelope

    rng = np.random.default_rng(5)
    x = np.arange(20_011) * 1e-3
    y = np.sin(7 * x) + 0.01 * rng.standard_normal(x.size)
    y[[777, 12_345, 20_010]] = (-4.0, 5.0, 3.0)
    xe, ye = envelope(x, y, 2000)
    assert len(xe) <= 2000 and np.all(np.diff(xe) > 0)
    assert {-4.0, 5.0, 3.0} <= set(ye.tolist())
    # no sample is lost: within two bucket widths (2 x 21 samples) of every sample the drawn
    # line reaches above and below it
    lo = np.searchsorted(xe, x - 0.042, side="left")
    hi = np.searchsorted(xe, x + 0.042, side="right")
    assert all(ye[a:b].max() >= v and ye[a:b].min() <= v for a, b, v in zip(lo, hi, y))
    short = np.arange(500.0)
    assert envelope(short, short)[1] is short


def test_reuse_freed_memory_keeps_a_freed_large_array_for_the_next_one():
    """After ``reuse_freed_memory`` a freed 200 MB array stays in the process (resident, ready
    for the next array) instead of going back to the kernel and being faulted in again (glibc;
    skipped where mallopt or /proc is unavailable). Runs in a child: the setting is process-wide."""
    code = textwrap.dedent("""
        import json, sys
        import numpy as np
        from robust_drake.allocator import reuse_freed_memory

        def rss():
            with open("/proc/self/status") as fh:
                return next(int(l.split()[1]) * 1024 for l in fh if l.startswith("VmRSS:"))

        applied = reuse_freed_memory() if sys.argv[1] == "on" else False
        before = rss()
        a = np.ones(25_000_000)
        touched = rss() - before
        del a
        kept = rss() - before
        b = np.ones(25_000_000)
        again = rss() - before
        print(json.dumps({"applied": applied, "touched": touched, "kept": kept, "again": again}))
    """)
    run = lambda mode: json.loads(subprocess.run([sys.executable, "-c", code, mode], capture_output=True,  # noqa: E731
                                                 text=True, check=True).stdout)
    try:
        on, off = run("on"), run("off")
    except subprocess.CalledProcessError as exc:
        pytest.skip(f"no /proc here: {exc.stderr.strip().splitlines()[-1]}")
    if not on["applied"]:
        pytest.skip("glibc mallopt not available")
    size = 25_000_000 * 8
    assert off["touched"] > 0.9 * size and on["touched"] > 0.9 * size
    assert off["kept"] < 0.1 * size  # default: unmapped on free (mapped and faulted again next time)
    assert on["kept"] > 0.9 * size  # kept in the heap ...
    assert on["again"] < 1.1 * size  # ... and the next array of that size reuses it


def test_release_keeps_the_answers(reg):
    """After ``release`` the memo is rebuilt on demand: the same scores and predictions."""
    data = _data(reg)
    cache = ColumnCache(data, reg)
    folds, w = blocked_folds(data, 4), np.array([20.0, 10.0])
    spring, stribeck = _candidates()[2], _candidates()[4]
    before = [cv_score(cache, [spring], w, folds), cv_score(cache, [spring, stribeck], w, folds)]
    Y_before = cache.model([spring, stribeck])[0]
    cache.release(keep=[spring])
    assert len(cache._effects) == 1 and not cache._grams
    assert [cv_score(cache, [spring], w, folds), cv_score(cache, [spring, stribeck], w, folds)] == before
    assert np.array_equal(cache.model([spring, stribeck])[0], Y_before)


def test_qr_factor_in_row_blocks_equals_the_qr_of_the_joined_columns(reg):
    """``ColumnCache.qr_r`` (incremental QR over row blocks, no joined copy) = R of the stacked
    weighted [A | b] (LS) and of [Zw lstsq(Zw, A) | b] (two-stage IV), up to the signs of R's rows:
    R^T R equal to round-off, and the consistent fit solved from it the same."""
    from robust_drake.identification.consistency import consistent_identification

    data, zdata = _data(reg), _data(reg, cutoff=4.0)
    cache, icache = ColumnCache(data, reg), ColumnCache(zdata, reg)
    effects = [_candidates()[2], _candidates()[0]]
    w = np.array([25.0, 9.0])
    Y, Z = cache.model(effects)[0], icache.model(effects)[0]
    A, Zw = ((M * w[None, :, None]).reshape(-1, Y.shape[2]) for M in (Y, Z))
    b = (data.tau * w[None, :]).reshape(-1)
    for left, AA in ((None, A), (icache, Zw @ np.linalg.lstsq(Zw, A, rcond=None)[0])):
        ref = np.linalg.qr(np.column_stack([AA, b]), mode="r")
        for rows in (50, 333, 10**6):  # several blocks (not dividing N), one block
            R = cache.qr_r(effects, w, left=left, block_rows=rows)
            assert R.shape == ref.shape
            assert _close(R.T @ R, ref.T @ ref), (left, rows)
        n_extra = Y.shape[2] - len(reg.base_names)
        fast = consistent_identification(reg, ROBOT, None, None, n_extra, R_full=cache.qr_r(effects, w, left=left),
                                         rows=len(b))  # the same program (regularised: rows known)
        slow = consistent_identification(reg, ROBOT, AA, b, n_extra)
        # the nearest feasible point (an SDP solved to Clarabel's default accuracy) to 1e-5 as before;
        # the regularised fit (log-det cone, its optimum flat along the budget) to the interior
        # point method's ~sqrt(tolerance) accuracy in the parameters
        assert np.allclose(fast.nearest_pi, slow.nearest_pi, rtol=1e-5, atol=1e-6 * np.abs(slow.nearest_pi).max())
        assert np.allclose(fast.theta, slow.theta, rtol=1e-4, atol=1e-4 * np.abs(slow.theta).max())


def test_span_basis_in_row_blocks_equals_lstsq_on_filtered_rigid_body_columns(reg):
    """The block-wise SpanBasis (R by incremental QR, semi-normal equations with a refinement step)
    on real, unscaled, filtered rigid-body columns (a non-contiguous view of the cache's base, several
    blocks) gives lstsq's minimum-norm direction and residual, for effect columns in and out of the span."""
    from robust_drake.model_repair.nominal import SpanBasis

    cache = ColumnCache(_data(reg), reg)
    p0 = len(reg.base_names)
    Yb = cache.base[:, :, :p0]
    A = Yb.reshape(-1, p0)
    basis = SpanBasis.__new__(SpanBasis)
    basis.BLOCK_ROWS = 128  # several blocks, the last one short
    SpanBasis.__init__(basis, Yb)
    inside = Yb @ np.random.default_rng(5).normal(size=(p0, 2))
    for e in _candidates()[:5]:  # single-joint effects: alone (zero on the other joint) and with in-span columns
        for Phi in (cache.effect(e)[0], np.concatenate([cache.effect(e)[0], inside], axis=2)):
            B = Phi.reshape(-1, Phi.shape[2])
            d0 = np.linalg.lstsq(A, B, rcond=None)[0]
            d, rel = basis.direction(Phi)
            assert _close(d, d0, 1e-7), e
            assert rel == pytest.approx(np.linalg.norm(B - A @ d0) / np.linalg.norm(B), rel=1e-7, abs=1e-12)
