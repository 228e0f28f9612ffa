//! Outlier handling (design document, section 14) against the targets of
//! its issue, on the contamination generator (`host_tests::contamination`)
//! and the design document's clean scenarios A-G.
//!
//! Where the core meets a target the test asserts the target; where it
//! does not yet, the test asserts the measured level and names the target
//! it misses (`docs/results.md` has the full table), so that a regression
//! fails and an improvement is visible.

use host_tests::contamination::{
    contaminate, fit_errors, run_study, Case, CellStats, CleanRun, Coverage, Degenerate, Grid,
    Kind, Precision, Setting, Units,
};
use host_tests::scenarios::{Truth, SCENARIOS};
use host_tests::sim::Rng;
use mag_cal_core::{calibrate, Config, Error, Method, SampleClass};

/// Plain ADC2 (outlier handling off) and the default (on), on the clean
/// scenarios A-G: the robust default is never refused, and its mean errors
/// are within 3 % of the plain fit's (the target), for one-step and
/// iterated ADC2.
#[test]
fn clean_scenarios_are_never_refused_and_as_accurate() {
    let truth = Truth::paper();
    for method in [Method::Adc2, Method::Adc2Iterated] {
        for s in SCENARIOS.iter() {
            let (mut plain, mut robust) = ([0.0f64; 2], [0.0f64; 2]);
            let runs = 30;
            for run in 0..runs {
                let r = s.generate(&truth, run);
                let cfg = Config {
                    method,
                    ..Config::default()
                };
                let off = Config {
                    robust: false,
                    ..cfg
                };
                let errors = |cfg: &Config| {
                    let fit = calibrate::<f64, _>(&r.samples, cfg)
                        .unwrap_or_else(|e| panic!("{method:?} {} run {run}: {e}", s.id));
                    let c = fit.calibration;
                    let e = fit_errors(&c.hard_iron_vector(), &c.soft_iron_matrix(), &truth);
                    [e.e_m, e.e_b]
                };
                for (acc, e) in [(&mut plain, errors(&off)), (&mut robust, errors(&cfg))] {
                    acc[0] += e[0];
                    acc[1] += e[1];
                }
            }
            let ratio = [robust[0] / plain[0], robust[1] / plain[1]];
            println!(
                "{method:?} {}: mean e_M {:.5} (plain {:.5}), e_b {:.5} (plain {:.5}): ratios {:.3} / {:.3}",
                s.id,
                robust[0] / runs as f64,
                plain[0] / runs as f64,
                robust[1] / runs as f64,
                plain[1] / runs as f64,
                ratio[0],
                ratio[1]
            );
            assert!(
                ratio[0] <= 1.03 && ratio[1] <= 1.03,
                "{method:?} {}: {ratio:?}",
                s.id
            );
        }
    }
}

/// The study's grid at the fractions up to 10 %, 16 runs a cell.
fn up_to_ten_percent() -> Grid {
    Grid {
        fractions: vec![0.005, 0.01, 0.02, 0.05, 0.10],
        degenerate: Degenerate::ALL.to_vec(),
        ..Grid::full(16)
    }
}

fn pooled(cells: impl Iterator<Item = CellStats>) -> CellStats {
    let mut all = CellStats::default();
    for c in cells {
        all.merge(&c);
    }
    all
}

