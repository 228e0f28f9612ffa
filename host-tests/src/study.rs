//! The Monte Carlo study behind the paper's Table I and Table II, shared by
//! the `paper-tables` binary (100 and 101 runs) and the fast acceptance test
//! `tests/paper_relations.rs` (fewer runs).
//!
//! This module runs the core (`mag_cal_core::calibrate`) and the core's
//! alignment and heading smoother (the code under test in scenario H);
//! everything it judges the results by comes from [`crate::metrics`].

use std::hint::black_box;
use std::time::Instant;

use mag_cal_core::{calibrate, Config, Fit, Method};
use nalgebra::{Matrix3, Vector3};

use crate::metrics::{self, Errors, Estimate};
use crate::scenarios::{HeadingScenario, Scenario, Truth};

/// The methods in the order of the paper's Table I (`Method::ALL`).
pub const METHODS: [Method; 5] = Method::ALL;

/// Labels of [`METHODS`] as the tables print them.
pub const LABELS: [&str; 5] = ["LS9", "subMLE", "ADC1", "ADC2", "ADC2-iter"];

/// Index of a method in [`METHODS`].
pub fn idx(m: Method) -> usize {
    METHODS
        .iter()
        .position(|&x| x == m)
        .expect("method in Method::ALL")
}

/// The configuration of every run: the library's defaults (LS9 start, pass
/// cap 50, iteration cap 50), only the method changes.
pub fn config(method: Method) -> Config {
    Config {
        method,
        ..Config::default()
    }
}

/// The calibration as the metrics see it.
pub fn estimate(fit: &Fit<f64>) -> Estimate {
    Estimate {
        b: fit.calibration.hard_iron_vector(),
        w: fit.calibration.soft_iron_matrix(),
    }
}

/// A flop-proportional cost of one `calibrate` call, per sample, from the
/// passes the report counts: a deterministic stand-in for wall-clock time
/// where timing is unreliable (tests on a shared machine).
///
/// Every call makes three fixed passes: validation and centring (about 12
/// flops a sample), the 35 moments (about 120: 9 powers, 35 products of
/// three and the sums), and the last pass with the final calibration: its
/// radial error (about 30: `W (y - b)`, `|u|^2`, a reciprocal square root,
/// the square) and, except for ADC1 and ADC2, which take them from their
/// artificial-data pass, the direction sums of the coverage checks (about
/// 20). Then `passes` method passes: the artificial-data statistics of
/// ADC1, ADC2 and each iterated-ADC2 step (about 70: `W (y - b)`, one
/// reciprocal square root, 24 sums), or one subMLE cost-and-gradient
/// evaluation (about 140: `M e`, `z`, `w`, the symmetric 3x3 gradient
/// update and the centre's). Counted from the core's loops; the small
/// O(1) solves are neglected (a few thousand flops, against 2.4e5 for a
/// whole ADC2 run at n = 1000).
pub fn flop_proxy(method: Method, passes: u32) -> f64 {
    const FIXED: f64 = 12.0 + 120.0 + 30.0;
    let directions = match method {
        Method::Adc1 | Method::Adc2 => 0.0,
        _ => 20.0,
    };
    let per_pass = match method {
        Method::SubMle => 140.0,
        Method::Ls => 0.0,
        _ => 70.0,
    };
    FIXED + directions + per_pass * f64::from(passes)
}

/// Per-run records of one method in one scenario.
#[derive(Clone, Debug, Default)]
pub struct MethodRuns {
    /// The errors of every run.
    pub errors: Vec<Errors>,
    /// Wall-clock seconds of `calibrate` (the fastest of the repeats).
    pub seconds: Vec<f64>,
    /// `report.passes`.
    pub passes: Vec<u32>,
    /// `report.iterations`.
    pub iterations: Vec<u32>,
    /// [`flop_proxy`] of each run.
    pub flops: Vec<f64>,
    /// Runs whose report carried a warning.
    pub warned: usize,
}

