//! Planar (heading-only) calibration on simulated level turns: the sensor,
//! the turns with tilts, and the heading errors of the planar fit against
//! the truth and against the three-dimensional fit of the same sensor
//! (`tests/planar.rs`, and the `planar-table` binary for
//! `docs/results.md`); the ground robot's log of issue 36 ("still, one
//! slow turn, still": [`robot_log`]) and how far a planar fit lies from
//! another ([`Shift`]), for `tests/still_planar.rs` and the `still-table`
//! binary.

use mag_cal_core::heading::heading_deg;
use mag_cal_core::planar::{calibrate_planar, Error, PlanarCalibration, PlanarConfig, PlanarFit};
use mag_cal_core::{calibrate, Config, Real};
use nalgebra::{Matrix3, Rotation3, SMatrix, Vector3};

use crate::sim::{fibonacci_sphere, Rng};

/// The sensor: a symmetric soft iron (field 400 counts; symmetric, so the
/// three-dimensional fit's frame is the body frame and its heading has no
/// mounting error) and a hard iron.
pub fn sensor() -> (Matrix3<f64>, Vector3<f64>) {
    let s = Matrix3::new(1.15, 0.06, -0.03, 0.06, 0.92, 0.04, -0.03, 0.04, 1.02);
    (s * 400.0, Vector3::new(120.0, -75.0, 40.0))
}

/// The earth's field in NED, inclination 60 deg, unit strength.
pub fn earth() -> Vector3<f64> {
    let inc = 60f64.to_radians();
    Vector3::new(inc.cos(), 0.0, inc.sin())
}

/// World-to-body rotation of a vehicle at heading `psi`, pitch `theta`,
/// roll `phi` (radians, the NED Euler convention).
pub fn attitude(psi: f64, theta: f64, phi: f64) -> Matrix3<f64> {
    let body_to_world = Rotation3::from_euler_angles(phi, theta, psi);
    body_to_world.matrix().transpose()
}

/// A noisy reading (1 % of the field per axis) of the body field `h`.
pub fn reading(h: Vector3<f64>, rng: &mut Rng) -> [f64; 3] {
    let (t, b) = sensor();
    let noise = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 4.0;
    let y = t * h + b + noise;
    [y.x, y.y, y.z]
}