/// Up to 10 % of any kind, robust ADC2 and iterated ADC2, f32 and f64.
///
/// Targets of the issue: at least 97 % of the runs accepted, median error
/// ratios (`e_M`, `e_b`) to the clean fit of the same rows at most 1.3, at
/// most 0.5 % of the runs accepted with an error above 0.05. Met by every
/// kind and fraction but the ratios of a moving disturbance at 10 % (up
/// to 1.5 for one-step ADC2: held to that measured level instead of the
/// target); a displaced patch at 10 % has its own test at 256 runs a cell
/// (here 64, too few to resolve 97 %). A clipped range (every row beyond a
/// level on one axis) loses the cap beyond the level: its ratio is held
/// to 2.
#[test]
fn contamination_up_to_ten_percent() {
    let grid = up_to_ten_percent();
    for method in [Method::Adc2, Method::Adc2Iterated] {
        for precision in Precision::ALL {
            let config = Config {
                method,
                ..Config::default()
            };
            let study = run_study(&config, precision, &grid);
            let label = format!("{method:?} {}", precision.name());
            let all = pooled(grid.kinds.iter().flat_map(|&k| {
                let study = &study;
                grid.fractions
                    .iter()
                    .map(move |&f| study.pooled(&Case::Contaminated(k, f)))
            }));
            println!(
                "{label}: {} runs, {:.1} % accepted, {:.2} % silently wrong",
                all.runs,
                100.0 * all.accepted_share(),
                100.0 * all.wrong_share()
            );
            assert!(all.wrong_share() <= 0.005, "{label}: {}", all.wrong_share());
            for &kind in &grid.kinds {
                for &f in &grid.fractions {
                    let cell = study.pooled(&Case::Contaminated(kind, f));
                    let what = format!("{label} {} {}", kind.name(), f);
                    // Every kind to the ratio of the target, a clipped
                    // range too: its rows share the axis's extreme, which
                    // sends the data past the plain fit to the screening's
                    // clip rule (`tuning::CLIP_HINT_ROWS`; at 2 % the
                    // plain fit passed as clean, with ratios 1.35 / 1.52).
                    let (needed, ratio) = match kind {
                        // 64 runs a cell here, where one run is 1.6 %: the
                        // 97 % of the target is asserted on 256 runs a cell
                        // by `a_displaced_patch_of_the_trajectory_is_left_out`.
                        Kind::Patch if f > 0.05 => (0.95, 1.3),
                        _ => (0.97, 1.3),
                    };
                    assert!(
                        cell.accepted_share() >= needed,
                        "{what}: accepted {} ({:?})",
                        cell.accepted_share(),
                        cell.main_refusals()
                    );
                    let (rm, rb) = (cell.median_ratio_m(), cell.median_ratio_b());
                    assert!(rm <= ratio && rb <= ratio, "{what}: ratios {rm} {rb}");
                }
            }
        }
    }
}

/// Prints the figures of `cell` under `what` and asserts that at least
/// `accepted` of its runs were accepted, at most `wrong` silently wrong,
/// and that the median error ratios are at most `ratio` (`e_M`, `e_b`).
fn assert_cell(what: &str, cell: &CellStats, accepted: f64, wrong: f64, ratio: (f64, f64)) {
    let (rm, rb) = (cell.median_ratio_m(), cell.median_ratio_b());
    println!(
        "{what}: {} runs, {:.1} % accepted, {:.2} % silently wrong, median ratios {rm:.2} / {rb:.2}",
        cell.runs,
        100.0 * cell.accepted_share(),
        100.0 * cell.wrong_share(),
    );
    assert!(
        cell.accepted_share() >= accepted,
        "{what}: {:?}",
        cell.main_refusals()
    );
    assert!(
        cell.wrong_share() <= wrong,
        "{what}: {}",
        cell.wrong_share()
    );
    assert!(rm <= ratio.0 && rb <= ratio.1, "{what}: ratios {rm} {rb}");
}

/// A tenth of the trajectory, one patch of directions, displaced by 0.3 of
/// the field (a magnet near one orientation of the device), 64 runs a
/// setting, robust ADC2 and iterated ADC2, f32 and f64: at least 97 % of
/// the runs accepted, at most 0.5 % wrong, median ratios at most 1.3 (the
/// targets up to 10 %; measured 98.0-98.8 %, 0-0.4 %, 1.12-1.16). The robust
/// LS refits from the crude sphere used to keep the patch (the first
/// refit's cut comes from the crude sphere's error, 0.1 of the field on a
/// distorted ellipsoid) and settle on the ellipsoid it bulged: 89.5 % of
/// the one-step runs were accepted, the rest refused as a systematic
/// misfit with `M` off by 0.07-0.28. The trimmed refits on the subsample
/// (`tuning::TRIM_SHARE`) escape it.
#[test]
fn a_displaced_patch_of_the_trajectory_is_left_out() {
    meets_the_targets_up_to_ten_percent(Kind::Patch);
}