impl MethodRuns {
    /// One metric of every run.
    pub fn metric(&self, f: impl Fn(&Errors) -> f64) -> Vec<f64> {
        self.errors.iter().map(f).collect()
    }
}

/// The study of one scenario.
#[derive(Clone, Debug)]
pub struct ScenarioStudy {
    /// The scenario.
    pub scenario: Scenario,
    /// Per method, in [`METHODS`] order.
    pub methods: Vec<MethodRuns>,
    /// Largest gauge-free ADC1-ADC2 difference over the runs:
    /// `max|dM| / max|M|` and `|db| / rho`.
    pub adc1_vs_adc2: (f64, f64),
}

impl ScenarioStudy {
    /// Runs.
    pub fn runs(&self) -> usize {
        self.methods[0].errors.len()
    }

    /// Mean e_S of a method.
    pub fn mean_es(&self, m: Method) -> f64 {
        metrics::mean_std(&self.methods[idx(m)].metric(|e| e.e_s)).0
    }

    /// `mean e_S(a) / mean e_S(b)` and its standard error (paired runs).
    pub fn es_ratio(&self, a: Method, b: Method) -> (f64, f64) {
        metrics::ratio_of_means(
            &self.methods[idx(a)].metric(|e| e.e_s),
            &self.methods[idx(b)].metric(|e| e.e_s),
        )
    }

    /// Median over the runs of `seconds(m) / seconds(ADC2)` of the same run.
    pub fn time_ratio_to_adc2(&self, m: Method) -> f64 {
        let a = &self.methods[idx(m)].seconds;
        let d = &self.methods[idx(Method::Adc2)].seconds;
        metrics::median(&a.iter().zip(d).map(|(x, y)| x / y).collect::<Vec<_>>())
    }

    /// Median over the runs of `(seconds(m) - seconds(LS9)) /
    /// (seconds(ADC2) - seconds(LS9))`: the cost of what a method adds to
    /// the LS9 fit they all start with, relative to ADC2's.
    pub fn time_beyond_ls_ratio(&self, m: Method) -> f64 {
        let a = &self.methods[idx(m)].seconds;
        let d = &self.methods[idx(Method::Adc2)].seconds;
        let l = &self.methods[idx(Method::Ls)].seconds;
        let r: Vec<f64> = a
            .iter()
            .zip(d)
            .zip(l)
            .map(|((x, y), z)| (x - z) / (y - z))
            .collect();
        metrics::median(&r)
    }

    /// Median over the runs of `flops(m) / flops(ADC2)` of the same run.
    pub fn flop_ratio_to_adc2(&self, m: Method) -> f64 {
        let a = &self.methods[idx(m)].flops;
        let d = &self.methods[idx(Method::Adc2)].flops;
        metrics::median(&a.iter().zip(d).map(|(x, y)| x / y).collect::<Vec<_>>())
    }
}

/// Times `calibrate` `repeats` times and keeps the fastest (the least
/// disturbed by the rest of the machine); returns the fit and the seconds.
fn timed_fit(samples: &[[f64; 3]], cfg: &Config, repeats: usize) -> (Fit<f64>, f64) {
    let mut best = f64::INFINITY;
    let mut fit = None;
    for _ in 0..repeats.max(1) {
        let t0 = Instant::now();
        let f = calibrate::<f64, _>(black_box(samples), black_box(cfg));
        let dt = t0.elapsed().as_secs_f64();
        best = best.min(dt);
        fit = Some(black_box(f));
    }
    let fit = fit
        .expect("at least one repeat")
        .unwrap_or_else(|e| panic!("{:?} refused a simulated run: {e:?}", cfg.method));
    (fit, best)
}

