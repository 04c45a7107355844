"""Blending analysis (cfddem/measure/blending.py) on synthetic streams and fields: outflow
concentration, VRR, RTD of plug flow and of a perfectly mixed vessel, convolution, virtual
tracers, flow-pattern classification, the results-file tree."""

import math

import numpy as np
import pytest

from cfddem.io.results import ResultsFile, read_measurements
from cfddem.measure.blending import (advect_tracers, batch_input_variance, blending_arrays, by_recirculation,
                                     classify_flow_pattern, convolve_rtd, outflow_concentration, release_area,
                                     release_line, rtd_from_pulse, rtd_from_residence_times, rtd_from_step,
                                     variance_reduction_ratio, virtual_tracer_rtd, vrr_by_recirculation)

# a planar silo field: 150 mm wide, bins of 10 mm, 270 mm high
W, H, CELL = 0.15, 0.27, 0.01
XC = (np.arange(15) + 0.5) * CELL
YC = (np.arange(27) + 0.5) * CELL


# ------------------------------------------------------------------ outflow concentration
def test_outflow_concentration_counts_mass_and_number_and_leaves_empty_intervals_nan():
    # interval [0, 0.1): 3 particles, one tracer of mass 2 among masses 1, 1 -> c_mass 0.5,
    # c_number 1/3; [0.1, 0.2): nothing; [0.2, 0.3): two tracers (one at exactly t_end)
    t = np.array([0.01, 0.05, 0.09, 0.21, 0.3])
    m = np.array([1.0, 2.0, 1.0, 1.0, 3.0])
    tr = np.array([0, 1, 0, 1, 1])
    c = outflow_concentration(t, m, tr, dt=0.1)
    assert c["time"] == pytest.approx([0.05, 0.15, 0.25])
    assert c["c_mass"][0] == pytest.approx(0.5) and c["c_number"][0] == pytest.approx(1 / 3)
    assert math.isnan(c["c_mass"][1]) and math.isnan(c["c_number"][1])
    assert c["c_mass"][2] == 1.0 and c["count"].tolist() == [3, 0, 2] and c["mass"][2] == pytest.approx(4.0)


