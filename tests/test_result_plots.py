"""Result objects and figures (issue 16): ``SimulationResult.plot()`` / ``.to_pandas()``,
``rd.repair_figure``, the repair residual and torque figures, the ``compare`` table figure.

Each figure is a detached ``matplotlib.figure.Figure`` (pyplot's figure list unchanged), every
axis is labelled with its unit in brackets, and the layouts the issue asked for hold: one
column per validation file with no line drawn across a file boundary, spectra clipped to six
decades, the compare table's columns sharing their y-limits across controllers.
"""

import re
from types import SimpleNamespace

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.figure import Figure

import robust_drake as rd

UNIT = re.compile(r"\[[^\]]+\]")


def _labelled(ax) -> bool:
    return bool(UNIT.search(ax.get_ylabel()))


@pytest.fixture(scope="module")
def run():
    return rd.simulate(controller="sp2", trajectory="cpt", duration=0.1)


def test_simulation_result_plot_is_a_detached_labelled_figure(run):
    before = plt.get_fignums()
    fig = run.plot()
    assert plt.get_fignums() == before
    assert isinstance(fig, Figure)
    axes = fig.get_axes()
    assert len(axes) == run.q.shape[1] + 2  # joint errors, task-space error, torques
    assert all(_labelled(ax) for ax in axes)
    assert "[rad]" in axes[0].get_ylabel() and "[N m]" in axes[-1].get_ylabel()
    assert axes[-1].get_xlabel() == "t [s]"
    # the D2R2 torque limit is drawn at +-31.2 N m (JS section 9)
    ys = sorted({round(float(l.get_ydata()[0]), 3) for l in axes[-1].get_lines() if l.get_linestyle() == "--"})
    assert ys == [-31.2, 31.2]


def test_simulation_result_to_pandas(run):
    df = run.to_pandas()
    n, K = run.q.shape[1], len(run.t)
    signals = ("q", "v", "q_d", "qd_d", "qdd_d", "q_meas", "v_hat", "u", "tau", "e")
    assert df.shape == (K, len(signals) * n + 1)  # + e_task (planar arm)
    assert df.index.name == "t" and df.index[0] == pytest.approx(run.t[0])
    assert list(df.columns) == [f"{s}{j}" for s in signals for j in range(1, n + 1)] + ["e_task"]
    assert df.attrs["units"]["tau1"] == "N m" and df.attrs["units"]["e_task"] == "m"
    assert set(df.attrs["units"]) == {"t", *df.columns}
    # the task error is the end effector's distance from its desired point (JS eq. 58's integrand)
    from robust_drake.kinematics import planar_forward_kinematics

    tip = planar_forward_kinematics(run.q, run.link_lengths) - planar_forward_kinematics(run.q_d, run.link_lengths)
    assert np.allclose(df["e_task"], np.hypot(tip[:, 0], tip[:, 1]))
    assert len(repr(run)) < 300 and "SimulationResult(" in repr(run)
    # tracking error from the frame equals the logged error, and |tau| obeys the saturation
    assert np.allclose(df["q1"] - df["q_d1"], run.q[:, 0] - run.q_d[:, 0])
    assert df[["tau1", "tau2"]].abs().to_numpy().max() <= 31.2 + 1e-9


def test_repair_figure_from_report_dict_and_errors(tmp_path):
    rep = {"robot": "x", "joint_names": ["a", "b"], "verdict": "repaired",
           "baseline": {"rms_fit": [0.2, 0.1], "rms_validate": [0.3, None]},
           "final": {"rms_fit": [0.1, 0.05], "rms_validate": [0.15, 0.08]}}
    before = plt.get_fignums()
    fig = rd.repair_figure(rep)
    assert plt.get_fignums() == before
    ax_fit, ax_val = fig.get_axes()
    assert "[N m]" in ax_fit.get_ylabel()
    heights = [p.get_height() for p in ax_val.patches]
    assert heights[:2] == [0.3, pytest.approx(np.nan, nan_ok=True)] and heights[2:] == [0.15, 0.08]
    with pytest.raises(rd.RobustDrakeError, match="no repair report"):
        rd.repair_figure(tmp_path)
    with pytest.raises(rd.RobustDrakeError, match="not a repair report"):
        rd.repair_figure({"robot": "x"})