/// Runs `runs` Monte Carlo runs of scenario `s` with every method.
/// `repeats`: timing repeats per call (1 when timing does not matter).
/// The order of the methods rotates from run to run, so no method is
/// always the first to touch the freshly generated samples.
pub fn run_scenario(s: &Scenario, runs: usize, repeats: usize) -> ScenarioStudy {
    let truth = Truth::paper();
    let mut methods = vec![MethodRuns::default(); METHODS.len()];
    let mut adc1_vs_adc2 = (0.0f64, 0.0f64);
    for run in 0..runs {
        let data = s.generate(&truth, run);
        let mut fits: Vec<Option<Fit<f64>>> = vec![None; METHODS.len()];
        for k in 0..METHODS.len() {
            let i = (k + run) % METHODS.len();
            let m = METHODS[i];
            let (fit, secs) = timed_fit(&data.samples, &config(m), repeats);
            let rec = &mut methods[i];
            rec.errors
                .push(metrics::evaluate(&estimate(&fit), &truth, &data.dirs));
            rec.seconds.push(secs);
            rec.passes.push(fit.report.passes);
            rec.iterations.push(fit.report.iterations);
            rec.flops.push(flop_proxy(m, fit.report.passes));
            rec.warned += usize::from(!fit.report.warnings.is_empty());
            fits[i] = Some(fit);
        }
        let e1 = estimate(fits[idx(Method::Adc1)].as_ref().expect("ADC1 fit"));
        let e2 = estimate(fits[idx(Method::Adc2)].as_ref().expect("ADC2 fit"));
        let (dm, db) = metrics::gauge_free_distance(&e1, &e2);
        adc1_vs_adc2 = (adc1_vs_adc2.0.max(dm), adc1_vs_adc2.1.max(db));
    }
    ScenarioStudy {
        scenario: *s,
        methods,
        adc1_vs_adc2,
    }
}

/// Rows of Table II besides the raw readings: every method.
pub const HEADING_METHODS: [Method; 5] = METHODS;

/// Smoothing window of Table II's "ADC2 smooth" row (the paper's optimum,
/// the core's `DEFAULT_WINDOW`).
pub const SMOOTH_WINDOW: usize = 15;

/// Largest window of the sweep (the paper's 67).
pub const MAX_WINDOW: usize = 67;

/// The window sweep: every odd window from 3 to 67 (odd, so the window has
/// a centre sample and the delay-compensated comparison is exact).
pub fn sweep_windows() -> Vec<usize> {
    (3..=MAX_WINDOW).step_by(2).collect()
}

/// Mean absolute heading errors (degrees) of one smoothed heading sequence:
/// `centred` compares the output of a trailing window of `w` samples with
/// the true heading at the window's centre (the filter's group delay of
/// `(w - 1) / 2` samples treated as latency), `causal` with the true heading
/// of the newest sample (the delay counted as error). `naive_centred`: the
/// arithmetic mean of the raw degrees instead of the circular mean (what
/// the design document forbids), against the window centre.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Smoothed {
    /// Against the window centre.
    pub centred: f64,
    /// Against the newest sample.
    pub causal: f64,
    /// Arithmetic mean of degrees, against the window centre.
    pub naive_centred: f64,
}

/// Results of scenario H.
#[derive(Clone, Debug, Default)]
pub struct HeadingStudy {
    /// Runs used for the statistics (all but the alignment run).
    pub runs: usize,
    /// Mean |heading error| of the raw readings, per run.
    pub raw: Vec<f64>,
    /// Mean |heading error| with the true calibration, `K^-1 (y - bias)`,
    /// per run: the noise floor no calibration can beat.
    pub truth: Vec<f64>,
    /// Per method ([`HEADING_METHODS`] order): mean |heading error| per run.
    pub methods: Vec<Vec<f64>>,
    /// Per method: seconds of `calibrate` per run (all runs).
    pub seconds: Vec<Vec<f64>>,
    /// Per method: runs whose report carried a warning (all runs).
    pub warned: Vec<usize>,
    /// Per method: the alignment fitted on the first run.
    pub alignment: Vec<Matrix3<f64>>,
    /// Windows of the sweep.
    pub windows: Vec<usize>,
    /// ADC2, smoothed: per window, per run.
    pub sweep: Vec<Vec<Smoothed>>,
    /// Largest difference (degrees) between the core's smoother and the
    /// independent [`metrics::circular_moving_average`].
    pub smoother_check: f64,
    /// Largest difference between the core's and the metrics' Procrustes
    /// rotations (max abs entry).
    pub procrustes_check: f64,
}

