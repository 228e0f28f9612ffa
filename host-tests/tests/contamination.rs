//! The contamination generator (`host_tests::contamination`) does what it
//! says, and a small study runs end to end.
//!
//! The study test asserts that the study itself works (clean data are
//! accepted and fitted well, every run is accounted for); the robustness
//! targets of the design document's section 14 are `tests/robust.rs`'s. It
//! prints the table at 1 % and 10 % contamination (`-- --nocapture` to see
//! it).

use host_tests::contamination::{
    contaminate, degenerate, fit_errors, order_along_path, render_table, rows_for, run_study,
    CleanRun, Contaminated, Coverage, Degenerate, Grid, Kind, Precision, Rows, Setting, Units,
    CLIP_LEVEL, DISPLACE_LARGE, DISPLACE_SMALL, FRACTIONS, MOVING_PEAK, RAIL_UT, SIZES, SPIKE_UT,
    STATIONARY_ROWS, STUCK_RUN,
};
use host_tests::reference::{adc2, RefLs};
use host_tests::sim::Rng;
use mag_cal_core::Config;
use nalgebra::Vector3;

/// Every setting of the study's grid.
fn settings() -> Vec<Setting> {
    let mut v = Vec::new();
    for units in Units::ALL {
        for coverage in Coverage::ALL {
            for n in SIZES {
                v.push(Setting { units, coverage, n });
            }
        }
    }
    v
}

/// A clean run of every setting, from several seeds.
fn runs() -> Vec<CleanRun> {
    let mut v = Vec::new();
    for (i, s) in settings().into_iter().enumerate() {
        for seed in 0..3 {
            v.push(CleanRun::generate(s, &mut Rng(1000 * i as u64 + seed)));
        }
    }
    v
}

/// Every kind at every fraction of `run`.
fn every_contamination(run: &CleanRun, seed: u64) -> Vec<Contaminated> {
    let mut v = Vec::new();
    for (a, kind) in Kind::ALL.into_iter().enumerate() {
        for (b, f) in FRACTIONS.into_iter().enumerate() {
            let mut rng = Rng::for_case(seed, (a * 100 + b) as u64);
            v.push(contaminate(run, kind, f, &mut rng));
        }
    }
    v
}

/// Both views of rows agree: for counts the floats are the `i16` values.
fn check_rows(units: Units, rows: &Rows) {
    match (units, &rows.counts) {
        (Units::Counts, Some(c)) => {
            assert_eq!(c.len(), rows.samples.len());
            for (c, y) in c.iter().zip(&rows.samples) {
                assert_eq!(c.map(f64::from), *y);
            }
        }
        (Units::MicroTesla, None) => {
            assert!(rows.samples.iter().flatten().all(|v| v.is_finite()));
        }
        _ => panic!("counts rows must come with i16 values, uT rows without"),
    }
}

fn diff(a: &[f64; 3], b: &[f64; 3]) -> Vector3<f64> {
    Vector3::from(*a) - Vector3::from(*b)
}

#[test]
fn clean_runs_have_the_asked_shape_and_fit_with_small_error() {
    for run in runs() {
        let s = run.setting;
        assert_eq!(run.len(), s.n);
        assert_eq!(run.dirs.len(), s.n);
        check_rows(s.units, &run.clean);
        let nominal = s.units.nominal_field();
        assert!((run.field / nominal - 1.0368).abs() < 1e-3, "{}", run.field);
        assert!((run.noise_std / run.field - 0.01).abs() < 1e-3);
        assert!(run.truth.b.amax() <= s.units.max_offset());
        if s.coverage == Coverage::Band {
            let zmax = 30f64.to_radians().sin() + 1e-12;
            assert!(run.dirs.iter().all(|h| h.z.abs() <= zmax));
        }
        // The independent reference (LS9 + ADC2 in f64) on the clean rows.
        let fit = adc2(&run.clean.samples, RefLs::Ls9).expect("clean rows fit");
        let e = fit_errors(&fit.b, &fit.w, &run.truth);
        assert!(e.e_m < 0.02 && e.e_b < 0.01, "{s:?}: {e:?}");
    }
}

