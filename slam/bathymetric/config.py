"""Named parameters of the bathymetric PF-SLAM filters, with their source (paper section and
equation, or the resolution letter A1-A30 of the reading notes where the paper is silent)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["BathyConfig"]


class BathyConfig(BaseModel):
    """All lengths in metres, variances in m^2, windows counted in pings (swaths)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    n_particles: int = Field(400, ge=1, description="N (Sec. V-A)")
    radius_m: float = Field(10.0, gt=0, description="R, overlap radius (Sec. V-A)")
    sigma_c2: float = Field(1.0, ge=0, description="jitter floor sigma_c^2 per step, eq. (3)")
    jitter_a: float = Field(1.0, ge=0, description="A, extra jitter after resampling, eq. (3)")
    jitter_b: int = Field(10, ge=0, description="B, hold-off steps of A, eq. (3) (Fig. 2; A8)")
    jitter_c: float = Field(10.0, gt=0, description="C, decay steps of A, eq. (3) (Fig. 2; A8)")
    omega_sigma_m: float = Field(0.01, ge=0, description="omega std per axis, eq. (2) (A9)")
    t_p: int = Field(20, ge=1, description="T_p, Pmap swaths (Sec. V-A)")
    t_m: int = Field(20, ge=2, description="T_m, Mmap swaths (Sec. V-A)")
    t_l: int = Field(60, ge=1, description="t_l, recent pings excluded from the overlap test (A10)")
    mse_max_m2: float = Field(0.5, gt=0, description="MSE gate, eq. (6) (Sec. V-A)")
    min_valid_fraction: float = Field(
        0.25, gt=0, le=1, description="I threshold as a share of the Mmap points (A2)"
    )
    sigma_s_m: float = Field(
        0.15,
        gt=0,
        description="sigma_s, std of eq. (8) (A3): the Pmap-vs-Mmap depth residual at the true "
        "alignment, measured 0.12 m (bathy_survey) / 0.15 m (bathy_sandwaves) by "
        "benchmarks/diag_bathy_residual.py (was 0.3: 2x too wide, weights too flat to move "
        "the cloud at a crossing)",
    )
    sigma_map2: float = Field(
        0.1,
        ge=0,
        description="sigma^2_pmap = sigma^2_mmap, map-error variance of eqs. (11)-(12) (A4)",
    )
    unmatched_weight: Literal["uniform", "neutral", "gate"] = Field(
        "neutral",
        description="weight of particles outside R or failing the gates: 'uniform' = 1/N as "
        "written (Sec. III-C; A5); 'gate' (ours) = w_gate = 1 / sqrt(2 pi (sigma_s^2 + "
        "mse_max)), the expected eq. (7) weight of a match whose MSE is at the gate; "
        "'neutral' (ours, default) = the mean matched weight outside R (no evidence) and "
        "min(w_gate, mean) inside R but gated out (a poor fit). With 'gate' or 'neutral' "
        "alpha flattens towards w_gate. 1/N makes any match N x likelier than none, so the "
        "sharpness of a crossing's multiplied weights grows with N; 'gate' rewards every "
        "passing match, so long mediocre overlaps outweigh short good ones",
    )
    min_matched_fraction: float = Field(
        0.1,
        ge=0,
        le=1,
        description="weights count only when at least this share of the particles passes the "
        "overlap test and the gates; below it every weight is 1/N (ours: a few outlier "
        "particles touching an adjacent line are not evidence about the cloud)",
    )
    alpha_towards: Literal["one", "fallback"] = Field(
        "fallback",
        description="what alpha = 0 flattens a weight to: 'one' as eq. (9) is written "
        "(w^alpha), or 'fallback' = the 1/N of unmatched particles, "
        "w^alpha (1/N)^(1 - alpha) (ours: with the 1/N floor of A5, w^0 = 1 would make "
        "featureless matches 400x likelier than no match at all)",
    )
    use_alpha: bool = Field(True, description="weight indexation, eqs. (9)-(12)")
    idw_power: float = Field(2.0, gt=0, description="IDW power p (A1)")
    idw_k: int = Field(8, ge=1, description="IDW neighbours (A1)")
    idw_radius_m: float = Field(4.0, gt=0, description="IDW search radius (A1: ~2 x spacing)")
    idw_min_neighbours: int = Field(3, ge=1, description="neighbours for a valid point (A1)")
    pmap_beam_stride: int = Field(2, ge=1, description="every n-th beam in Pmap (speed; ours)")
    mmap_beam_stride: int = Field(4, ge=1, description="every n-th beam in Mmap (speed; ours)")
    mmap_ping_stride: int = Field(2, ge=1, description="every n-th swath in Mmap (speed; ours)")
    neff_fraction: float = Field(2 / 3, gt=0, le=1, description="resample if Neff < f N, eq. (13)")
    min_ramp_pings: int = Field(
        0,
        ge=0,
        description="ours, 0 = eq. 15 as written (default): spread an accepted correction over "
        "at least "
        "this many recent pings (T_p) even when earlier loops cover them; literally a repeated "
        "closure moves only the newest ping, a kink inside the next Pmaps",
    )
    closure: Literal["resampling", "crossing"] = Field(
        "crossing",
        description="what one loop closure is: 'resampling' = every resampling of eq. (13) as "
        "written (a crossing then makes many small consecutive ones); 'crossing' (ours) = the "
        "weights of consecutive matched pings are multiplied (log-summed) and the particles "
        "resampled once, when the crossing ends (crossing_gap_pings without any particle in "
        "R of the old track) or after crossing_max_pings, if the accumulated Neff < f N",
    )
    closure_estimate: Literal["mean", "mode"] = Field(
        "mode",
        description="'crossing': what the closure's resampling draws from: 'mean' = the whole "
        "weighted cloud (its centroid can sit between modes, where no particle is), 'mode' "
        "(ours, default) = only the particles within mode_radius_m of the particle whose "
        "neighbourhood holds the most weight (what the paper's repeated resamplings of one "
        "crossing converge to)",
    )
    mode_radius_m: float = Field(
        3.0, gt=0, description="'mode': radius of the dominant mode (m; ours, = lccd_tau_m)"
    )
    min_mode_ratio: float = Field(
        3.0,
        ge=1,
        description="'crossing' + 'mode' (ours): a crossing whose accumulated Neff < f N "
        "closes only when its dominant mode holds at least this many times the weight of the "
        "heaviest disjoint mode_radius_m neighbourhood (filters.mode_ratio; both are "
        "estimates of posterior masses, so the rule does not depend on N); below it the "
        "crossing's weights are dropped as if Neff >= f N: no resampling, no closure. "
        "1 = off (eq. 13 alone)",
    )
    mode_apart_m: float = Field(
        10.0,
        gt=0,
        description="'min_mode_ratio': alternatives to the dominant mode are mode_radius_m "
        "neighbourhoods centred farther than this (m; ours): 2 x the measured width of a "
        "crossing's likelihood (std 5.1 m, median over the closures of the diagnosed run), "
        "so the shoulder of the same peak is not counted as a rival closure",
    )
    min_mode_odds: float = Field(
        0.0,
        ge=0,
        description="'min_mode_ratio' too (ours): the crossing closes only when the weight "
        "within mode_apart_m of the dominant mode's centre is at least this many times all "
        "the weight farther away (filters.mode_odds: the posterior odds that the closure is "
        "where the mode says rather than anywhere else; 1 = more likely than not). The "
        "rival ratio alone passes a mode holding 4 % of the weight when each rival holds "
        "less still. 0 = off",
    )
    crossing_gap_pings: int = Field(
        5, ge=1, description="'crossing': pings without overlap that end a crossing (ours)"
    )
    jitter_in_crossing: bool = Field(
        False,
        description="'crossing': add the eq. (3) jitter between the matched pings of a "
        "crossing too (ours, default off: the weights of a crossing are multiplied, so each "
        "particle must keep one offset through it; the DR error moves ~0.02 m per ping, the "
        "jitter 1 m)",
    )
    crossing_max_pings: int = Field(
        40, ge=1, description="'crossing': longest crossing before a closure is made (ours)"
    )
    lccd: bool = Field(True, description="loop-closure consistency determination (Sec. IV-B)")
    lccd_mode: Literal["pool", "veto", "parts", "drift", "oracle"] = Field(
        "veto",
        description="how LCCD decides: 'pool' = Sec. IV-B, a closure needs a partner within "
        "lccd_tau_m among all closures so far (the first is always rejected, a loop disjoint "
        "from all others never agrees); 'veto' (ours, default) = the same clustering, but a "
        "closure without a partner is rejected only when an accepted closure comparable with "
        "it (not disjoint) disagrees; 'parts' (ours; closure = 'crossing') = the modes of "
        "lccd_parts successive parts of the crossing's own pings must agree; 'drift' (ours, "
        "PCM-style) = the largest set of closures whose DR drift rates (eq. 25 per ping) "
        "agree pairwise under the drift model (drift_spec_m, drift_walk_m, closure_sigma_m, "
        "drift_gate_chi2; disjoint closures are comparable) and fit the spec; 'oracle' "
        "(DIAGNOSTIC ONLY, never a default, needs the truth: evaluate.run_filter hands it "
        "over) = accept a closure iff its truth label (A22, loops.loop_valid) says valid, the "
        "bound of what any closure test can do on a scenario",
    )
    lccd_overturn: bool = Field(
        True,
        description="'veto' (ours): an accepted closure with partners (its cluster at "
        "lccd_tau_m holds 2 or more closures) overturns earlier accepted closures comparable "
        "with it, outside its cluster, whose own cluster is smaller; their corrections are "
        "undone on the mean trajectory and the particles (the ramp of eqs. 15-22 is additive). "
        "Without it, a weak wrong first closure accepted by 'veto' vetoes the right ones after it",
    )
    lccd_pending: bool = Field(
        False,
        description="'veto' (ours; A17's 'singleton => invalid' made revisable): a closure "
        "that no accepted closure can judge (the first, or one disjoint from every accepted "
        "one) is held pending: its correction is not applied and the particles are restored, "
        "until a later closure falls in its lccd_tau_m cluster (that one is applied, the "
        "pending one counts as accepted) or an accepted closure comparable with it disagrees "
        "(it stays rejected). False = accept it as 'veto' does",
    )
    lccd_replace: bool = Field(
        True,
        description="'veto' (ours): a closure vetoed only by accepted closures that no other "
        "accepted closure agrees with (lone, e.g. the first) replaces them when its mode ratio "
        "(min_mode_ratio's evidence) is larger: between two contradicting closures and nothing "
        "else to judge them, the one the posterior supports more; the replaced ones are undone "
        "as lccd_overturn does. Without it a weak wrong first closure vetoes every stronger "
        "right one after it until two of them agree (default on: 8 runs, session 5)",
    )
    lccd_parts: int = Field(2, ge=2, description="'parts': parts a crossing is split into")
    drift_estimate: bool = Field(
        True,
        description="ours (False = the paper; default since session 6: bathy_survey N = 100, "
        "20 runs, 12.0 -> 3.9 m): estimate the DR bias (m per ping per axis) "
        "from the accepted closures' drift rates (loops.DriftModel.estimate: their weighted "
        "mean with the spec's zero-mean prior), remove it from the DR step in prediction "
        "(eq. 2 with u - b), and re-anchor the stretch before the first accepted loop "
        "interval, which no closure corrects (eqs. 15-22 move only [t_loop, t]) and which "
        "carries the whole DR drift since the known start: it moves by -b t, everything "
        "after it rigidly by -b t_first",
    )
    drift_frame: Literal["world", "body"] = Field(
        "world",
        description="drift_estimate's model (ours): 'world' = a DR bias constant in the world "
        "frame, m per ping per axis (eq. 28's; loops.DriftModel); 'body' (issue 28) = an "
        "INS + DVL error that turns with the vehicle: each DR step u is (1 + s) R(psi) times "
        "the true one (DVL scale factor s, heading error psi = DVL/INS misalignment + INS "
        "heading bias + a Gauss-Markov drift), estimated from the accepted closures by "
        "filters.BodyDrift (psi piecewise constant over body_block_pings, a Gaussian-process "
        "prior from the body_* spec)",
    )
    body_scale_sigma: float = Field(
        0.005, ge=0, description="'body': prior std of the DVL scale factor s (1; the spec)"
    )
    body_heading_sigma_deg: float = Field(
        0.5,
        ge=0,
        description="'body': prior std of the constant heading error (deg): misalignment + "
        "heading bias (both rotate every DR step alike in 2-D)",
    )
    body_gm_sigma_deg: float = Field(
        1.0, ge=0, description="'body': std of the Gauss-Markov heading drift (deg)"
    )
    body_gm_tau_pings: float = Field(
        900.0, gt=0, description="'body': time constant of the heading drift (pings)"
    )
    body_block_pings: int = Field(
        60, ge=1, description="'body': pings over which psi is held constant (estimation grid)"
    )
    heading_bias: bool = Field(
        False,
        description="MTM-PF, ours (issue 28; NOT the paper's, whose A30 takes the heading as "
        "error-free): each particle carries a heading offset b (rad) of the navigation "
        "(INS heading = true + b) that rotates its DR increment by -b in prediction (eq. 2) "
        "and its Pmap by -b about the vehicle in the match (eqs. 4-5); the stored swath is "
        "rotated by the cloud's mean -b. Resampling keeps each particle's b; its estimate and "
        "spread are logged per ping (MTMPF.heading_log). False = position only (as before)",
    )
    heading_sigma0_deg: float = Field(
        0.5, ge=0, description="'heading_bias': initial spread of b (deg, std; mean 0)"
    )
    heading_walk_deg: float = Field(
        0.01,
        ge=0,
        description="'heading_bias': random walk of b per ping (deg, std per step); with "
        "heading_tau_pings > 0 the driving noise of a Gauss-Markov b of that stationary std "
        "sqrt(walk^2 / (1 - a^2)), a = exp(-1 / tau), as sim_devices/ins.py HEADING_ERROR",
    )
    heading_tau_pings: float = Field(
        0.0,
        ge=0,
        description="'heading_bias': Gauss-Markov correlation time of b (pings; 0 = a pure "
        "random walk)",
    )
    drift_min_agree: int = Field(
        2,
        ge=1,
        description="drift_estimate (ours): the bias is estimated from the largest set of "
        "accepted closures that fit the spec and agree pairwise under the drift model "
        "(loops.DriftModel.largest_agreeing), and only once that set holds at least this "
        "many closures (0 bias until then; the re-anchor is retroactive, so waiting costs "
        "only the prediction in between). 1 = every accepted closure, unfiltered: a lone false "
        "closure then bends the bias and the re-anchor (bathy_survey N = 50, 20 runs: 51.0 m "
        "with 1, 32.9 m with 2, 38.5 m without drift_estimate)",
    )
    drift_spec_m: float = Field(
        0.012,
        gt=0,
        description="drift model (ours): std per axis of the DR bias before any closure (m "
        "per ping), the navigation spec; eq. (28)'s m_e, the DR the paper simulates",
    )
    drift_walk_m: float = Field(
        3.3e-5,
        ge=0,
        description="drift model (ours): random walk of the DR bias per sqrt(ping) per axis "
        "(m); eq. (28) holds it constant (0); 3.3e-5 lets it wander 2 mm per ping (1/6 of "
        "m_e) in an hour, a slowly varying current or DVL / INS bias",
    )
    closure_sigma_m: float = Field(
        2.0,
        gt=0,
        description="drift model (ours): alignment error of a valid closure per axis (m): "
        "the loop-interval error left by the closures labelled valid (A22) has a per-axis "
        "RMS of 1.92 m (109 closures, bathy_sandfield, N = 100, 20 runs, LCCD off; "
        "benchmarks/diag_bathy_drift.py, docs/results/bathymetric/s6_probe)",
    )
    drift_gate_chi2: float = Field(
        9.21,
        gt=0,
        description="drift model (ours): chi-square gate (2 dof) of the pairwise and spec "
        "tests; 9.21 = 99 %",
    )
    lccd_tau_m: float = Field(3.0, gt=0, description="clustering cut distance (A15)")
    lccd_linkage: str = Field("single", description="scipy linkage method (A15)")
    lccd_disjoint_m: float = Field(1e6, gt=0, description="distance of disjoint loops (A14)")
    grid_cell_m: float = Field(2.0, gt=0, description="DEM cell of the final map (ours)")
    bpslam_weights: Literal["accumulate", "replace"] = Field(
        "accumulate",
        description="BPSLAM's weights between resamplings: 'accumulate' (issue 28, Barkby "
        "2011/2012 and any SIR filter) = each ping's likelihood multiplies the previous "
        "weight, reset to 1/N by a resampling; 'replace' = the weight is the latest ping's "
        "likelihood (the rule the paper gives its own method, A6; what BPSLAM did before "
        "issue 28)",
    )
    bpslam_sigma_c2: float = Field(
        1.0,
        ge=0,
        description="BPSLAM's jitter per ping (m^2, its eq. 3 floor; BPSLAM has no A term): "
        "1 = the paper's sigma_c^2; the held-out protocol tunes its own value on the tuning "
        "seeds (docs/results/bathymetric/heldout/frozen.json)",
    )