# ------------------------------------------------------------------ VRR
def test_vrr_is_the_ratio_of_variances_over_the_intervals_where_both_are_finite():
    rng = np.random.default_rng(3)
    ci = rng.uniform(0, 1, 400)
    co = 0.5 + 0.1 * rng.normal(size=400)
    co[::7] = np.nan  # intervals without outflow
    ok = np.isfinite(co)
    expect = np.var(ci[ok]) / np.var(co[ok])
    assert variance_reduction_ratio(ci, co) == pytest.approx(expect, rel=1e-12)
    # a square wave 0/1 (variance 1/4) reduced to +-0.05 around 0.5 (variance 0.0025): VRR 100
    sq = (np.arange(200) // 10) % 2 * 1.0
    out = 0.5 + 0.05 * np.where(sq > 0, 1.0, -1.0)
    assert variance_reduction_ratio(sq, out) == pytest.approx(100.0, rel=1e-12)
    assert variance_reduction_ratio(sq, np.full(200, 0.5)) == math.inf


def test_vrr_by_recirculation_for_a_batch_uses_f_times_one_minus_f():
    assert batch_input_variance(0.25) == pytest.approx(0.1875)
    with pytest.raises(ValueError, match="batch fraction"):
        batch_input_variance(1.0)
    # t_mean = 1 s, dt = 0.01: the amplitude of the outflow's oscillation halves every recirculation
    t = (np.arange(400) + 0.5) * 0.01
    amp = 0.4 * 0.5 ** np.floor(t)
    co = 0.25 + amp * np.sin(2 * np.pi * 5 * t)
    r = vrr_by_recirculation(t, co, t_mean=1.0, batch_fraction=0.25, count=np.full(400, 100.0))
    assert r["n_r"].tolist() == [1.0, 2.0, 3.0, 4.0]
    var_out = (0.4 * 0.5 ** np.arange(4)) ** 2 / 2  # var of A sin over whole periods
    assert r["vrr"] == pytest.approx(0.1875 / var_out, rel=1e-9)
    assert r["n_intervals"].tolist() == [100] * 4
    # counting noise of 100 particles per interval: c(1-c)/100 ~ 0.1875/100 at small amplitude
    assert r["var_sampling"][-1] == pytest.approx(0.1875 / 100, rel=0.02)
    # continuous input: the window variances of c_in
    ci = 0.5 + 0.5 * np.sign(np.sin(2 * np.pi * 2 * t))
    r2 = vrr_by_recirculation(t, co, t_mean=1.0, c_in=ci)
    assert r2["var_in"] == pytest.approx(np.full(4, 0.25), rel=1e-9)
    assert r2["vrr"] == pytest.approx(0.25 / var_out, rel=1e-9)


def test_by_recirculation_gives_window_means_of_a_series():
    t = np.linspace(0, 3.0, 301)
    rho = 600.0 + 10 * np.floor(t / 1.5)  # jumps at t = 1.5 s; t_mean 1.5 s
    r = by_recirculation(t, rho, t_mean=1.5)
    assert r["n_r"][-1] == pytest.approx(2.0)
    assert r["window_n_r"].tolist() == [1.0, 2.0]
    assert r["window_mean"] == pytest.approx([600.0, 610.0])


# ------------------------------------------------------------------ RTD
def test_plug_flow_rtd_peaks_at_theta_one_without_spread():
    # every tracer spends exactly t_mean = 2 s
    r = rtd_from_residence_times(np.full(1000, 2.0), t_mean=2.0, dtheta=0.02)
    assert r["peak"] == pytest.approx(1.0, abs=0.01) and r["mean"] == pytest.approx(1.0, abs=1e-12)
    assert r["variance"] < 1e-3 and r["theta_s"] == pytest.approx(1.0)
    assert r["F"][r["theta"] < 0.98].max() == 0.0 and r["F"][-1] == pytest.approx(1.0)
    # the same from a step of the input seen at the outlet: F jumps from 0 to 1 at t = 2 s
    t = np.arange(0.0, 4.0, 0.01)
    s = rtd_from_step(t, (t >= 2.0).astype(float))
    assert s["t_mean"] == pytest.approx(2.0, abs=0.01)
    assert s["peak"] == pytest.approx(1.0, abs=0.005) and s["variance"] < 1e-3
    assert s["theta_s"] == pytest.approx(1.0, abs=0.005) and s["t_s_over_t_d"] == pytest.approx(1.0, abs=0.005)


def test_perfectly_mixed_vessel_gives_exponential_e_within_two_percent():
    # Residence times of a perfectly mixed vessel are exponential.  With N = 2e6 samples and bins of
    # 0.1, the bin at theta = 2.95 holds N (e^-2.9 - e^-3.0) ~ 5300 samples: relative counting error
    # 1/sqrt(5300) = 1.4 %, bins nearer 0 less; the 2 % bound is 1.4 standard errors at theta = 3,
    # 6 or more below theta = 1.5.  The histogram's bias (bin average of e^-theta) is h^2/24 = 0.04 %.
    rng = np.random.default_rng(20240519)
    tau = 1.7
    r = rtd_from_residence_times(rng.exponential(tau, 2_000_000), t_mean=tau, dtheta=0.1)
    sel = r["theta"] < 3.0
    assert np.abs(r["E"][sel] / np.exp(-r["theta"][sel]) - 1).max() < 0.02
    assert r["mean"] == pytest.approx(1.0, abs=0.003) and r["variance"] == pytest.approx(1.0, abs=0.01)
    assert np.abs(r["F"][sel] - (1 - np.exp(-r["theta"][sel]))).max() < 0.005
    # from the analytic outflow of a pulse, c = exp(-t/tau), and of a step, c = 1 - exp(-t/tau)
    t = np.arange(0.0, 15 * tau, 0.005)
    p = rtd_from_pulse(t, np.exp(-t / tau))
    assert p["t_mean"] == pytest.approx(tau, rel=1e-4)
    # trapezoid normalisation error (dt/tau)^2/12 ~ 1e-6 and the tail beyond 15 tau, e^-15
    assert np.abs(p["E"] - np.exp(-p["theta"])).max() < 1e-4
    assert p["variance"] == pytest.approx(1.0, rel=1e-3) and p["peak"] == 0.0
    s = rtd_from_step(t, 1 - np.exp(-t / tau), t_mean=tau)
    sel = s["theta"] < 5
    assert np.abs(s["E"][sel] / np.exp(-s["theta"][sel]) - 1).max() < 0.02


def test_step_rtd_from_crossing_records_of_a_mixed_vessel():
    # A perfectly mixed vessel fed with tracer from t = 0: each particle leaving in interval k is a
    # tracer with probability F = 1 - exp(-t/tau).  2000 crossings per 0.01 s interval: the binomial
    # error of c is at most 0.5/sqrt(2000) = 0.011, so 0.05 is 4.5 standard errors.
    rng = np.random.default_rng(7)
    tau, n_per, dt = 0.5, 2000, 0.01
    t = np.repeat(np.arange(0.0, 3.0, dt), n_per) + rng.uniform(0, dt, 300 * n_per)
    tracer = rng.uniform(size=len(t)) < 1 - np.exp(-t / tau)
    c = outflow_concentration(t, np.full(len(t), 1e-5), tracer, dt, t_end=3.0)
    assert len(c["time"]) == 300 and (c["count"] == n_per).all()
    assert c["c_mass"] == pytest.approx(c["c_number"], rel=1e-12)  # equal masses
    r = rtd_from_step(c["time"], c["c_number"], t_mean=tau)
    assert np.abs(r["F"] - (1 - np.exp(-r["theta"]))).max() < 0.05
    # t_mean from the record, int (1 - F) dt: the noise averages out (and the record ends at 6 tau)
    assert rtd_from_step(c["time"], c["c_number"])["t_mean"] == pytest.approx(tau, rel=0.01)


# ------------------------------------------------------------------ convolution
def test_step_convolved_with_a_known_rtd_gives_f():
    tau = 2.0
    th = np.linspace(0, 20, 4001)
    t = np.arange(0.0, 12.0, 0.01)
    step = np.ones_like(t)
    c = convolve_rtd(t, step, th, np.exp(-th), tau)
    assert np.abs(c - (1 - np.exp(-t / tau))).max() < 1e-4
    # three tanks in series: E = 27/2 theta^2 e^(-3 theta), F = 1 - e^(-3 theta)(1 + 3 theta + 9/2 theta^2)
    E3 = 13.5 * th ** 2 * np.exp(-3 * th)
    c3 = convolve_rtd(t, step, th, E3, tau)
    q = t / tau
    assert np.abs(c3 - (1 - np.exp(-3 * q) * (1 + 3 * q + 4.5 * q ** 2))).max() < 1e-4
    # a step down from c_before = 1 to 0 is the complement
    c4 = convolve_rtd(t, np.zeros_like(t), th, E3, tau, c_before=1.0)
    assert np.abs(c4 + c3 - 1).max() < 1e-4


def test_sinusoid_through_an_exponential_rtd_has_the_analytic_amplitude_ratio():
    tau = 1.0
    th = np.linspace(0, 30, 6001)
    dt = 0.005
    t = np.arange(0.0, 40.0, dt)
    for period in (1.0, 2.5, 10.0):  # whole periods in the 20 s window
        w = 2 * np.pi / period
        c = convolve_rtd(t, 0.5 + 0.4 * np.sin(w * t), th, np.exp(-th), tau, c_before=0.5)
        late = t > 20.0  # transient e^(-t/tau) gone
        A = np.stack([np.sin(w * t[late]), np.cos(w * t[late]), np.ones(late.sum())], axis=1)
        (a, b, m), *_ = np.linalg.lstsq(A, c[late], rcond=None)
        assert math.hypot(a, b) / 0.4 == pytest.approx(1 / math.sqrt(1 + (w * tau) ** 2), rel=0.005)
        assert m == pytest.approx(0.5, abs=1e-4)
        assert variance_reduction_ratio(0.5 + 0.4 * np.sin(w * t[late]), c[late]) == pytest.approx(
            1 + (w * tau) ** 2, rel=0.01)


# ------------------------------------------------------------------ virtual tracers
def test_virtual_tracers_in_a_uniform_downward_field_give_plug_flow_at_h_over_v():
    v = 0.02
    vx, vy = np.zeros((27, 15)), np.full((27, 15), -v)
    h = 0.2
    r = virtual_tracer_rtd(XC, YC, vx, vy, release_line(XC, h, 200), y_outlet=0.0, t_mean=h / v, dtheta=0.01)
    assert r["n_arrived"] == 200 and r["n_stuck"] == 0 and r["n_late"] == 0
    assert np.nanmax(np.abs(r["t_exit"] - h / v)) < 1e-9 * h / v
    assert r["peak"] == pytest.approx(1.0, abs=0.01) and r["variance"] < 1e-3
    # released over the whole filled area (uniform weights): exit times uniform on [0, H/v], the
    # washout of the content (1 - F(theta) = 1 for plug flow below theta = 1).  The release lattice
    # has 4 x 4 points per bin: with theta bins of one bin height (1/27) each holds 4 of its rows.
    a = virtual_tracer_rtd(XC, YC, vx, vy, release_area(XC, YC, vx, vy, 4000), y_outlet=0.0, t_mean=H / v,
                           weights="uniform", dtheta=1 / 27)
    assert a["n_arrived"] == a["n_released"] == 27 * 15 * 16
    assert a["E"][:27] == pytest.approx(np.ones(27), rel=1e-9) and a["E"][27:].max() == 0.0
    assert a["mean"] == pytest.approx(0.5, rel=1e-9) and a["variance"] == pytest.approx(1 / 12, rel=1e-3)


def test_flux_weighted_virtual_tracers_have_the_mean_residence_time_volume_over_flow_rate():
    # a sheared downward field, speed rising linearly from 0.01 m/s at x = 0.005 to 0.03 at 0.145
    # (exact in bilinear interpolation; constant in the outer half bins).  Material crossing the line
    # y = h has mean residence time V / Q = h W / int v dx (the mean-residence-time theorem), which
    # the flux weights give; uniform weights over-weight the slow side: mean of h / v(x) over x.
    v = 0.01 + 0.02 * (XC - XC[0]) / (XC[-1] - XC[0])
    vy = np.tile(-v, (27, 1))
    xs = np.concatenate([[0.0], XC, [W]])
    vs = np.concatenate([[v[0]], v, [v[-1]]])
    Q = np.trapezoid(vs, xs)
    h = 0.2
    start = release_line(XC, h, 3000)
    r = virtual_tracer_rtd(XC, YC, np.zeros_like(vy), vy, start, y_outlet=0.0, t_mean=h * W / Q)
    assert r["n_arrived"] == 3000 and r["mean"] == pytest.approx(1.0, abs=1e-4)
    assert r["theta_s"] == pytest.approx(Q / (W * 0.03), rel=1e-6)  # the fastest streamline first
    u = virtual_tracer_rtd(XC, YC, np.zeros_like(vy), vy, start, y_outlet=0.0, t_mean=h * W / Q, weights="uniform")
    expect = np.mean(h / np.interp(start[:, 0], xs, vs)) / (h * W / Q)
    assert u["mean"] == pytest.approx(expect, rel=1e-6) and u["mean"] > 1.05


def test_stuck_tracers_in_a_stagnant_side_zone_are_counted_and_excluded():
    # moving at 0.02 m/s left of x = 0.1 (bin centres up to 0.095), at rest from the bin centred at
    # 0.105: bilinear speed between 0.095 and 0.105 falls linearly, below 1 % of 0.02 for
    # x > 0.105 - 0.01 * 0.01 = 0.1049.  Tracers move straight down, so the stuck ones are exactly those.
    vy = np.full((27, 15), -0.02)
    vy[:, XC > 0.1] = 0.0
    vy[20:, :] = np.nan  # empty above 0.2 m (taken as at rest)
    start = release_line(XC, 0.15, 300)
    r = virtual_tracer_rtd(XC, YC, np.zeros_like(vy), vy, start, y_outlet=0.0)
    expect_stuck = int((start[:, 0] > 0.105 - 1e-4).sum())
    assert r["n_stuck"] == expect_stuck == 90 and r["n_arrived"] == 210 and r["n_late"] == 0
    # arrivals: the band 0.095 < x < 0.1049 moves more slowly (interpolated speed): a spread, not stuck
    fast = start[:, 0] < 0.095
    assert r["t_exit"][fast] == pytest.approx(np.full(fast.sum(), 0.15 / 0.02), rel=1e-9)
    assert np.isnan(r["t_exit"][r["stuck"]]).all()
    # a tracer released in the empty region is stuck too (empty bins do not move)
    top = advect_tracers(XC, YC, np.zeros_like(vy), vy, [[0.05, 0.25]], y_outlet=0.0)
    assert top["n_stuck"] == 1


# ------------------------------------------------------------------ flow pattern
def _field(moving):
    vy = np.where(moving, -0.02, 0.0)
    return vy


def test_flow_pattern_of_three_synthetic_fields():
    X, Y = np.meshgrid(XC, YC)
    # uniform: mass flow
    m = classify_flow_pattern(XC, YC, _field(np.ones_like(X, bool)))
    assert m["pattern"] == "mass" and m["stagnant_fraction"] == 0.0 and m["h_t_over_H"] == pytest.approx(0.0)
    assert m["fill_height"] == pytest.approx(H)
    # stagnant corners: triangles from the outlet edges (x = 0.055, 0.095) to the side walls at y = 0.08
    corner = (Y < 0.08 * (1 - X / 0.055)) | (Y < 0.08 * (1 - (W - X) / 0.055))
    s = classify_flow_pattern(XC, YC, _field(~corner), fraction=0.05)
    assert s["pattern"] == "semi-mass"
    # the row centred at 0.055 m has two stagnant bins at each wall (boundary 1.5 bins from the wall
    # centre: not reaching), the row at 0.065 m one (within the one-bin tolerance): h_t = 0.06 m
    assert s["h_t"] == pytest.approx(0.06) and s["h_t_over_H"] == pytest.approx(0.06 / H)
    assert s["stagnant_fraction"] == pytest.approx(corner.mean(), abs=1e-12)
    # narrow channel (50 mm of 150 mm) up to the surface: internal flow
    channel = np.abs(X - W / 2) < 0.025
    i = classify_flow_pattern(XC, YC, _field(channel), fraction=0.01)
    assert i["pattern"] == "internal" and math.isnan(i["h_t"])
    assert i["stagnant_fraction"] == pytest.approx(10 / 15, abs=1e-12)
    assert np.nanmax(i["width_fraction"]) == pytest.approx(0.05 / W, abs=CELL / W)
    # a channel that reaches the walls only in the upper 30 % is internal too (h_t / H > 0.5)
    late = channel | (Y > 0.19)
    assert classify_flow_pattern(XC, YC, _field(late))["pattern"] == "internal"


# ------------------------------------------------------------------ results file
def test_blending_arrays_round_trip_through_the_results_file(tmp_path):
    t = np.arange(5) * 0.1
    rtd = rtd_from_residence_times(np.full(10, 1.0))
    tree = blending_arrays(t, np.linspace(0, 0.4, 5), 12.5, rtd=rtd, flow_pattern={"pattern": "semi-mass"},
                           attrs={"t_mean": 3.0})
    with ResultsFile(tmp_path / "results.h5") as rf:
        rf.write_measurements(None, tree)
    back = read_measurements(tmp_path / "results.h5", with_attrs=True)
    assert back["blending"]["vrr"] == 12.5 and back["blending"]["@attrs"]["t_mean"] == 3.0
    assert back["blending"]["concentration_out"] == pytest.approx([0, 0.1, 0.2, 0.3, 0.4])
    assert back["rtd"]["E"] == pytest.approx(rtd["E"]) and back["flow_pattern"] == "semi-mass"
    with pytest.raises(ValueError, match="flow_pattern"):
        blending_arrays(t, t, 1.0, flow_pattern="funnel")


def test_bad_input_is_refused_with_a_message():
    t = np.arange(10) * 0.1
    with pytest.raises(ValueError, match="either c_in"):
        vrr_by_recirculation(t, t, 0.5)
    with pytest.raises(ValueError, match="uniformly spaced"):
        convolve_rtd(t ** 2, t, [0.0, 1.0], [1.0, 1.0], 1.0)
    with pytest.raises(ValueError, match="same time base"):
        variance_reduction_ratio(t, t[:5])
    with pytest.raises(ValueError, match="unequal length"):
        outflow_concentration(t, t[:3], t, 0.1)
    with pytest.raises(ValueError, match="no virtual tracer reached"):
        virtual_tracer_rtd(XC, YC, np.zeros((27, 15)), np.full((27, 15), -0.02), [[0.05, 0.1]], y_outlet=0.0,
                           t_max=1.0)