/// `kind` in a tenth of the rows, 64 runs a setting (256 a cell), robust
/// ADC2 and iterated ADC2, f32 and f64: the targets up to 10 % (at least
/// 97 % accepted, at most 0.5 % wrong, median ratios at most 1.3).
fn meets_the_targets_up_to_ten_percent(kind: Kind) {
    let grid = Grid {
        kinds: vec![kind],
        fractions: vec![0.1],
        degenerate: vec![],
        ..Grid::full(64)
    };
    for method in [Method::Adc2, Method::Adc2Iterated] {
        for precision in Precision::ALL {
            let config = Config {
                method,
                ..Config::default()
            };
            let study = run_study(&config, precision, &grid);
            let cell = study.pooled(&Case::Contaminated(kind, 0.1));
            let what = format!("{method:?} {} {} 0.1", precision.name(), kind.name());
            assert_cell(&what, &cell, 0.97, 0.005, (1.3, 1.3));
        }
    }
}

/// A disturbance that moves past the sensor (the displacement rises and
/// falls over a tenth of the rows, peak 0.5 of the field), robust ADC2 and
/// iterated ADC2 in f32 and f64: the rows beside the run of rejected rows
/// are left out ([`mag_cal_core::runs`]), so the fit meets the targets up
/// to 10 % (measured 1.16-1.23 against 1.32-1.47 before the runs, whose
/// edges, displaced by less than the cut, were used).
#[test]
fn a_moving_disturbance_is_left_out_with_its_edges() {
    meets_the_targets_up_to_ten_percent(Kind::Moving);
}

/// The rows of a run and beside it: the report counts them as rejected,
/// `classify` says so row by row, and the span holds the disturbance's
/// peak.
#[test]
fn the_rows_beside_a_run_are_counted_and_classified_as_rejected() {
    let mut with_runs = 0;
    for seed in 0..8u64 {
        let setting = Setting {
            units: Units::MicroTesla,
            coverage: Coverage::Sphere,
            n: 1000,
        };
        let run = CleanRun::generate(setting, &mut Rng(77 + seed));
        let c = contaminate(&run, Kind::Moving, 0.1, &mut Rng(5 + seed));
        let rows = &c.rows.samples;
        let fit = calibrate::<f64, _>(rows, &Config::default()).expect("calibrates");
        let r = &fit.report;
        let runs = r.selection.runs;
        let classes: Vec<SampleClass> = r.selection.classify(&fit.calibration, rows).collect();
        let count = |class: SampleClass| classes.iter().filter(|&&k| k == class).count();
        assert_eq!(count(SampleClass::Used), r.samples_used, "seed {seed}");
        assert_eq!(count(SampleClass::Rejected), r.rejected, "seed {seed}");
        assert_eq!(count(SampleClass::Screened), r.screened, "seed {seed}");
        assert_eq!(
            r.samples_used + r.samples_dropped + r.screened + r.rejected,
            rows.len()
        );
        // The disturbance's peak, its middle row, lies in a span.
        let first = c.marked.iter().position(|&m| m).expect("displaced rows");
        let last = c.marked.iter().rposition(|&m| m).expect("displaced rows");
        with_runs += usize::from(runs.contains((first + last) / 2));
        for &(s, e) in runs.spans() {
            assert!(
                (s..e).all(|i| classes[i] != SampleClass::Used),
                "seed {seed}"
            );
        }
    }
    assert_eq!(with_runs, 8, "a span at the peak in {with_runs} of 8 runs");
}

/// One axis clipped on some reads (a lower clip level with rows left
/// beyond it, so the level is no extreme of the axis) in 20 and 30 % of
/// the rows: at least 97 % of the runs accepted and at most 2 % silently
/// wrong (the target at 20-30 %). The plain fit bends to the rows
/// pulled inwards; the skewness of its residuals (`CLEAN_SKEWNESS`) sends
/// it to the robust path. The accuracy is not held: the screening no
/// longer searches for a clip level inside an axis's range (issue 35's
/// ablation, `docs/robustness.md` section 5, pruned it: 1 148 B), and the
/// median `e_M` ratio is 1.64 at 20 % and 3.25 at 30 % (1.41 at 30 % with
/// the search); 1.17 % of the 30 % runs are silently wrong.
#[test]
fn an_axis_clipped_on_some_reads_is_not_silently_wrong() {
    let grid = Grid {
        kinds: vec![Kind::ClipSaturation],
        fractions: vec![0.2, 0.3],
        degenerate: vec![],
        ..Grid::full(64)
    };
    for precision in Precision::ALL {
        let study = run_study(&Config::default(), precision, &grid);
        for &f in &grid.fractions {
            let cell = study.pooled(&Case::Contaminated(Kind::ClipSaturation, f));
            let what = format!("{} clip {f}", precision.name());
            // No accuracy target at 20-30 %.
            assert_cell(&what, &cell, 0.97, 0.02, (f64::INFINITY, f64::INFINITY));
        }
    }
}

