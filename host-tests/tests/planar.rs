//! Planar (heading-only) calibration (`mag_cal_core::planar`): a level
//! vehicle turning about its vertical axis with tilts of 0-10 deg, the
//! heading against the truth, and against the three-dimensional fit of
//! the same sensor on full-sphere data. Run with `--nocapture` for the
//! table of `docs/results.md`.

use host_tests::real::read_xyz;
use host_tests::sim::{fibonacci_sphere, Rng};
use mag_cal_core::heading::heading_deg;
use mag_cal_core::planar::{calibrate_planar, PlanarConfig, PlanarFit};
use mag_cal_core::{calibrate, Config, Error};
use nalgebra::{Matrix3, Rotation3, Vector3};

/// The sensor: a symmetric soft iron (field 400 counts; symmetric, so the
/// three-dimensional fit's frame is the body frame and its heading has no
/// mounting error) and a hard iron.
fn sensor() -> (Matrix3<f64>, Vector3<f64>) {
    let s = Matrix3::new(1.15, 0.06, -0.03, 0.06, 0.92, 0.04, -0.03, 0.04, 1.02);
    (s * 400.0, Vector3::new(120.0, -75.0, 40.0))
}

/// The earth's field in NED, inclination 60 deg, unit strength.
fn earth() -> Vector3<f64> {
    let inc = 60f64.to_radians();
    Vector3::new(inc.cos(), 0.0, inc.sin())
}

/// World-to-body rotation of a vehicle at heading `psi`, pitch `theta`,
/// roll `phi` (radians, the NED Euler convention).
fn attitude(psi: f64, theta: f64, phi: f64) -> Matrix3<f64> {
    let body_to_world = Rotation3::from_euler_angles(phi, theta, psi);
    body_to_world.matrix().transpose()
}

/// A noisy reading (1 % of the field per axis) of the body field `h`.
fn reading(h: Vector3<f64>, rng: &mut Rng) -> [f64; 3] {
    let (t, b) = sensor();
    let noise = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 4.0;
    let y = t * h + b + noise;
    [y.x, y.y, y.z]
}

/// `n` readings of two turns at a varying rate, with roll and pitch
/// wandering within `tilt` degrees; and the true headings.
fn level_turns(tilt: f64, n: usize, seed: u64) -> (Vec<[f64; 3]>, Vec<f64>) {
    let mut rng = Rng::for_case(seed, 1);
    let (mut samples, mut headings) = (Vec::new(), Vec::new());
    let (p1, p2) = (rng.uniform() * 6.0, rng.uniform() * 6.0);
    for i in 0..n {
        let s = i as f64 / n as f64;
        let psi = std::f64::consts::TAU * (2.0 * s + 0.1 * (9.0 * s).sin());
        let k = tilt.to_radians();
        let theta = k * (7.0 * s * std::f64::consts::TAU + p1).sin();
        let phi = k * (5.0 * s * std::f64::consts::TAU + p2).cos();
        let h = attitude(psi, theta, phi) * earth();
        samples.push(reading(h, &mut rng));
        headings.push(psi.to_degrees());
    }
    (samples, headings)
}

fn wrap(d: f64) -> f64 {
    (d + 540.0).rem_euclid(360.0) - 180.0
}