impl HeadingStudy {
    /// Mean over runs of the raw error.
    pub fn raw_mean(&self) -> f64 {
        metrics::mean_std(&self.raw).0
    }

    /// Mean over runs of the true calibration's error (the noise floor).
    pub fn truth_mean(&self) -> f64 {
        metrics::mean_std(&self.truth).0
    }

    /// Mean over runs for a method.
    pub fn mean(&self, m: Method) -> f64 {
        metrics::mean_std(&self.methods[idx(m)]).0
    }

    /// Mean over runs of ADC2 smoothed with window `w`.
    pub fn smoothed_mean(&self, w: usize) -> Smoothed {
        let k = self
            .windows
            .iter()
            .position(|&x| x == w)
            .expect("window in the sweep");
        let runs = &self.sweep[k];
        let n = runs.len() as f64;
        Smoothed {
            centred: runs.iter().map(|s| s.centred).sum::<f64>() / n,
            causal: runs.iter().map(|s| s.causal).sum::<f64>() / n,
            naive_centred: runs.iter().map(|s| s.naive_centred).sum::<f64>() / n,
        }
    }
}

/// Headings (degrees) of the readings `samples[range]` through the core's
/// heading function: raw if `cal` is `None`, else `Q W (y - b)`.
fn headings(
    samples: &[[f64; 3]],
    range: std::ops::Range<usize>,
    cal: Option<(&Estimate, &Matrix3<f64>)>,
) -> Vec<f64> {
    samples[range]
        .iter()
        .map(|y| {
            let y = Vector3::from(*y);
            let v = match cal {
                None => y,
                Some((est, q)) => q * est.apply(&y),
            };
            core_heading::heading_deg(&v)
        })
        .collect()
}

fn mean_abs_error(est: &[f64], truth: &[f64]) -> f64 {
    est.iter()
        .zip(truth)
        .map(|(e, t)| metrics::wrap_deg(e - t).abs())
        .sum::<f64>()
        / est.len() as f64
}

