//! Planar (heading-only) calibration (`mag_cal_core::planar`): a level
//! vehicle turning about its vertical axis with tilts of 0-10 deg, the
//! heading against the truth, and against the three-dimensional fit of
//! the same sensor on full-sphere data (`host_tests::planar`; the
//! `planar-table` binary writes its table into `docs/results.md`).

use host_tests::planar::{
    attitude, earth, errors, level_turns, planar, reading, render, sensor, tilt_study, wrap,
};
use host_tests::real::read_xyz;
use host_tests::sim::{fibonacci_sphere, Rng};
use mag_cal_core::planar::{self, calibrate_planar, PlanarConfig, PlanarFit};
use mag_cal_core::{calibrate, Config, Error};
use nalgebra::{Matrix3, Vector3};

#[test]
fn level_turns_give_the_heading_of_a_full_calibration() {
    let rows = tilt_study(&[0.0, 2.0, 5.0, 10.0], 20);
    print!("{}", render(&rows));
    for r in &rows {
        assert!(r.sane, "{r:?}");
        let (pl, fl) = (r.planar_level, r.full_level);
        if r.tilt == 0.0 {
            // Level: the planar fit is as good as the full calibration (the
            // noise of a reading alone is 1.15 deg RMS of heading).
            assert!(pl.0 < 1.5 && pl.0 < 1.1 * fl.0, "{r:?}");
        }
        if r.tilt <= 5.0 {
            assert_eq!(r.refused, 0, "{r:?}");
        }
        // On tilted turns, both fits pay the tilt of an uncompensated
        // heading; the planar one no more than the 3-D one and its own
        // calibration error.
        assert!(r.planar_tilted.0 < r.full_tilted.0 + pl.0, "{r:?}");
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
        matches!(planar(&sphere), Err(planar::Error::NotPlanar { .. })),
        "{:?}",
        planar(&sphere).map(|f| f.report)
    );
    // Half a turn: too short an arc.
    let half: Vec<[f64; 3]> = (0..200)
        .map(|i| reading(attitude(i as f64 * 0.0157, 0.0, 0.0) * earth(), &mut rng))
        .collect();
    assert!(
        matches!(planar(&half), Err(planar::Error::ShortArc { .. })),
        "{:?}",
        planar(&half).map(|f| f.report)
    );
    // A device lying still: noise around one point.
    let still: Vec<[f64; 3]> = (0..200).map(|_| reading(earth(), &mut rng)).collect();
    let e = planar(&still).unwrap_err();
    assert!(
        matches!(
            e,
            planar::Error::NoEllipse { .. } | planar::Error::NotPlanar { .. }
        ),
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
    assert!(matches!(e, planar::Error::NoEllipse { .. }), "{e}");
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
        Err(Error::Planar { .. })
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