/// RMS and largest heading error, after removing the constant offset (the
/// circular mean of the differences: one alignment with a known heading,
/// without that reading's noise).
fn errors(est: &[f64], truth: &[f64]) -> (f64, f64) {
    let (s, c) = est.iter().zip(truth).fold((0.0, 0.0), |(s, c), (h, t)| {
        let d = (h - t).to_radians();
        (s + d.sin(), c + d.cos())
    });
    let offset = f64::atan2(s, c).to_degrees();
    let e: Vec<f64> = est
        .iter()
        .zip(truth)
        .map(|(h, t)| wrap(h - t - offset))
        .collect();
    let rms = (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt();
    (rms, e.iter().fold(0.0f64, |m, x| m.max(x.abs())))
}

fn planar(samples: &[[f64; 3]]) -> Result<PlanarFit<f64>, Error> {
    calibrate_planar::<f64, _>(samples, &PlanarConfig::default())
}

/// Heading errors (RMS, largest) of one run.
struct Comparison {
    /// The planar fit of the tilted turns, on level turns.
    planar_level: (f64, f64),
    /// The 3-D fit of the same sensor on 400 full-sphere readings, on the
    /// same level turns.
    full_level: (f64, f64),
    /// The planar fit on the tilted turns it was fitted to.
    planar_tilted: (f64, f64),
    /// The 3-D fit on the tilted turns, heading without tilt compensation.
    full_tilted: (f64, f64),
    fit: PlanarFit<f64>,
}

fn compare(tilt: f64, seed: u64, config: &PlanarConfig) -> Comparison {
    let (tilted, tilted_truth) = level_turns(tilt, 300, seed);
    let fit =
        calibrate_planar::<f64, _>(&tilted, config).unwrap_or_else(|e| panic!("tilt {tilt}: {e}"));
    let (level, truth) = level_turns(0.0, 300, seed + 1000);
    let mut rng = Rng::for_case(seed, 2);
    let sphere: Vec<[f64; 3]> = fibonacci_sphere(400)
        .into_iter()
        .map(|h| reading(h, &mut rng))
        .collect();
    let full = calibrate::<f64, _>(&sphere, &Config::default()).expect("3-D fit");
    let planar_on = |s: &[[f64; 3]]| -> Vec<f64> {
        s.iter().map(|y| fit.calibration.heading_deg(*y)).collect()
    };
    let full_on = |s: &[[f64; 3]]| -> Vec<f64> {
        s.iter()
            .map(|y| heading_deg(full.calibration.apply(*y)))
            .collect()
    };
    Comparison {
        planar_level: errors(&planar_on(&level), &truth),
        full_level: errors(&full_on(&level), &truth),
        planar_tilted: errors(&planar_on(&tilted), &tilted_truth),
        full_tilted: errors(&full_on(&tilted), &tilted_truth),
        fit,
    }
}

#[test]
fn level_turns_give_the_heading_of_a_full_calibration() {
    let seeds = 20;
    // Measured past the default fit-error limit, which refuses the tilts
    // of 10 deg (their fit error is about 0.2 of the horizontal field).
    let mut wide = PlanarConfig::default();
    wide.thresholds.refuse_fit_error = 1.0;
    println!(
        "| tilt while turning | planar, on level turns | 3-D fit, on level turns | planar, on the tilted turns | \
         3-D fit, on the tilted turns | fit error | thickness | refused by default |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for tilt in [0.0, 2.0, 5.0, 10.0] {
        let mut runs: Vec<Comparison> = (0..seeds).map(|seed| compare(tilt, seed, &wide)).collect();
        let refused = (0..seeds)
            .filter(|&seed| {
                let (s, _) = level_turns(tilt, 300, seed);
                calibrate_planar::<f64, _>(&s, &PlanarConfig::default()).is_err()
            })
            .count();
        for r in &runs {
            assert!(
                r.fit.report.axis_tilt_deg < 15.0,
                "{}",
                r.fit.report.axis_tilt_deg
            );
            assert_eq!(r.fit.report.sectors, 12);
        }
        let med = |runs: &mut Vec<Comparison>, f: fn(&Comparison) -> (f64, f64)| {
            runs.sort_by(|a, b| f(a).0.total_cmp(&f(b).0));
            f(&runs[runs.len() / 2])
        };
        let pl = med(&mut runs, |r| r.planar_level);
        let fl = med(&mut runs, |r| r.full_level);
        let pt = med(&mut runs, |r| r.planar_tilted);
        let ft = med(&mut runs, |r| r.full_tilted);
        let fe = med(&mut runs, |r| (r.fit.report.fit_error, 0.0)).0;
        let th = med(&mut runs, |r| (r.fit.report.thickness, 0.0)).0;
        println!(
            "| {tilt} deg | {:.2} deg ({:.1}) | {:.2} deg ({:.1}) | {:.2} deg ({:.1}) | {:.2} deg ({:.1}) | \
             {fe:.3} | {th:.3} | {refused} of {seeds} |",
            pl.0, pl.1, fl.0, fl.1, pt.0, pt.1, ft.0, ft.1
        );
        if tilt == 0.0 {
            // Level: the planar fit is as good as the full calibration (the
            // noise of a reading alone is 1.15 deg RMS of heading).
            assert!(pl.0 < 1.5 && pl.0 < 1.1 * fl.0, "{pl:?} {fl:?}");
            assert_eq!(refused, 0);
        }
        if tilt <= 5.0 {
            assert_eq!(refused, 0, "tilt {tilt}");
        }
        // On tilted turns, both fits pay the tilt of an uncompensated
        // heading; the planar one no more than the 3-D one and its own
        // calibration error.
        assert!(pt.0 < ft.0 + pl.0, "{tilt}: {pt:?} {ft:?} {pl:?}");
    }
}

#[test]
fn recovers_the_ellipse_in_the_plane() {
    // Without noise or tilt, u = K (y - centre) is the unit circle and the
    // centre's in-plane part is that of b + cos(theta) T a.
    let (t, b) = sensor();
    let samples: Vec<[f64; 3]> = (0..200)
        .map(|i| {
            let h = attitude(i as f64 * 0.0631, 0.0, 0.0) * earth();
            let y = t * h + b;
            [y.x, y.y, y.z]
        })
        .collect();
    let fit = planar(&samples).unwrap();
    let cal = fit.calibration;
    for s in &samples {
        let [x, y] = cal.apply(*s);
        assert!(((x * x + y * y).sqrt() - 1.0).abs() < 1e-9);
    }
    // The true ellipse centre: b + T (0, 0, sin(inc)) in the body frame
    // (level: the vertical component is the same in every reading).
    let centre = b + t * Vector3::new(0.0, 0.0, earth().z);
    let got = Vector3::from(cal.centre());
    let axis = Vector3::from(cal.axis());
    let off = (got - centre) - axis * axis.dot(&(got - centre));
    assert!(off.norm() < 1e-6, "{off}");
    // Axis: the normal of the plane T spans with the horizontal axes.
    let normal = (t * Vector3::x()).cross(&(t * Vector3::y())).normalize();
    assert!(axis.dot(&normal).abs() > 1.0 - 1e-9);
    // The field strength in the plane: the horizontal field through T.
    let h = cal.plane_strength();
    assert!(h > 0.5 * 0.92 * 400.0 && h < 0.5 * 1.15 * 400.0, "{h}");
    assert_eq!(fit.report.rejected, 0);
    assert!(fit.report.fit_error < 1e-6);
}

#[test]
fn heading_turns_with_the_device() {
    // Heading increases clockwise seen from above, whichever way the
    // sensor's axes point, as long as `up` names the upward axis.
    let (t, b) = sensor();
    let flip = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0)); // z up
    for (frame, up) in [
        (Matrix3::identity(), [0.0, 0.0, -1.0]),
        (flip, [0.0, 0.0, 1.0]),
    ] {
        let samples: Vec<[f64; 3]> = (0..100)
            .map(|i| {
                let h = frame * attitude(i as f64 * 0.0631, 0.0, 0.0) * earth();
                let y = t * h + b;
                [y.x, y.y, y.z]
            })
            .collect();
        let fit = calibrate_planar::<f64, _>(&samples, &PlanarConfig::with_up(up)).unwrap();
        let cal = fit.calibration.aligned(samples[0], 0.0).unwrap();
        let h = cal.heading_deg(samples[5]);
        assert!((h - (5.0 * 0.0631f64).to_degrees()).abs() < 1e-6, "{h}");
    }
}