/// A device lying still, a filled ball and a cube are refused, as
/// `NoSphere`, naming the fit error.
#[test]
fn what_is_not_a_sphere_is_refused() {
    let grid = Grid {
        kinds: vec![],
        fractions: vec![],
        ..up_to_ten_percent()
    };
    let study = run_study(&Config::default(), Precision::F32, &grid);
    for d in Degenerate::ALL {
        let cell = study.pooled(&Case::Degenerate(d));
        assert_eq!(cell.accepted, 0, "{}: {:?}", d.name(), cell.main_refusals());
        let refusals = cell.main_refusals();
        assert_eq!(
            refusals.first().map(|r| r.0),
            Some("NoSphere"),
            "{refusals:?}"
        );
    }
    // The message names the figure and the cause.
    let still: Vec<[f64; 3]> = (0..200)
        .map(|i| {
            let w = f64::from(i) * 0.7;
            [
                120.0 + w.sin(),
                -40.0 + (1.3 * w).cos(),
                75.0 + (2.1 * w).sin(),
            ]
        })
        .collect();
    let e = calibrate::<f32, _>(&still, &Config::default()).unwrap_err();
    assert!(matches!(e, Error::NoSphere { fit_error, .. } if fit_error.get() > 0.2));
    let text = e.to_string();
    assert!(
        text.contains("fit error") && text.contains("not rotated"),
        "{text}"
    );
}

/// Outlier handling off gives the plain estimates: the same calibration as
/// the robust default on clean data, and a wrong one on contaminated data.
#[test]
fn the_switch_gives_the_plain_fit() {
    let truth = Truth::paper();
    let r = SCENARIOS[0].generate(&truth, 3);
    let plain = Config {
        robust: false,
        ..Config::default()
    };
    let a = calibrate::<f64, _>(&r.samples, &plain).unwrap();
    let b = calibrate::<f64, _>(&r.samples, &Config::default()).unwrap();
    // Clean: the default keeps the plain fit, bit for bit.
    assert_eq!(b.report.robust_passes, 0);
    assert_eq!(a.calibration, b.calibration);
    // Five wild rows among 1000: plain ADC2 is no longer a calibration of
    // this sensor, the default is.
    let mut dirty = r.samples.clone();
    for (k, i) in [17, 230, 401, 622, 915].into_iter().enumerate() {
        dirty[i] = [40.0 + k as f64, -35.0, 52.0];
    }
    let robust = calibrate::<f64, _>(&dirty, &Config::default()).unwrap();
    let e = fit_errors(
        &robust.calibration.hard_iron_vector(),
        &robust.calibration.soft_iron_matrix(),
        &truth,
    );
    assert!(!e.wrong(), "{e:?}");
    assert!(robust.report.screened + robust.report.rejected >= 5);
    match calibrate::<f64, _>(&dirty, &plain) {
        Err(_) => {}
        Ok(f) => {
            let c = f.calibration;
            assert!(fit_errors(&c.hard_iron_vector(), &c.soft_iron_matrix(), &truth).wrong());
        }
    }
}