#[test]
fn generation_is_deterministic() {
    let s = Setting {
        units: Units::Counts,
        coverage: Coverage::Band,
        n: 600,
    };
    let a = CleanRun::generate(s, &mut Rng(7));
    let b = CleanRun::generate(s, &mut Rng(7));
    assert_eq!(a.clean, b.clean);
    for kind in Kind::ALL {
        let x = contaminate(&a, kind, 0.05, &mut Rng(8));
        let y = contaminate(&b, kind, 0.05, &mut Rng(8));
        assert_eq!((&x.rows, &x.marked), (&y.rows, &y.marked), "{kind:?}");
    }
}

#[test]
fn fractions_are_what_was_asked_and_only_marked_rows_change() {
    for (r, run) in runs().iter().enumerate() {
        for c in every_contamination(run, r as u64) {
            let n = run.len();
            let want = rows_for(n, c.fraction);
            assert_eq!(want, (c.fraction * n as f64).round() as usize);
            if c.kind == Kind::RangeClip {
                // Rows already at the clip level (ties in counts) stay as
                // they are.
                assert!(
                    c.count() <= want && (want == 0 || c.count() >= 1),
                    "{:?} {} n {n}: {}",
                    c.kind,
                    c.fraction,
                    c.count()
                );
            } else {
                assert_eq!(c.count(), want, "{:?} {} n {n}", c.kind, c.fraction);
            }
            assert_eq!(c.rows.len(), n);
            check_rows(run.setting.units, &c.rows);
            for i in 0..n {
                assert_eq!(
                    c.marked[i],
                    c.rows.samples[i] != run.clean.samples[i],
                    "{:?} {} row {i}",
                    c.kind,
                    c.fraction
                );
            }
        }
    }
}