#[test]
fn refuses_what_is_not_a_turn_about_one_axis() {
    let mut rng = Rng::for_case(7, 0);
    // The full sphere: not planar.
    let sphere: Vec<[f64; 3]> = fibonacci_sphere(300)
        .into_iter()
        .map(|h| reading(h, &mut rng))
        .collect();
    assert!(
        matches!(planar(&sphere), Err(Error::NotPlanar { .. })),
        "{:?}",
        planar(&sphere).map(|f| f.report)
    );
    // Half a turn: too short an arc.
    let half: Vec<[f64; 3]> = (0..200)
        .map(|i| reading(attitude(i as f64 * 0.0157, 0.0, 0.0) * earth(), &mut rng))
        .collect();
    assert!(
        matches!(planar(&half), Err(Error::ShortArc { .. })),
        "{:?}",
        planar(&half).map(|f| f.report)
    );
    // A device lying still: noise around one point.
    let still: Vec<[f64; 3]> = (0..200).map(|_| reading(earth(), &mut rng)).collect();
    let e = planar(&still).unwrap_err();
    assert!(
        matches!(e, Error::NoEllipse { .. } | Error::NotPlanar { .. }),
        "{e}"
    );
    // A flat disc filled with points: no ellipse.
    let disc: Vec<[f64; 3]> = (0..300)
        .map(|_| {
            let r = rng.uniform().sqrt() * 300.0;
            let a = rng.uniform() * std::f64::consts::TAU;
            [r * a.cos(), r * a.sin(), 5.0 * rng.normal()]
        })
        .collect();
    let e = planar(&disc).unwrap_err();
    assert!(matches!(e, Error::NoEllipse { .. }), "{e}");
}