/// Samples crowded on one side of the sphere, as an on-device collection
/// gives them when the device is swung flat many times before it is
/// tilted: 80 % of the directions within 35 deg of one pole, the rest
/// anywhere. Their coordinate-wise median sits near that pole, and the
/// screening ball about it (2.5 median distances) leaves out the far side.
/// With 2 % of the rows displaced by 0.3 of the field (so that the robust
/// path runs) the default fit is accepted, and agrees with the plain fit
/// of the clean rows (gauge-free: `M = W^T W` and `b`). Without the
/// re-centring of the screen, all 20 seeds were refused (planar, poor
/// coverage, no sphere).
#[test]
fn samples_crowded_on_one_side_are_calibrated() {
    use host_tests::sim::{make_samples, random_t, Rng};
    use nalgebra::Vector3;
    let rho = 400.0;
    for seed in 0..20 {
        let mut rng = Rng(1000 + seed);
        let t = random_t(&mut rng) * rho;
        let b = Vector3::new(900.0, -350.0, 1200.0);
        let dirs: Vec<Vector3<f64>> = (0..1000)
            .map(|i| {
                if i % 10 < 8 {
                    (0..1000)
                        .map(|_| rng.unit_vector())
                        .find(|d| d.z < -0.82)
                        .unwrap_or(-Vector3::z())
                } else {
                    rng.unit_vector()
                }
            })
            .collect();
        let clean = make_samples(&t, &b, &dirs, 0.01 * rho, &mut rng);
        let mut dirty = clean.clone();
        for row in dirty.iter_mut().step_by(50) {
            let d = rng.unit_vector() * 0.3 * rho;
            *row = [row[0] + d.x, row[1] + d.y, row[2] + d.z];
        }
        let plain = Config {
            robust: false,
            ..Config::default()
        };
        let p = calibrate::<f64, _>(&clean, &plain).unwrap().calibration;
        let r = calibrate::<f64, _>(&dirty, &Config::default())
            .unwrap_or_else(|e| panic!("seed {seed}: {e}"));
        let c = r.calibration;
        let e_b = (c.hard_iron_vector() - p.hard_iron_vector()).norm() / p.field_strength();
        let (m_r, m_p) = (c.shape_matrix(), p.shape_matrix());
        let e_m = (m_r - m_p).norm() / m_p.norm();
        assert!(
            e_b < 0.01 && e_m < 0.02,
            "seed {seed}: e_b {e_b:.4} e_M {e_m:.4}"
        );
        assert!(
            r.report.rejected >= 10,
            "seed {seed}: {}",
            r.report.rejected
        );
    }
}

/// A fifth of the rows displaced as one stretch (a patch by 0.3 of the
/// field, or a disturbance moving past, peak 0.5), 64 runs a setting (256
/// a cell), robust ADC2 and iterated ADC2, f32 and f64: at least 97 % of
/// the runs accepted and at most 1 % silently wrong (the target at 20-30 %
/// is 2 %; measured 99.2-100 % and 0-0.8 %). The fit from the crude start
/// keeps most of such a stretch, bent into a compromise, and was refused
/// as a systematic misfit in 16-34 % of the runs and silently wrong in
/// 0.4-3.9 %; the window starts ([`mag_cal_core::DOUBT_LACK_OF_FIT`]) find
/// the fit without it.
#[test]
fn a_fifth_of_the_rows_displaced_as_one_stretch_is_left_out() {
    let grid = Grid {
        kinds: vec![Kind::Patch, Kind::Moving],
        fractions: vec![0.2],
        degenerate: vec![],
        ..Grid::full(64)
    };
    for method in [Method::Adc2, Method::Adc2Iterated] {
        for precision in Precision::ALL {
            let config = Config {
                method,
                ..Config::default()
            };
            let study = run_study(&config, precision, &grid);
            for kind in [Kind::Patch, Kind::Moving] {
                let cell = study.pooled(&Case::Contaminated(kind, 0.2));
                let what = format!("{method:?} {} {} 0.2", precision.name(), kind.name());
                assert_cell(&what, &cell, 0.97, 0.01, (f64::INFINITY, f64::INFINITY));
            }
        }
    }
}