/// `n` readings of two turns at a varying rate, with roll and pitch
/// wandering within `tilt` degrees; and the true headings.
pub fn level_turns(tilt: f64, n: usize, seed: u64) -> (Vec<[f64; 3]>, Vec<f64>) {
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

/// An angle difference in `[-180, 180)` degrees.
pub fn wrap(d: f64) -> f64 {
    (d + 540.0).rem_euclid(360.0) - 180.0
}

/// RMS and largest heading error, after removing the constant offset (the
/// circular mean of the differences: one alignment with a known heading,
/// without that reading's noise).
pub fn errors(est: &[f64], truth: &[f64]) -> (f64, f64) {
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

/// The planar fit with the default configuration.
pub fn planar(samples: &[[f64; 3]]) -> Result<PlanarFit<f64>, mag_cal_core::planar::Error> {
    calibrate_planar::<f64, _>(samples, &PlanarConfig::default())
}

/// Heading errors (RMS, largest) of one run.
pub struct Comparison {
    /// The planar fit of the tilted turns, on level turns.
    pub planar_level: (f64, f64),
    /// The 3-D fit of the same sensor on 400 full-sphere readings, on the
    /// same level turns.
    pub full_level: (f64, f64),
    /// The planar fit on the tilted turns it was fitted to.
    pub planar_tilted: (f64, f64),
    /// The 3-D fit on the tilted turns, heading without tilt compensation.
    pub full_tilted: (f64, f64),
    pub fit: PlanarFit<f64>,
}

/// One run: the fit of tilted turns (seed `seed`) and its errors.
pub fn compare(tilt: f64, seed: u64, config: &PlanarConfig) -> Comparison {
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

/// The medians over `seeds` runs at one tilt.
#[derive(Clone, Copy, Debug)]
pub struct TiltRow {
    /// Tilt while turning, degrees.
    pub tilt: f64,
    /// Median (RMS, largest) heading errors, degrees.
    pub planar_level: (f64, f64),
    /// See [`Comparison`].
    pub full_level: (f64, f64),
    /// See [`Comparison`].
    pub planar_tilted: (f64, f64),
    /// See [`Comparison`].
    pub full_tilted: (f64, f64),
    /// Median fit error of the planar fit.
    pub fit_error: f64,
    /// Median thickness.
    pub thickness: f64,
    /// Runs the default thresholds refuse.
    pub refused: usize,
    /// Runs.
    pub seeds: u64,
    /// Every run's fit had full coverage and an axis within 15 deg of up.
    pub sane: bool,
}

/// The study of the table: `seeds` runs at each tilt, measured past the
/// default fit-error limit (which refuses most tilts of 10 deg, whose fit
/// error is about 0.2 of the horizontal field).
pub fn tilt_study(tilts: &[f64], seeds: u64) -> Vec<TiltRow> {
    let mut wide = PlanarConfig::default();
    wide.thresholds.refuse_fit_error = 1.0;
    tilts
        .iter()
        .map(|&tilt| {
            let mut runs: Vec<Comparison> =
                (0..seeds).map(|seed| compare(tilt, seed, &wide)).collect();
            let refused = (0..seeds)
                .filter(|&seed| {
                    let (s, _) = level_turns(tilt, 300, seed);
                    calibrate_planar::<f64, _>(&s, &PlanarConfig::default()).is_err()
                })
                .count();
            let sane = runs
                .iter()
                .all(|r| r.fit.report.axis_tilt_deg < 15.0 && r.fit.report.sectors == 12);
            let med = |runs: &mut Vec<Comparison>, f: fn(&Comparison) -> (f64, f64)| {
                runs.sort_by(|a, b| f(a).0.total_cmp(&f(b).0));
                f(&runs[runs.len() / 2])
            };
            TiltRow {
                tilt,
                planar_level: med(&mut runs, |r| r.planar_level),
                full_level: med(&mut runs, |r| r.full_level),
                planar_tilted: med(&mut runs, |r| r.planar_tilted),
                full_tilted: med(&mut runs, |r| r.full_tilted),
                fit_error: med(&mut runs, |r| (r.fit.report.fit_error, 0.0)).0,
                thickness: med(&mut runs, |r| (r.fit.report.thickness, 0.0)).0,
                refused,
                seeds,
                sane,
            }
        })
        .collect()
}

/// The markdown table of a study.
pub fn render(rows: &[TiltRow]) -> String {
    let mut t = String::from(
        "| tilt while turning | planar, on level turns | 3-D fit, on level turns | planar, on the tilted turns | \
         3-D fit, on the tilted turns | fit error | thickness | refused by default |\n\
         |---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        t.push_str(&format!(
            "| {} deg | {:.2} deg ({:.1}) | {:.2} deg ({:.1}) | {:.2} deg ({:.1}) | {:.2} deg ({:.1}) | \
             {:.3} | {:.3} | {} of {} |\n",
            r.tilt,
            r.planar_level.0,
            r.planar_level.1,
            r.full_level.0,
            r.full_level.1,
            r.planar_tilted.0,
            r.planar_tilted.1,
            r.full_tilted.0,
            r.full_tilted.1,
            r.fit_error,
            r.thickness,
            r.refused,
            r.seeds
        ));
    }
    t
}

/// The robot's sensor: soft iron (field 400 counts) and hard iron.
pub fn robot_sensor() -> (Matrix3<f64>, Vector3<f64>) {
    let s = Matrix3::new(1.12, 0.05, -0.02, 0.05, 0.93, 0.03, -0.02, 0.03, 1.01);
    (s * 400.0, Vector3::new(85.0, -140.0, 30.0))
}

/// The robot's field in the plane of its turns (the horizontal field
/// through the soft iron), counts: the RMS distance of the noiseless turn
/// from its centre.
pub fn robot_plane_field() -> f64 {
    let (t, _) = robot_sensor();
    let body = |psi: f64| t * (attitude(psi, 0.0, 0.0) * earth());
    let n = 720;
    let pts: Vec<Vector3<f64>> = (0..n)
        .map(|i| body(i as f64 / n as f64 * std::f64::consts::TAU))
        .collect();
    let mean = pts.iter().sum::<Vector3<f64>>() / n as f64;
    (pts.iter().map(|p| (p - mean).norm_squared()).sum::<f64>() / n as f64).sqrt()
}

/// A reading of the level robot at heading `psi` (radians), normal noise
/// of `sigma` counts per axis, its length clipped at 2.2 sigma (the log has
/// no row beyond 5 % of the field).
pub fn robot_reading(psi: f64, sigma: f64, rng: &mut Rng) -> [f64; 3] {
    let (t, b) = robot_sensor();
    let h = attitude(psi, 0.0, 0.0) * earth();
    let n = Vector3::new(rng.normal(), rng.normal(), rng.normal());
    let n = n * (2.2 / n.norm()).min(1.0) * sigma;
    let y = t * h + b + n;
    [y.x, y.y, y.z]
}

/// "Still, one slow turn, still": `still` rows at the start heading with
/// noise `still_noise` (share of the field in the plane, per axis), `turn`
/// rows of `turns` slow turns with noise `turn_noise`, `still` rows at the
/// end heading. The rows, and the range of the turn's.
pub fn robot_log(
    still: usize,
    turn: usize,
    (still_noise, turn_noise): (f64, f64),
    turns: f64,
    seed: u64,
) -> (Vec<[f64; 3]>, std::ops::Range<usize>) {
    let mut rng = Rng::for_case(seed, 36);
    let field = robot_plane_field();
    let (start, end) = (0.3, 0.3 + turns * std::f64::consts::TAU);
    let mut rows: Vec<[f64; 3]> = (0..still)
        .map(|_| robot_reading(start, still_noise * field, &mut rng))
        .collect();
    for i in 0..turn {
        let psi = start + (end - start) * (i as f64 + 0.5) / turn as f64;
        rows.push(robot_reading(psi, turn_noise * field, &mut rng));
    }
    rows.extend((0..still).map(|_| robot_reading(end, still_noise * field, &mut rng)));
    (rows, still..still + turn)
}

/// The heading error that 1 % of the field makes at most: `asin(0.01)`.
pub const HEADING_OF_ONE_PERCENT: f64 = 0.573;

/// How far a fit lies from the fit without the still rows, in units of the
/// latter's field in the plane: the centre within the plane, the field
/// strength, `K^T K` (Frobenius, relative to its norm), and the largest
/// heading difference over the recording's rows (degrees, their mean
/// difference removed: one alignment).
#[derive(Clone, Copy, Debug, Default)]
pub struct Shift {
    pub centre: f64,
    pub field: f64,
    pub m: f64,
    pub heading: f64,
}

impl Shift {
    /// The shift of `fit` from `base`, the heading over `rows`.
    pub fn of<T: Real>(base: &PlanarFit<T>, fit: &PlanarFit<T>, rows: &[[f64; 3]]) -> Self {
        let f = |v: T| v.to_f64();
        let (a, b) = (&base.calibration, &fit.calibration);
        let rho = f(a.plane_strength());
        let axis = Vector3::from(a.axis().map(f));
        let dc = Vector3::from(b.centre().map(f)) - Vector3::from(a.centre().map(f));
        let in_plane = dc - axis * dc.dot(&axis);
        let k = |c: &PlanarCalibration<T>| {
            let m = c.matrix();
            SMatrix::<f64, 2, 3>::from_fn(|i, j| f(m[i][j]))
        };
        let (ka, kb) = (k(a), k(b));
        let (ma, mb) = (ka.transpose() * ka, kb.transpose() * kb);
        let diffs: Vec<f64> = rows
            .iter()
            .map(|r| {
                let s = r.map(|v| T::lit(v));
                f(b.turn_angle_deg(s)) - f(a.turn_angle_deg(s))
            })
            .collect();
        let (sin, cos) = diffs.iter().fold((0.0, 0.0), |(s, c), d| {
            (s + d.to_radians().sin(), c + d.to_radians().cos())
        });
        let mean = f64::atan2(sin, cos).to_degrees();
        let heading = diffs
            .iter()
            .map(|d| ((d - mean + 540.0).rem_euclid(360.0) - 180.0).abs())
            .fold(0.0, f64::max);
        Self {
            centre: in_plane.norm() / rho,
            field: (f(b.plane_strength()) - rho).abs() / rho,
            m: (mb - ma).norm() / ma.norm(),
            heading,
        }
    }

    /// The larger of each part.
    pub fn max(self, o: Self) -> Self {
        Self {
            centre: self.centre.max(o.centre),
            field: self.field.max(o.field),
            m: self.m.max(o.m),
            heading: self.heading.max(o.heading),
        }
    }

    /// Within 1 % of the field (and the heading error that makes).
    pub fn within_one_percent(&self) -> bool {
        self.centre < 0.01
            && self.field < 0.01
            && self.m < 0.01
            && self.heading < HEADING_OF_ONE_PERCENT
    }
}

impl std::fmt::Display for Shift {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "centre {:.3} %, field {:.3} %, K'K {:.3} %, heading {:.3} deg",
            100.0 * self.centre,
            100.0 * self.field,
            100.0 * self.m,
            self.heading
        )
    }
}

/// A planar refusal's cause: its variant (the shared refusals by theirs),
/// e.g. `ShortArc`, `TooManyOutliers`.
pub fn cause(e: &Error) -> String {
    let text = match e {
        Error::Fit(inner) => format!("{inner:?}"),
        other => format!("{other:?}"),
    };
    text.split([' ', '{', '(']).next().unwrap_or("").to_owned()
}