#[test]
fn glitches_and_a_passing_magnet_do_not_bend_the_heading() {
    let (clean, truth) = level_turns(2.0, 400, 11);
    let mut dirty = clean.clone();
    let mut rng = Rng::for_case(11, 9);
    // 2 % wild readings, five zero rows, 3 % displaced by 0.3 of the field.
    for k in 0..8 {
        dirty[k * 50 + 3] = [rng.normal() * 5000.0, rng.normal() * 5000.0, 30000.0];
    }
    for k in 0..5 {
        dirty[k * 70 + 7] = [0.0, 0.0, 0.0];
    }
    for row in &mut dirty[200..212] {
        row[0] += 120.0;
    }
    let fit_clean = planar(&clean).unwrap();
    let fit = planar(&dirty).unwrap();
    assert_eq!(fit.report.drops.zero, 5);
    // The wild rows share their z value: the clip rule drops them.
    assert!(
        fit.report.screened + fit.report.drops.clipped >= 8,
        "{:?}",
        fit.report
    );
    assert!(fit.report.rejected >= 10, "{:?}", fit.report);
    let heading = |f: &PlanarFit<f64>| -> Vec<f64> {
        clean
            .iter()
            .map(|s| f.calibration.heading_deg(*s))
            .collect()
    };
    let (rms_clean, _) = errors(&heading(&fit_clean), &truth);
    let (rms, _) = errors(&heading(&fit), &truth);
    assert!(rms < 1.2 * rms_clean + 0.1, "{rms} against {rms_clean}");
}

#[test]
fn single_precision_agrees_with_double() {
    let (samples, _) = level_turns(5.0, 300, 3);
    let f64_fit = planar(&samples).unwrap();
    let s32: Vec<[f32; 3]> = samples.iter().map(|s| s.map(|v| v as f32)).collect();
    let f32_fit = calibrate_planar::<f32, _>(&s32, &PlanarConfig::default()).unwrap();
    for (a, b) in samples.iter().zip(&s32) {
        let h64 = f64_fit.calibration.heading_deg(*a);
        let h32 = f32_fit.calibration.heading_deg(*b) as f64;
        assert!(wrap(h64 - h32).abs() < 0.01, "{h64} {h32}");
    }
}

#[test]
fn the_real_planar_recording_gets_a_heading_calibration() {
    // `planar_243.txt`: a sensor turned about its z axis (z 503..577 uT
    // while x and y swing by hundreds); the 3-D fit refuses it.
    let samples = read_xyz("planar_243.txt");
    assert!(matches!(
        calibrate::<f64, _>(&samples, &Config::default()),
        Err(Error::Planar)
    ));
    let fit = calibrate_planar::<f64, _>(&samples, &PlanarConfig::with_up([0.0, 0.0, 1.0]))
        .unwrap_or_else(|e| panic!("{e}"));
    let r = fit.report;
    println!(
        "planar_243.txt: {} used, {:?}, {} screened, {} rejected; flatness {:.4}, fit error {:.4}, \
         sectors {}, thickness {:.4}, axis {:.1} deg from z; centre {:?}, plane strength {:.2}; {} passes",
        r.samples_used,
        r.drops,
        r.screened,
        r.rejected,
        r.flatness,
        r.fit_error,
        r.sectors,
        r.thickness,
        r.axis_tilt_deg,
        fit.calibration.centre(),
        fit.calibration.plane_strength(),
        r.passes
    );
    assert!(r.fit_error < 0.05, "{r:?}");
    assert!(r.axis_tilt_deg < 20.0, "{r:?}");
    assert!(r.samples_used + r.rejected + r.screened + r.drops.total() == samples.len());
}