/// The report names the window the robust LS started without, when the
/// fit from the rows outside it scored best, and that window holds most of
/// the displaced stretch. (Where the fit from the crude start left the
/// stretch out itself, or the window starts did no better, it names none.)
#[test]
fn the_report_names_the_window_the_fit_started_without() {
    let mut named = 0;
    for seed in 0..16u64 {
        let setting = Setting {
            units: Units::MicroTesla,
            coverage: Coverage::Sphere,
            n: 1000,
        };
        let run = CleanRun::generate(setting, &mut Rng(300 + seed));
        let c = contaminate(&run, Kind::Patch, 0.2, &mut Rng(11 + seed));
        let fit = calibrate::<f64, _>(&c.rows.samples, &Config::default()).expect("calibrates");
        let e = fit_errors(
            &fit.calibration.hard_iron_vector(),
            &fit.calibration.soft_iron_matrix(),
            &run.truth,
        );
        assert!(!e.wrong(), "seed {seed}: e_M {} e_b {}", e.e_m, e.e_b);
        let window = fit.report.start_window();
        println!("seed {seed}: start window {:?}", window.spans());
        if window.is_empty() {
            continue;
        }
        named += 1;
        // Half the rows, in one span or two when it wraps at the end.
        let rows: usize = window.spans().iter().map(|&(s, e)| e - s).sum();
        assert_eq!(rows, 500, "seed {seed}: {:?}", window.spans());
        let displaced = c.marked.iter().filter(|&&m| m).count();
        let inside = (0..c.marked.len())
            .filter(|&i| c.marked[i] && window.contains(i))
            .count();
        assert!(
            2 * inside > displaced,
            "seed {seed}: {inside} of {displaced} displaced rows in {:?}",
            window.spans()
        );
    }
    // Measured: 9 of 16.
    assert!(named >= 5, "{named} of 16 runs named a window");
}

/// The LS fit alone with outlier handling: its lack of fit is not judged
/// (the algebraic criterion leaves a pattern under noise), so before its
/// plain attempt made the artificial-data pass and judged its lack of shape
/// (`mag_cal_core::CLEAN_SHAPE`), plain LS fits bent by displaced rows
/// passed for clean: with a tenth of the rows displaced by a field, 42 % of
/// the runs were accepted with `M` off by more than 0.05; a displaced
/// patch of 20 % 12 %, a moving disturbance of 20 % 16 %; and, its radius
/// shrinking under noise, a noise ball was accepted in 47 % of the runs.
/// Now up to 10 %: the targets (at least 97 % accepted, at most 0.5 %
/// wrong, median ratios at most 1.3); at 20 % at most 2 % wrong; a noise
/// ball never accepted: in 4 of 256 runs the LS fit of its outer rows kept
/// the fit error just under its limit (0.19-0.20), and those are refused
/// as a filled cloud, their residuals skewed inwards
/// (`tuning::REFUSE_SKEWNESS`).
#[test]
fn the_ls_fit_alone_is_judged_by_its_shape() {
    let grid = Grid {
        kinds: vec![Kind::Displace1, Kind::Patch, Kind::Moving],
        fractions: vec![0.1, 0.2],
        degenerate: vec![Degenerate::NoiseBall, Degenerate::Stationary],
        ..Grid::full(64)
    };
    let config = Config {
        method: Method::Ls,
        ..Config::default()
    };
    for precision in Precision::ALL {
        let study = run_study(&config, precision, &grid);
        for &kind in &grid.kinds {
            let ten = study.pooled(&Case::Contaminated(kind, 0.1));
            let what = format!("Ls {} {} 0.1", precision.name(), kind.name());
            assert_cell(&what, &ten, 0.97, 0.005, (1.3, 1.3));
            let twenty = study.pooled(&Case::Contaminated(kind, 0.2));
            let what = format!("Ls {} {} 0.2", precision.name(), kind.name());
            assert_cell(&what, &twenty, 0.0, 0.02, (f64::INFINITY, f64::INFINITY));
        }
        for d in &grid.degenerate {
            let cell = study.pooled(&Case::Degenerate(*d));
            println!(
                "Ls {} {}: {} of {} accepted",
                precision.name(),
                d.name(),
                cell.accepted,
                cell.runs
            );
            assert_eq!(cell.accepted, 0, "{}: {:?}", d.name(), cell.main_refusals());
            if *d == Degenerate::NoiseBall {
                let refusals = cell.main_refusals();
                assert!(
                    refusals.iter().any(|r| r.0 == "FilledCloud"),
                    "{refusals:?}"
                );
            }
        }
    }
    // The refusal names its figure and the cause.
    let e = Error::FilledCloud {
        skewness: mag_cal_core::Figure::new(-0.8),
        limit: mag_cal_core::Figure::new(-0.6),
    };
    let text = e.to_string();
    assert!(
        text.contains("skewness -0.8, limit -0.6)") && text.contains("fill a volume"),
        "{text}"
    );
}