def _ident_data(segments=2, N=600, n=2, seed=0):
    from robust_drake.identification.data import IdentData

    rng = np.random.default_rng(seed)
    t = np.concatenate([np.arange(N) * 0.01 for _ in range(segments)])  # every file starts at 0 s
    seg = np.repeat(np.arange(segments), N)
    q = np.sin(np.outer(t, np.arange(1, n + 1)) + seg[:, None])
    qd = np.cos(np.outer(t, np.arange(1, n + 1)) + seg[:, None])
    d = IdentData(t=t, q=q, qd=qd, qdd=-q, tau=rng.normal(size=(len(t), n)), dt=0.01, segment=seg,
                  conditioning=[{"source": f"/x/file{k}.csv"} for k in range(segments)])
    return d


def test_torque_validate_one_column_per_file_no_line_across_files():
    from robust_drake.model_repair.report import torque_validate_figure

    val = _ident_data()
    r = np.full_like(val.tau, 0.1)
    res = SimpleNamespace(inputs=SimpleNamespace(val=val, joint_names=["j1", "j2"]),
                          baseline=SimpleNamespace(val_residual=r), final=SimpleNamespace(val_residual=r / 2))
    fig = torque_validate_figure(res)
    axes = np.array(fig.get_axes()).reshape(2, 2)
    assert [ax.get_title() for ax in axes[0]] == ["file0.csv", "file1.csv"]
    for ax in axes.flat:
        for line in ax.get_lines():
            x = np.asarray(line.get_xdata())
            assert np.all(np.diff(x) > 0)  # each line runs forward in time: one file, never two
    assert all(_labelled(ax) for ax in axes[:, 0]) and all("[s]" in ax.get_xlabel() for ax in axes[-1])
    leg = axes[0, -1].get_legend()
    assert leg is not None and leg.get_bbox_to_anchor().x0 > axes[0, -1].get_window_extent().x1 - 1


def test_residual_figure_units_and_clipped_spectrum():
    from robust_drake.model_repair.residual import SPECTRUM_FLOOR, residual_figure

    d = _ident_data(segments=1, N=2000)
    r = d.tau * 1e-3
    r[:, 1] = 1e-12 * np.sin(np.arange(len(d.t)))  # a joint with a near-zero residual
    before = plt.get_fignums()
    fig = residual_figure(d, r, other=r / 2)
    assert plt.get_fignums() == before
    axes = fig.get_axes()
    assert len(axes) == 6
    xl = [ax.get_xlabel() for ax in axes]
    for unit in ("q_j [rad]", "qd_j [rad/s]", "qdd_j [rad/s^2]", "tau_j [N m]", "frequency [Hz]"):
        assert unit in xl
    assert all(_labelled(ax) for ax in axes)
    lo, hi = axes[4].get_ylim()
    assert lo / hi >= SPECTRUM_FLOOR / 2.5  # six decades at most, not down to 1e-20


def test_compare_table_figure_shared_columns_sp1_sp2_one_row(tmp_path):
    from robust_drake.experiments.jaritz_spong import plot_table

    t = np.linspace(0, 1, 101)
    rows = []
    for c, scale in (("sp1", 1.0), ("sp2", 1.1), ("zc", 5.0)):
        e = scale * 1e-3 * np.column_stack([np.sin(t), np.cos(t)])
        rows.append(dict(controller=c, metrics_skip=0.2, logs=dict(
            t=t.tolist(), e=e.tolist(), tau=(scale * np.column_stack([t, -t])).tolist(),
            q=(0.5 + e).tolist(), q_d=np.full((len(t), 2), 0.5).tolist())))
    import matplotlib.figure as mf

    captured = []
    orig = mf.Figure.savefig
    try:
        mf.Figure.savefig = lambda self, *a, **k: (captured.append(self), orig(self, *a, **k))[1]
        path = plot_table(7, rows, tmp_path)
    finally:
        mf.Figure.savefig = orig
    assert path.name == "table7.png" and path.exists()
    axes = np.array(captured[0].get_axes()).reshape(-1, 3)
    assert axes.shape[0] == 2  # SP1 and SP2 in one row, ZC in the other
    assert [ax.get_ylabel() for ax in axes[0]] == ["joint error [rad]", "task-space error [mm]", "torque [N m]"]
    for col in range(3):
        assert axes[0, col].get_ylim() == axes[1, col].get_ylim()  # rows compare
    assert len(axes[0, 1].get_lines()) == 2 and len(axes[1, 1].get_lines()) == 1