/// Scenario H with `runs` runs: run 0 calibrates and fits the alignment of
/// each method against the true field (all of its samples); runs `1..runs`
/// calibrate afresh, keep that alignment, and are scored on their level turns
/// (the paper's procedure: the true heading is not known in use). Scores are
/// mean absolute heading errors over the 1200 level samples; the smoothed
/// scores average over the outputs of a full window only.
pub fn run_heading(runs: usize, windows: &[usize], repeats: usize) -> HeadingStudy {
    assert!(runs >= 2, "one alignment run and at least one scored run");
    let h = HeadingScenario::paper();
    let nm = HEADING_METHODS.len();
    let mut out = HeadingStudy {
        runs: runs - 1,
        methods: vec![Vec::new(); nm],
        seconds: vec![Vec::new(); nm],
        warned: vec![0; nm],
        alignment: vec![Matrix3::identity(); nm],
        windows: windows.to_vec(),
        sweep: vec![Vec::new(); windows.len()],
        ..HeadingStudy::default()
    };
    for run in 0..runs {
        let data = h.generate(run);
        let level = data.level.clone();
        let truth: Vec<f64> = data.true_dirs[level.clone()]
            .iter()
            .map(core_heading::heading_deg)
            .collect();
        if run > 0 {
            out.raw.push(mean_abs_error(
                &headings(&data.samples, level.clone(), None),
                &truth,
            ));
            let exact = Estimate {
                b: Vector3::from(h.bias),
                w: h.coupling.try_inverse().expect("invertible coupling"),
            };
            out.truth.push(mean_abs_error(
                &headings(
                    &data.samples,
                    level.clone(),
                    Some((&exact, &Matrix3::identity())),
                ),
                &truth,
            ));
        }
        for (i, &m) in HEADING_METHODS.iter().enumerate() {
            let (fit, secs) = timed_fit(&data.samples, &config(m), repeats);
            out.seconds[i].push(secs);
            out.warned[i] += usize::from(!fit.report.warnings.is_empty());
            let est = estimate(&fit);
            if run == 0 {
                let u: Vec<Vector3<f64>> = data
                    .samples
                    .iter()
                    .map(|y| est.apply(&Vector3::from(*y)))
                    .collect();
                let q = core_align::procrustes(&u, &data.true_dirs);
                let q_check = metrics::procrustes(&u, &data.true_dirs);
                out.procrustes_check = out.procrustes_check.max((q - q_check).amax());
                out.alignment[i] = q;
                continue;
            }
            let psi = headings(
                &data.samples,
                level.clone(),
                Some((&est, &out.alignment[i])),
            );
            out.methods[i].push(mean_abs_error(&psi, &truth));
            if m != Method::Adc2 {
                continue;
            }
            for (k, &w) in windows.iter().enumerate() {
                let smooth = core_heading::smooth(&psi, w);
                let check = metrics::circular_moving_average(&psi, w);
                assert_eq!(smooth.len(), check.len());
                for (a, b) in smooth.iter().zip(&check) {
                    out.smoother_check = out.smoother_check.max(metrics::wrap_deg(a - b).abs());
                }
                // Output j covers inputs j .. j + w: newest j + w - 1,
                // centre j + (w - 1) / 2.
                let centred = mean_abs_error(&smooth, &truth[(w - 1) / 2..]);
                let causal = mean_abs_error(&smooth, &truth[w - 1..]);
                let naive: Vec<f64> = psi
                    .windows(w)
                    .map(|win| win.iter().sum::<f64>() / w as f64)
                    .collect();
                let naive_centred = mean_abs_error(&naive, &truth[(w - 1) / 2..]);
                out.sweep[k].push(Smoothed {
                    centred,
                    causal,
                    naive_centred,
                });
            }
        }
    }
    out
}

/// The core's alignment step (`mag_cal_core::align`).
mod core_align {
    use super::*;

    /// Rotation `Q` (det +1) minimising `sum |Q u_i - h_i|^2`.
    pub fn procrustes(u: &[Vector3<f64>], h: &[Vector3<f64>]) -> Matrix3<f64> {
        let u: Vec<[f64; 3]> = u.iter().map(|v| [v.x, v.y, v.z]).collect();
        let h: Vec<[f64; 3]> = h.iter().map(|v| [v.x, v.y, v.z]).collect();
        let q = mag_cal_core::align::procrustes(&u, &h).expect("alignment of a full recording");
        Matrix3::from_row_slice(q.as_flattened())
    }
}

/// The core's heading and smoother (`mag_cal_core::heading`).
mod core_heading {
    use super::*;
    use mag_cal_core::heading::HeadingSmoother;

    /// `atan2(-v_y, v_x)` in degrees.
    pub fn heading_deg(v: &Vector3<f64>) -> f64 {
        mag_cal_core::heading::heading_deg((*v).into())
    }

    /// The smoother's outputs once its window is full (`len - w + 1`).
    pub fn smooth(headings: &[f64], w: usize) -> Vec<f64> {
        let mut s = HeadingSmoother::<f64, MAX_WINDOW>::with_window(w).expect("window");
        headings
            .iter()
            .enumerate()
            .filter_map(|(i, &a)| s.push(a).filter(|_| i + 1 >= w))
            .collect()
    }
}

/// One acceptance relation and its outcome.
#[derive(Clone, Debug, PartialEq)]
pub struct Relation {
    /// Short identifier (stable; the tests look relations up by it).
    pub id: &'static str,
    /// What is claimed.
    pub claim: String,
    /// The measured value(s).
    pub measured: String,
    /// Whether it holds.
    pub pass: bool,
}