#[test]
fn each_kind_changes_rows_as_documented() {
    for (r, run) in runs().iter().enumerate() {
        let units = run.setting.units;
        let rho = run.field;
        // Rounding to counts moves a value by up to half a count an axis.
        let slack = if units == Units::Counts { 0.9 } else { 1e-9 };
        for c in every_contamination(run, 77 + r as u64) {
            let rows = c.marked_rows();
            let y = |i: usize| c.rows.samples[i];
            let clean = |i: usize| run.clean.samples[i];
            let changed_axes = |i: usize| {
                (0..3)
                    .filter(|&a| y(i)[a] != clean(i)[a])
                    .collect::<Vec<_>>()
            };
            match c.kind {
                Kind::Spike => {
                    let range = if units == Units::Counts {
                        32767.0
                    } else {
                        SPIKE_UT
                    };
                    assert!(rows.iter().all(|&i| y(i).iter().all(|v| v.abs() <= range)));
                }
                Kind::RailSaturation => {
                    for &i in &rows {
                        let axes = changed_axes(i);
                        assert_eq!(axes.len(), 1);
                        let v = y(i)[axes[0]];
                        match &c.rows.counts {
                            Some(k) => {
                                let v = k[i][axes[0]];
                                assert!(v == i16::MAX || v == i16::MIN, "{v}");
                            }
                            None => assert_eq!(v.abs(), RAIL_UT),
                        }
                    }
                }
                Kind::ClipSaturation => {
                    for &i in &rows {
                        let axes = changed_axes(i);
                        assert_eq!(axes.len(), 1);
                        let a = axes[0];
                        let col: Vec<f64> = run.clean.samples.iter().map(|y| y[a]).collect();
                        let hi = col.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                        let lo = col.iter().copied().fold(f64::INFINITY, f64::min);
                        let (centre, extent) = (0.5 * (hi + lo), 0.5 * (hi - lo));
                        // At the clip level, and moved towards the centre.
                        let level = (y(i)[a] - centre).abs() / extent;
                        assert!((level - CLIP_LEVEL).abs() < 2.0 / extent, "{level}");
                        assert!((y(i)[a] - centre).abs() < (clean(i)[a] - centre).abs());
                    }
                }
                Kind::RangeClip => {
                    // One axis, one value: the axis's extreme, shared by
                    // every clipped row, and no row beyond it.
                    let axes: Vec<usize> = rows.iter().flat_map(|&i| changed_axes(i)).collect();
                    if let Some(&a) = axes.first() {
                        assert!(axes.iter().all(|&b| b == a));
                        let level = y(rows[0])[a];
                        assert!(rows.iter().all(|&i| y(i)[a] == level));
                        let n = run.clean.samples.len();
                        let beyond = (0..n).filter(|&i| {
                            let (v, l) = (y(i)[a], level);
                            if clean(rows[0])[a] > l {
                                v > l
                            } else {
                                v < l
                            }
                        });
                        assert_eq!(beyond.count(), 0);
                    }
                }
                Kind::Zeros => {
                    assert!(rows.iter().all(|&i| y(i) == [0.0; 3]));
                    if let Some(k) = &c.rows.counts {
                        assert!(rows.iter().all(|&i| k[i] == [0; 3]));
                    }
                }
                Kind::Stuck => {
                    // Every repeat equals the row before it; runs start at an
                    // unmarked (clean) row and are 5-20 long, except at most
                    // one shorter run.
                    let mut lens = Vec::new();
                    let mut i = 0;
                    while i < c.marked.len() {
                        if c.marked[i] {
                            assert!(i > 0 && !c.marked[i - 1]);
                            let source = y(i - 1);
                            assert_eq!(source, clean(i - 1));
                            let mut len = 0;
                            while i < c.marked.len() && c.marked[i] {
                                assert_eq!(y(i), source);
                                len += 1;
                                i += 1;
                            }
                            lens.push(len);
                        } else {
                            i += 1;
                        }
                    }
                    let (short, long) = STUCK_RUN;
                    assert!(lens.iter().all(|&l| l <= long));
                    assert!(lens.iter().filter(|&&l| l < short).count() <= 1, "{lens:?}");
                }
                Kind::Displace03 | Kind::Displace1 => {
                    let length = if c.kind == Kind::Displace03 {
                        DISPLACE_SMALL
                    } else {
                        DISPLACE_LARGE
                    } * rho;
                    for &i in &rows {
                        let d = diff(&y(i), &clean(i)).norm();
                        assert!((d - length).abs() <= slack, "{d} vs {length}");
                    }
                }
                Kind::Patch | Kind::Moving => {
                    // One contiguous stretch.
                    if let (Some(&first), Some(&last)) = (rows.first(), rows.last()) {
                        assert_eq!(last - first + 1, rows.len());
                    }
                    let k = rows.len() as f64;
                    // The largest displacement (the middle of a moving one).
                    let d0 = rows
                        .iter()
                        .map(|&i| diff(&y(i), &clean(i)))
                        .max_by(|a, b| a.norm().total_cmp(&b.norm()));
                    for (j, &i) in rows.iter().enumerate() {
                        let d = diff(&y(i), &clean(i));
                        let want = if c.kind == Kind::Patch {
                            DISPLACE_SMALL
                        } else {
                            let t = (j as f64 + 0.5) / k;
                            MOVING_PEAK * (std::f64::consts::PI * t).sin()
                        } * rho;
                        assert!((d.norm() - want).abs() <= slack, "{} vs {want}", d.norm());
                        // Along one fixed direction (for counts, where the
                        // rounding leaves the direction of a displacement of
                        // a few counts undefined, checked beyond 20 counts).
                        let d0 = d0.expect("a contaminated row");
                        let cos = d.dot(&d0) / (d.norm() * d0.norm());
                        match units {
                            Units::MicroTesla => assert!(cos > 1.0 - 1e-9, "{cos}"),
                            Units::Counts if d.norm() > 20.0 && d0.norm() > 20.0 => {
                                assert!(cos > 0.95, "{cos}")
                            }
                            Units::Counts => {}
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn a_contiguous_stretch_is_a_patch_of_directions() {
    for coverage in Coverage::ALL {
        let setting = Setting {
            units: Units::MicroTesla,
            coverage,
            n: 1000,
        };
        let run = CleanRun::generate(setting, &mut Rng(5));
        // The order is a pure function of the directions.
        let mut again = run.dirs.clone();
        again.reverse();
        order_along_path(&mut again);
        assert_eq!(again, run.dirs);
        // Mean resultant length of every 10 % stretch: 0.9 for a cap of
        // that area (measured on the sphere 0.75-0.89), about 0.1 for 100
        // random directions, 0 for a ring (a stretch sorted by azimuth
        // within latitude bands).
        let worst = (0..10)
            .map(|s| {
                let sum: Vector3<f64> = run.dirs[100 * s..100 * (s + 1)].iter().sum();
                sum.norm() / 100.0
            })
            .fold(f64::INFINITY, f64::min);
        assert!(worst > 0.7, "{coverage:?}: {worst}");
        // Consecutive directions are close: the median step is about the
        // spacing of the points.
        let mut steps: Vec<f64> = run
            .dirs
            .windows(2)
            .map(|w| w[0].dot(&w[1]).clamp(-1.0, 1.0).acos().to_degrees())
            .collect();
        steps.sort_by(f64::total_cmp);
        assert!(steps[500] < 8.0, "{coverage:?}: median step {}", steps[500]);
    }
}

#[test]
fn degenerate_inputs_have_the_documented_shape() {
    for run in runs().iter().step_by(2) {
        let units = run.setting.units;
        let w = run.truth.t.try_inverse().expect("invertible");
        for d in Degenerate::ALL {
            let rows = degenerate(run, d, &mut Rng(9));
            check_rows(units, &rows);
            let u: Vec<Vector3<f64>> = rows
                .samples
                .iter()
                .map(|y| w * (Vector3::from(*y) - run.truth.b))
                .collect();
            match d {
                Degenerate::Stationary => {
                    assert_eq!(rows.len(), STATIONARY_ROWS);
                    let c: Vector3<f64> = u.iter().sum::<Vector3<f64>>() / u.len() as f64;
                    assert!((c.norm() - 1.0).abs() < 0.02);
                    assert!(u.iter().all(|x| (x - c).norm() < 0.08));
                }
                Degenerate::NoiseBall => {
                    assert_eq!(rows.len(), run.len());
                    assert!(u.iter().all(|x| x.norm() < 1.1));
                    // Filled: about half the volume within radius 0.79.
                    let inner = u.iter().filter(|x| x.norm() < 0.7937).count();
                    assert!((inner as f64 / u.len() as f64 - 0.5).abs() < 0.08);
                }
                Degenerate::Cube => {
                    assert_eq!(rows.len(), run.len());
                    let half = run.field + 0.5;
                    assert!(rows
                        .samples
                        .iter()
                        .all(|y| { (0..3).all(|a| (y[a] - run.truth.b[a]).abs() <= half) }));
                }
            }
        }
    }
}

#[test]
fn small_study_runs_and_accepts_clean_data() {
    let mut grid = Grid::full(8);
    grid.fractions = vec![0.01, 0.10];
    let study = run_study(&Config::default(), Precision::F64, &grid);
    let cells_per_block = 1 + Kind::ALL.len() * 2 + Degenerate::ALL.len();
    assert_eq!(study.cells.len(), 4 * cells_per_block);
    for (cell, s) in &study.cells {
        assert_eq!(s.runs, grid.runs, "{cell:?}");
        let refused: usize = s.refusals.values().sum();
        assert_eq!(s.accepted + refused, s.runs, "{cell:?}");
        assert!(s.wrong <= s.accepted && s.wrong_warned <= s.wrong);
        assert_eq!(s.e_m.len(), s.accepted);
        assert_eq!(s.clean_refused, 0, "{cell:?}");
    }
    // Today's core: clean data (1 % noise, sphere or band, counts or uT)
    // are always accepted, and fitted well, in both precisions.
    for p in Precision::ALL {
        let study = if p == Precision::F64 {
            study.clone()
        } else {
            run_study(&Config::default(), p, &grid)
        };
        for (cell, s) in study
            .cells
            .iter()
            .filter(|(c, _)| c.case.label() == "clean")
        {
            assert_eq!(s.accepted, s.runs, "{p:?} {cell:?}");
            let worst_m = s.e_m.iter().copied().fold(0.0, f64::max);
            let worst_b = s.e_b.iter().copied().fold(0.0, f64::max);
            assert!(worst_m < 0.02 && worst_b < 0.02, "{p:?} {cell:?}");
            assert!(s.ratio_m.iter().all(|&r| r == 1.0));
        }
    }
    println!("{}", render_table(&study, "ADC2 (Config::default())"));
}