/// Identifiers of the relations [`relations`] returns, in order.
pub const RELATION_IDS: [&str; 9] = [
    "adc2_vs_ls9_each",
    "adc2_vs_ls9_mean_a_e",
    "iterated_vs_submle_each",
    "iterated_vs_adc2_mean",
    "adc1_equals_adc2",
    "submle_cost",
    "h_adc2_vs_ls9",
    "h_smoothing",
    "iterated_passes",
];

/// How strictly the relations are checked.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Strictness {
    /// A ratio relation `r <= limit` passes when `r - k se <= limit`, with
    /// `se` the standard error of the ratio of means over the paired runs:
    /// 0 in the binary (the relation as stated, at 100 runs), about 2 in the
    /// fast test (fewer runs; the margin scales with 1/sqrt(runs)).
    pub se_factor: f64,
    /// Compare costs by wall clock (binary) or by [`flop_proxy`] (test).
    pub wall_clock: bool,
    /// Allowed excess of ADC2's heading error over LS's, degrees.
    pub heading_margin_deg: f64,
}

/// The acceptance relations on a Table I study (scenarios A-G in
/// order) and a heading study, in this order: [`RELATION_IDS`].
pub fn relations(table: &[ScenarioStudy], h: &HeadingStudy, how: Strictness) -> Vec<Relation> {
    let mut out = Vec::new();
    let k = how.se_factor;
    let fmt_ratio = |r: (f64, f64)| format!("{:.3} (se {:.3})", r.0, r.1);

    // 1. ADC2 e_S <= 0.95 LS9 e_S in each scenario.
    let r: Vec<(char, (f64, f64))> = table
        .iter()
        .map(|s| (s.scenario.id, s.es_ratio(Method::Adc2, Method::Ls)))
        .collect();
    out.push(Relation {
        id: "adc2_vs_ls9_each",
        claim: "ADC2 e_S <= 0.95 x LS9 e_S in each of A-G".into(),
        measured: r
            .iter()
            .map(|(id, x)| format!("{id} {}", fmt_ratio(*x)))
            .collect::<Vec<_>>()
            .join(", "),
        pass: r.iter().all(|(_, (x, se))| x - k * se <= 0.95),
    });

    // 2. ... and <= 0.85 on average over A-E (mean of the five ratios).
    let ae: Vec<&(char, (f64, f64))> = r.iter().filter(|(id, _)| *id <= 'E').collect();
    let mean = ae.iter().map(|(_, x)| x.0).sum::<f64>() / ae.len() as f64;
    let se = (ae.iter().map(|(_, x)| x.1 * x.1).sum::<f64>()).sqrt() / ae.len() as f64;
    out.push(Relation {
        id: "adc2_vs_ls9_mean_a_e",
        claim: "ADC2 e_S <= 0.85 x LS9 e_S on average over A-E (mean of the ratios)".into(),
        measured: fmt_ratio((mean, se)),
        pass: ae.len() == 5 && mean - k * se <= 0.85,
    });

    // 3. Iterated ADC2 e_S <= 1.4 subMLE e_S in each scenario.
    let r: Vec<(char, (f64, f64))> = table
        .iter()
        .map(|s| {
            (
                s.scenario.id,
                s.es_ratio(Method::Adc2Iterated, Method::SubMle),
            )
        })
        .collect();
    out.push(Relation {
        id: "iterated_vs_submle_each",
        claim: "iterated ADC2 e_S <= 1.4 x subMLE e_S in each of A-G".into(),
        measured: r
            .iter()
            .map(|(id, x)| format!("{id} {}", fmt_ratio(*x)))
            .collect::<Vec<_>>()
            .join(", "),
        pass: r.iter().all(|(_, (x, se))| x - k * se <= 1.4),
    });

    // 4. Iterated ADC2 below one-step ADC2 on average over A-G.
    let r: Vec<(f64, f64)> = table
        .iter()
        .map(|s| s.es_ratio(Method::Adc2Iterated, Method::Adc2))
        .collect();
    let mean = r.iter().map(|x| x.0).sum::<f64>() / r.len() as f64;
    let se = r.iter().map(|x| x.1 * x.1).sum::<f64>().sqrt() / r.len() as f64;
    out.push(Relation {
        id: "iterated_vs_adc2_mean",
        claim: "iterated ADC2 e_S < one-step ADC2 e_S on average over A-G (mean of the ratios)"
            .into(),
        measured: fmt_ratio((mean, se)),
        pass: mean - k * se < 1.0,
    });

    // 5. ADC1 = ADC2 (gauge-free), every run.
    let (dm, db) = table.iter().fold((0.0f64, 0.0f64), |acc, s| {
        (acc.0.max(s.adc1_vs_adc2.0), acc.1.max(s.adc1_vs_adc2.1))
    });
    out.push(Relation {
        id: "adc1_equals_adc2",
        claim: "ADC1 equals ADC2 within 1e-6 (max|dM|/max|M|, |db|/rho), every run".into(),
        measured: format!("{dm:.1e}, {db:.1e}"),
        pass: dm <= 1e-6 && db <= 1e-6,
    });

    // 6. subMLE costs >= 8 ADC2 (median over the runs of the same-run ratio),
    // in each scenario.
    let (what, r): (&str, Vec<(char, f64)>) = if how.wall_clock {
        (
            "wall clock",
            table
                .iter()
                .map(|s| (s.scenario.id, s.time_ratio_to_adc2(Method::SubMle)))
                .collect(),
        )
    } else {
        (
            "flop proxy",
            table
                .iter()
                .map(|s| (s.scenario.id, s.flop_ratio_to_adc2(Method::SubMle)))
                .collect(),
        )
    };
    out.push(Relation {
        id: "submle_cost",
        claim: format!("subMLE median time >= 8 x ADC2's, same runs, each of A-G ({what})"),
        measured: r
            .iter()
            .map(|(id, x)| format!("{id} {x:.1}x"))
            .collect::<Vec<_>>()
            .join(", "),
        pass: r.iter().all(|(_, x)| *x >= 8.0),
    });

    // 7. H: ADC2 not above LS; 8. smoothing lowers ADC2's error.
    let (adc2, ls) = (h.mean(Method::Adc2), h.mean(Method::Ls));
    out.push(Relation {
        id: "h_adc2_vs_ls9",
        claim: format!(
            "H: ADC2 heading error <= LS's + {} deg",
            how.heading_margin_deg
        ),
        measured: format!("ADC2 {adc2:.4} deg, LS {ls:.4} deg"),
        pass: adc2 <= ls + how.heading_margin_deg,
    });
    let smooth = h.smoothed_mean(SMOOTH_WINDOW).centred;
    out.push(Relation {
        id: "h_smoothing",
        claim: format!("H: smoothing (window {SMOOTH_WINDOW}) lowers ADC2's heading error"),
        measured: format!("{smooth:.4} deg smoothed, {adc2:.4} deg unsmoothed"),
        pass: smooth < adc2,
    });

    // 9. Iterated ADC2's median passes: <= 8 on a full sphere, <= 25 on a
    // +-30 deg band (plain iteration needs 16-22 and 70-90).
    let p: Vec<(char, bool, u32)> = table
        .iter()
        .map(|s| {
            let mut v = s.methods[idx(Method::Adc2Iterated)].passes.clone();
            v.sort_unstable();
            let median = v.get(v.len() / 2).copied().unwrap_or(u32::MAX);
            (s.scenario.id, s.scenario.banded, median)
        })
        .collect();
    out.push(Relation {
        id: "iterated_passes",
        claim: "iterated ADC2 median passes <= 8 on a full sphere, <= 25 on a +-30 deg band".into(),
        measured: p
            .iter()
            .map(|(id, _, m)| format!("{id} {m}"))
            .collect::<Vec<_>>()
            .join(", "),
        pass: p
            .iter()
            .all(|(_, banded, m)| *m <= if *banded { 25 } else { 8 }),
    });
    out
}
