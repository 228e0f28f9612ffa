//! Seeded, reproducible fuzzing of mag-cal-core's public API: no input
//! panics, and every `Ok` is well formed.
//!
//! A hand-rolled generator (SplitMix64, no dependency) builds each case from
//! `(seed, index)` alone, so any case can be replayed by its index. The
//! cases cover every class of floating-point value (NaN with payloads and
//! both signs, +-inf, subnormals, +-0, 1e38, `f32::MAX`, `f64::MAX`,
//! arbitrary bit patterns), and sample sets of every shape: garbage, short
//! slices (0..12 samples), long ones (up to 4000), duplicates, ellipsoids
//! with huge offsets and tiny radii, tiny everything, huge everything,
//! planes, lines, caps, clusters, integer grids, with special values mixed
//! in.
//!
//! - `fuzz_calibrate`: one case is one sample set, in one sample type
//!   (`[i16; 3]`, `[i32; 3]`, `[f32; 3]` or `[f64; 3]`) and one precision
//!   (`f32` or `f64`), run through every method and LS variant (15
//!   `calibrate` calls) with one `Config` (the default, or iteration and
//!   pass caps from 0 to 1000, any pass tolerance, noise covariance and
//!   expected field strength, garbage included). Every `Ok` must have a
//!   finite `b` and `W`, a finite positive field strength equal to
//!   `det(W)^(-1/3)` (recomputed in `f64`, to 64 ulps of the precision),
//!   `samples_used + samples_dropped == len`, `samples_used >= 10`, a
//!   finite radial RMS, and name the method and variant that ran.
//! - `fuzz_calibration_align_heading`: `Calibration::new`/`apply`,
//!   `AlignedCalibration`, `procrustes` (arbitrary pairs, rotated and
//!   reflected copies; an `Ok` must be a rotation), `heading_deg`,
//!   `tilt_compensated_heading_deg`, `wrap_deg` (results in (-180, 180]),
//!   `HeadingSmoother` (any window, any values), `SampleStore` past its
//!   capacity.
//! - `fuzz_collector_persist`: `Collector::offer` on every sample of a set
//!   (`Full` exactly when full, progress consistent, centre finite), and
//!   `persist`: round trips of arbitrary calibrations in `f64` and `f32`
//!   must be exact, a one-byte change or a truncation must be refused,
//!   arbitrary bytes give an error or a valid calibration.
//!
//! A panic is caught per case and reported with the case's index; the test
//! fails at the end with every failing index.
//!
//! Environment:
//! - `MAGCAL_FUZZ_CASES`: cases per test (defaults 4000, 5000 and 2000: a
//!   few seconds in the test profile);
//! - `MAGCAL_FUZZ_SEED`: the seed (default `0x6d61_6763_616c_0001`);
//! - `MAGCAL_FUZZ_THREADS`: worker threads (default: available cores);
//! - `MAGCAL_FUZZ_CASE`: run only this case index, printing it (to replay
//!   a failure);
//! - `MAGCAL_FUZZ_BY_SHAPE`: also tally `calibrate`'s outcomes per shape.
//!
//! The long run (see docs/robustness.md):
//! `MAGCAL_FUZZ_CASES=1000000 cargo test --release -p host-tests --test fuzz_core -- --nocapture`

use std::collections::BTreeMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use host_tests::sim;
use mag_cal_core::align::{procrustes, AlignedCalibration};
use mag_cal_core::collector::{Collector, Offer};
use mag_cal_core::heading::{heading_deg, tilt_compensated_heading_deg, wrap_deg, HeadingSmoother};
use mag_cal_core::offsets::{refit_offsets, Strength};
use mag_cal_core::planar::{calibrate_planar, PlanarConfig};
use mag_cal_core::{
    calibrate, persist, Calibration, Config, Error, Fit, LsVariant, Method, Real, Sample,
    SampleClass, SampleStore, Thresholds, MIN_SAMPLES,
};
use nalgebra::{Matrix3, Vector3};

const DEFAULT_SEED: u64 = 0x6d61_6763_616c_0001;

/// A case running longer than this is reported (while it runs and at the
/// end); it does not fail the test.
const SLOW_SECS: u64 = 5;

// --- The generator -----------------------------------------------------------

/// The case generator: the host tests' SplitMix64 (`sim::Rng`) with the
/// draws the fuzz cases need.
struct Rng(sim::Rng);

impl std::ops::Deref for Rng {
    type Target = sim::Rng;
    fn deref(&self) -> &sim::Rng {
        &self.0
    }
}

impl std::ops::DerefMut for Rng {
    fn deref_mut(&mut self) -> &mut sim::Rng {
        &mut self.0
    }
}

impl Rng {
    /// The generator of case `index` under `seed`.
    fn for_case(seed: u64, index: u64) -> Self {
        Rng(sim::Rng::for_case(seed, index))
    }

    /// Uniform in `[lo, hi)`.
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    /// `10^u` with `u` uniform in `[lo, hi)`.
    fn log_uniform(&mut self, lo: f64, hi: f64) -> f64 {
        10f64.powf(self.range(lo, hi))
    }

    fn sign(&mut self) -> f64 {
        if self.chance(0.5) {
            1.0
        } else {
            -1.0
        }
    }

    /// Standard normal (Box-Muller).
    fn normal(&mut self) -> f64 {
        let u = self.unit().max(1e-300);
        let v = self.unit();
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
    }

    /// A uniformly random unit vector.
    fn direction(&mut self) -> [f64; 3] {
        loop {
            let v = [self.normal(), self.normal(), self.normal()];
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if n > 1e-6 {
                return v.map(|c| c / n);
            }
        }
    }

    /// An `f64` of any class: arbitrary bits, a special value, or an
    /// ordinary number of any magnitude.
    fn any_f64(&mut self) -> f64 {
        match self.below(16) {
            0..=2 => f64::from_bits(self.next_u64()),
            3 => self.special_f64(),
            4 => self.special_f64(),
            5 => f64::from(self.any_f32()),
            6 => self.sign() * self.log_uniform(-320.0, 308.0),
            7 => self.sign() * self.log_uniform(-45.0, 38.5),
            8 => (self.below(2001) as f64) - 1000.0,
            _ => self.range(-1e3, 1e3),
        }
    }

    /// One of the values that break arithmetic.
    fn special_f64(&mut self) -> f64 {
        let nan_payload = f64::from_bits(0x7ff0_0000_0000_0000 | (self.next_u64() >> 12 | 1));
        let values = [
            f64::NAN,
            -f64::NAN,
            nan_payload,
            -nan_payload,
            f64::INFINITY,
            f64::NEG_INFINITY,
            0.0,
            -0.0,
            5e-324,
            -5e-324,
            f64::from_bits(self.below(1 << 52)), // a random subnormal
            f64::MIN_POSITIVE,
            1e-300,
            1e-160,
            1e-40,
            f64::from(f32::MIN_POSITIVE),
            1e-45,
            1e30,
            1e38,
            -1e38,
            f64::from(f32::MAX),
            -f64::from(f32::MAX),
            3.5e38, // above f32::MAX: infinite in f32
            1e154,
            1e155,
            1e300,
            f64::MAX,
            -f64::MAX,
            1.0,
            -1.0,
            f64::EPSILON,
            32767.0,
            -32768.0,
        ];
        values[self.index(values.len())]
    }

    /// An `f32` of any class.
    fn any_f32(&mut self) -> f32 {
        match self.below(8) {
            0..=2 => f32::from_bits(self.next_u64() as u32),
            3 => {
                let payload = f32::from_bits(0x7f80_0000 | ((self.next_u64() as u32) >> 9 | 1));
                let values = [
                    f32::NAN,
                    -f32::NAN,
                    payload,
                    -payload,
                    f32::INFINITY,
                    f32::NEG_INFINITY,
                    0.0,
                    -0.0,
                    1e-45,
                    f32::from_bits(self.below(1 << 23) as u32),
                    f32::MIN_POSITIVE,
                    1e-38,
                    1e19,
                    1e20,
                    1e30,
                    1e38,
                    f32::MAX,
                    -f32::MAX,
                    f32::EPSILON,
                ];
                values[self.index(values.len())]
            }
            _ => (self.sign() * self.log_uniform(-46.0, 38.6)) as f32,
        }
    }

    fn any_vec3(&mut self) -> [f64; 3] {
        [self.any_f64(), self.any_f64(), self.any_f64()]
    }

    /// A length for a sample set: mostly short, sometimes long.
    fn length(&mut self) -> usize {
        match self.below(10) {
            0..=3 => self.index(12),
            4..=7 => 10 + self.index(90),
            8 => 100 + self.index(400),
            _ => 500 + self.index(1500),
        }
    }
}

// --- Sample sets ---------------------------------------------------------------

/// A sample set in `f64`, before conversion to the case's sample type.
fn sample_set(rng: &mut Rng) -> (&'static str, Vec<[f64; 3]>) {
    let shape = rng.below(12);
    // Structured sets are mostly long enough to fit; garbage any length.
    let n = if shape >= 3 && rng.chance(0.85) {
        12 + rng.length()
    } else {
        rng.length()
    };
    let mut y: Vec<[f64; 3]> = match shape {
        // Garbage: every component of any class.
        0 | 1 => (0..n).map(|_| rng.any_vec3()).collect(),
        // One point, repeated (optionally with a few others).
        2 => {
            let p = if rng.chance(0.5) {
                rng.any_vec3()
            } else {
                let s = rng.log_uniform(-30.0, 30.0);
                [s, -s, s * 0.5]
            };
            let mut y = vec![p; n];
            for _ in 0..rng.below(3) {
                if !y.is_empty() {
                    let i = rng.index(y.len());
                    y[i] = rng.any_vec3();
                }
            }
            y
        }
        // A handful of distinct points, each repeated.
        3 => {
            let k = 1 + rng.index(12);
            let pts: Vec<[f64; 3]> = (0..k).map(|_| ellipsoid_point(rng, 100.0, 1.0)).collect();
            (0..n).map(|i| pts[i % k]).collect()
        }
        // Planar, collinear, or a cap / band of an ellipsoid.
        4 => {
            let (offset, radius) = scales(rng);
            let normal = rng.direction();
            let kind = rng.below(3);
            (0..n)
                .map(|_| {
                    let d = rng.direction();
                    let d = match kind {
                        // In the plane through the centre.
                        0 => {
                            let dot = d[0] * normal[0] + d[1] * normal[1] + d[2] * normal[2];
                            [
                                d[0] - dot * normal[0],
                                d[1] - dot * normal[1],
                                d[2] - dot * normal[2],
                            ]
                        }
                        // On a line.
                        1 => normal.map(|c| c * rng.range(-1.0, 1.0)),
                        // A cap of random size around `normal`.
                        _ => {
                            let dot = d[0] * normal[0] + d[1] * normal[1] + d[2] * normal[2];
                            if dot < 0.7 {
                                normal
                            } else {
                                d
                            }
                        }
                    };
                    [
                        offset[0] + radius * d[0],
                        offset[1] + radius * d[1],
                        offset[2] + radius * d[2],
                    ]
                })
                .collect()
        }
        // Integer grid values (what an i16 sensor gives), tiny spread.
        5 => {
            let c = [
                rng.range(-30000.0, 30000.0).round(),
                rng.range(-30000.0, 30000.0).round(),
                rng.range(-30000.0, 30000.0).round(),
            ];
            let r = rng.log_uniform(0.0, 3.5);
            (0..n)
                .map(|_| {
                    let d = rng.direction();
                    [
                        (c[0] + r * d[0]).round(),
                        (c[1] + r * d[1]).round(),
                        (c[2] + r * d[2]).round(),
                    ]
                })
                .collect()
        }
        // Two clusters, far apart.
        6 => {
            let a = ellipsoid_point(rng, 1e3, 1.0);
            let b = ellipsoid_point(rng, 1e3, 1.0);
            let e = rng.log_uniform(-12.0, 0.0);
            (0..n)
                .map(|i| {
                    let p = if i % 2 == 0 { a } else { b };
                    [
                        p[0] + e * rng.normal(),
                        p[1] + e * rng.normal(),
                        p[2] + e * rng.normal(),
                    ]
                })
                .collect()
        }
        // An ellipsoid at any scale: huge offsets with tiny radii, tiny
        // everything, huge everything.
        _ => {
            let (offset, radius) = scales(rng);
            let noise = if rng.chance(0.5) {
                0.0
            } else {
                radius * rng.log_uniform(-8.0, 0.0)
            };
            let axes = [
                rng.log_uniform(-0.5, 0.5),
                rng.log_uniform(-0.5, 0.5),
                rng.log_uniform(-0.5, 0.5),
            ];
            let shear = rng.range(-0.5, 0.5);
            (0..n)
                .map(|_| {
                    let d = rng.direction();
                    let e = [
                        axes[0] * d[0] + shear * d[1],
                        axes[1] * d[1],
                        axes[2] * d[2],
                    ];
                    [
                        offset[0] + radius * e[0] + noise * rng.normal(),
                        offset[1] + radius * e[1] + noise * rng.normal(),
                        offset[2] + radius * e[2] + noise * rng.normal(),
                    ]
                })
                .collect()
        }
    };
    // A stretch of consecutive rows displaced (a magnet passing), which
    // the robust fit leaves out with the rows beside it.
    if y.len() > 20 && rng.chance(0.15) {
        let len = 6 + rng.index(y.len() / 3);
        let start = rng.index(y.len() - len);
        let (d, scale) = (rng.direction(), rng.log_uniform(-3.0, 1.0));
        let size = y
            .iter()
            .flatten()
            .map(|v| v.abs())
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max);
        for row in y.iter_mut().skip(start).take(len) {
            for (v, dc) in row.iter_mut().zip(d) {
                *v += dc * scale * size;
            }
        }
    }
    // Special values mixed in, duplicates appended, or a garbage tail.
    if !y.is_empty() && rng.chance(0.3) {
        for _ in 0..1 + rng.below(4) {
            let i = rng.index(y.len());
            let c = rng.index(3);
            y[i][c] = rng.special_f64();
        }
    }
    if !y.is_empty() && rng.chance(0.1) {
        let copies = y.clone();
        y.extend(copies);
    }
    if rng.chance(0.05) {
        for _ in 0..rng.below(20) {
            y.push(rng.any_vec3());
        }
    }
    const NAMES: [&str; 12] = [
        "garbage",
        "garbage",
        "one point",
        "few points",
        "plane/line/cap",
        "integer grid",
        "two clusters",
        "ellipsoid",
        "ellipsoid",
        "ellipsoid",
        "ellipsoid",
        "ellipsoid",
    ];
    (NAMES[shape as usize], y)
}

/// An offset and a radius: ordinary, huge offset with a tiny radius, tiny
/// everything, or huge everything.
fn scales(rng: &mut Rng) -> ([f64; 3], f64) {
    let (off, rad) = match rng.below(8) {
        // Ordinary: what a magnetometer gives (also in i16 counts).
        0..=3 => (rng.log_uniform(0.0, 4.0), rng.log_uniform(0.5, 3.5)),
        4 => {
            let off = rng.log_uniform(3.0, 38.5);
            (off, off * rng.log_uniform(-16.0, -3.0))
        }
        5 => {
            let s = rng.log_uniform(-320.0, -20.0);
            (s * rng.range(0.0, 10.0), s)
        }
        6 => {
            let s = rng.log_uniform(20.0, 308.0);
            (s * rng.range(0.0, 10.0), s)
        }
        _ => (rng.log_uniform(-45.0, 38.5), rng.log_uniform(-45.0, 38.5)),
    };
    let d = rng.direction();
    (d.map(|c| c * off), rad)
}

fn ellipsoid_point(rng: &mut Rng, offset: f64, radius: f64) -> [f64; 3] {
    let d = rng.direction();
    d.map(|c| offset * 0.3 + radius * c)
}

/// The `Config` for `method` and `ls` with the case's optional fields.
// `..Config::default()` keeps this compiling when `Config` gains a field.
#[allow(clippy::needless_update)]
fn config(method: Method, ls: LsVariant, extras: &Extras) -> Config {
    Config {
        method,
        ls,
        max_iterations: extras.max_iterations,
        max_passes: extras.max_passes,
        pass_tolerance: extras.pass_tolerance,
        noise_covariance: extras.noise_covariance,
        expected_field_strength: extras.expected_field_strength,
        robust: extras.robust,
        thresholds: extras.thresholds,
        ..Config::default()
    }
}

/// The optional parts of a case's `Config`, shared by its 15 calls.
#[derive(Clone, Copy, Debug)]
struct Extras {
    max_iterations: u32,
    max_passes: u32,
    pass_tolerance: Option<f64>,
    noise_covariance: Option<[[f64; 3]; 3]>,
    expected_field_strength: Option<f64>,
    /// Outlier handling (on in 80 % of the cases).
    robust: bool,
    /// Judging limits: the defaults, or any numbers (NaN, 0, infinite).
    thresholds: Thresholds,
}

/// Judging limits for a case: each the default or, in turn, any number.
fn thresholds(rng: &mut Rng) -> Thresholds {
    let d = Thresholds::DEFAULT;
    if rng.chance(0.7) {
        return d;
    }
    let mut any = |v: f32| {
        if rng.chance(0.7) {
            v
        } else {
            rng.any_f64() as f32
        }
    };
    Thresholds {
        warn_samples: d.warn_samples,
        refuse_flatness: any(d.refuse_flatness),
        warn_flatness: any(d.warn_flatness),
        refuse_quadric_gap: any(d.refuse_quadric_gap),
        gap_noise_limit: any(d.gap_noise_limit),
        warn_quadric_gap: any(d.warn_quadric_gap),
        refuse_distortion: any(d.refuse_distortion),
        refuse_coverage: any(d.refuse_coverage),
        warn_gram_condition: any(d.warn_gram_condition),
        refuse_field_deviation: any(d.refuse_field_deviation),
        warn_spread_over_noise: any(d.warn_spread_over_noise),
        refuse_fit_error: any(d.refuse_fit_error),
        warn_fit_error: any(d.warn_fit_error),
        refuse_outlier_share: any(d.refuse_outlier_share),
        refuse_lack_of_fit: any(d.refuse_lack_of_fit),
        refuse_skewness: any(d.refuse_skewness),
    }
}

fn extras(rng: &mut Rng) -> Extras {
    let d = Config::default();
    if rng.chance(0.6) {
        return Extras {
            max_iterations: d.max_iterations,
            max_passes: d.max_passes,
            pass_tolerance: d.pass_tolerance,
            noise_covariance: d.noise_covariance,
            expected_field_strength: d.expected_field_strength,
            robust: rng.chance(0.8),
            thresholds: d.thresholds,
        };
    }
    // Caps from 0 up to 1000. (A cap of `u32::MAX` with a pass tolerance
    // that no pass can meet, e.g. a negative one, makes adc2-iter run
    // 4e9 passes: bounded, as documented, but not in a test's lifetime.)
    let small = |rng: &mut Rng, default: u32| match rng.below(4) {
        0 => rng.below(4) as u32,
        1 => rng.below(200) as u32,
        2 => 1000,
        _ => default,
    };
    Extras {
        max_iterations: small(rng, d.max_iterations),
        max_passes: small(rng, d.max_passes),
        pass_tolerance: rng.chance(0.5).then(|| rng.any_f64()),
        noise_covariance: rng.chance(0.5).then(|| {
            if rng.chance(0.5) {
                let s = rng.log_uniform(-10.0, 10.0);
                [[s, 0.0, 0.0], [0.0, s, 0.0], [0.0, 0.0, s]]
            } else {
                [rng.any_vec3(), rng.any_vec3(), rng.any_vec3()]
            }
        }),
        expected_field_strength: rng.chance(0.5).then(|| {
            if rng.chance(0.5) {
                rng.log_uniform(-3.0, 5.0)
            } else {
                rng.any_f64()
            }
        }),
        robust: rng.chance(0.8),
        thresholds: thresholds(rng),
    }
}

// --- Checks --------------------------------------------------------------------

/// Every method and LS variant on `samples` in precision `T`; every `Ok`
/// must be well formed. Returns the number of `calibrate` calls.
fn check_calibrate<T: Real, S: Sample + std::fmt::Debug>(
    samples: &[S],
    extras: &Extras,
) -> Result<u64, String> {
    if replaying() {
        eprintln!("samples: {samples:?}");
    }
    let mut calls = 0;
    for method in Method::ALL {
        for ls in [LsVariant::Ls9, LsVariant::Svd10, LsVariant::LiGriffiths] {
            let cfg = config(method, ls, extras);
            calls += 1;
            let t0 = Instant::now();
            let result = calibrate::<T, S>(samples, &cfg);
            if replaying() {
                eprintln!(
                    "  {method:?}/{ls:?} in {}: {:.3} s: {result:?}",
                    std::any::type_name::<S>(),
                    t0.elapsed().as_secs_f64()
                );
            }
            tally(&result);
            let Ok(fit) = result else {
                continue;
            };
            let c = fit.calibration;
            let r = fit.report;
            let what = || format!("{method:?}/{ls:?}: {fit:?}");
            if !c.hard_iron_vector().iter().all(|v| v.is_finite()) {
                return Err(format!("non-finite hard iron: {}", what()));
            }
            if !c.soft_iron_matrix().iter().all(|v| v.is_finite()) {
                return Err(format!("non-finite soft iron: {}", what()));
            }
            let rho = c.field_strength();
            if !(rho > T::zero() && rho.is_finite()) {
                return Err(format!("bad field strength: {}", what()));
            }
            // rho = det(W)^(-1/3), recomputed in f64 from the W returned,
            // on W scaled to a largest entry of 1 (det(W) itself can
            // underflow even in f64, e.g. W ~ 1e-131).
            let w64 = c.soft_iron_matrix().map(Real::to_f64);
            let s64 = w64.amax();
            let rho64 = 1.0 / (s64 * (w64 / s64).determinant().cbrt());
            let rel = (rho.to_f64() - rho64).abs() / rho64;
            if rel.is_nan() || rel > T::EPSILON.to_f64() * 64.0 {
                return Err(format!(
                    "field strength is not the inverse cube root of det W: {rho:?} against {rho64:e} \
                     (relative error {rel:e}), {}",
                    what()
                ));
            }
            if r.samples_used + r.samples_dropped + r.dwell + r.screened + r.rejected
                != samples.len()
            {
                return Err(format!(
                    "used + dropped + dwell + screened + rejected != len {}: {}",
                    samples.len(),
                    what()
                ));
            }
            let spans = r.selection.runs.spans();
            if spans.windows(2).any(|w| w[0].1 >= w[1].0)
                || spans.iter().any(|&(s, e)| s >= e || e > samples.len())
            {
                return Err(format!("spans out of order or range: {}", what()));
            }
            let classes: Vec<_> = r.selection.classify(&c, samples).collect();
            if spans
                .iter()
                .any(|&(s, e)| classes[s..e].contains(&SampleClass::Used))
            {
                return Err(format!("a row in a span classified used: {}", what()));
            }
            if r.samples_used < MIN_SAMPLES {
                return Err(format!("Ok with fewer than MIN_SAMPLES: {}", what()));
            }
            if !(r.radial_rms >= T::zero() && r.radial_rms.is_finite()) {
                return Err(format!("bad radial RMS: {}", what()));
            }
            if r.method != method || r.ls != ls {
                return Err(format!("report names another method: {}", what()));
            }
        }
    }
    Ok(calls)
}

/// Outcomes of `calibrate` over a run: `Ok`, or the error's variant.
static OUTCOMES: Mutex<BTreeMap<String, u64>> = Mutex::new(BTreeMap::new());

fn tally<T: Real>(result: &Result<Fit<T>, Error>) {
    let key = match result {
        Ok(fit) if !fit.report.selection.runs.is_empty() => "Ok (rows beside runs left out)".into(),
        Ok(fit) if fit.report.warnings.iter().next().is_some() => "Ok (with warnings)".into(),
        Ok(_) => "Ok".to_string(),
        Err(e) => {
            let name = format!("{e:?}");
            name.split([' ', '{', '('])
                .next()
                .unwrap_or("?")
                .to_string()
        }
    };
    let shape = SHAPE.with(|s| s.get());
    let mut outcomes = OUTCOMES.lock().unwrap();
    *outcomes.entry(key.clone()).or_default() += 1;
    if std::env::var_os("MAGCAL_FUZZ_BY_SHAPE").is_some() {
        *outcomes.entry(format!("{shape}: {key}")).or_default() += 1;
    }
}

thread_local! {
    /// The shape of the case being run, for the outcome table.
    static SHAPE: std::cell::Cell<&'static str> = const { std::cell::Cell::new("") };
}

/// One `fuzz_calibrate` case. Returns the number of `calibrate` calls.
fn calibrate_case(seed: u64, index: u64) -> Result<u64, String> {
    let mut rng = Rng::for_case(seed, index);
    let (shape, y) = sample_set(&mut rng);
    let extras = extras(&mut rng);
    let f64_precision = rng.chance(0.5);
    SHAPE.with(|s| s.set(shape));
    if replaying() {
        eprintln!(
            "case {index}: {shape}, {} samples, {} precision, {extras:?}",
            y.len(),
            if f64_precision { "f64" } else { "f32" }
        );
    }
    macro_rules! run {
        ($samples:expr) => {
            if f64_precision {
                check_calibrate::<f64, _>(&$samples, &extras)
            } else {
                check_calibrate::<f32, _>(&$samples, &extras)
            }
        };
    }
    match rng.below(8) {
        // i16: saturating conversion (NaN -> 0), or raw bit patterns.
        0 => {
            let s: Vec<[i16; 3]> = if rng.chance(0.8) {
                y.iter().map(|v| v.map(|c| c as i16)).collect()
            } else {
                (0..y.len())
                    .map(|_| [0; 3].map(|_: i16| rng.next_u64() as i16))
                    .collect()
            };
            run!(s)
        }
        1 => {
            let s: Vec<[i32; 3]> = if rng.chance(0.8) {
                y.iter().map(|v| v.map(|c| c as i32)).collect()
            } else {
                (0..y.len())
                    .map(|_| [0; 3].map(|_: i32| rng.next_u64() as i32))
                    .collect()
            };
            run!(s)
        }
        // f32: the f64 values rounded (1e300 -> inf), some replaced by f32
        // values of any class.
        2..=4 => {
            let p = rng.unit() * 0.2;
            let s: Vec<[f32; 3]> = y
                .iter()
                .map(|v| {
                    v.map(|c| {
                        if rng.chance(p) {
                            rng.any_f32()
                        } else {
                            c as f32
                        }
                    })
                })
                .collect();
            run!(s)
        }
        _ => run!(y),
    }
}

/// The rows of `m` (the API's matrices are by rows).
fn rows<T: Real>(m: &Matrix3<T>) -> [[T; 3]; 3] {
    m.transpose().into()
}

/// `a` within `tol` of a rotation: `|R^T R - I| <= tol`, `det R > 0`.
fn is_rotation<T: Real>(r: &Matrix3<T>, tol: f64) -> bool {
    let defect = (r.transpose() * r - Matrix3::identity()).amax();
    defect.to_f64() <= tol && r.determinant() > T::zero()
}

fn in_heading_range<T: Real>(h: T) -> bool {
    h.is_finite() && h.to_f64() > -180.0 && h.to_f64() <= 180.0
}

/// One case of the other entry points, in precision `T`.
fn others_case_in<T: Real>(rng: &mut Rng) -> Result<(), String> {
    let t = |x: f64| T::lit(x);
    let vec3 = |rng: &mut Rng| Vector3::from(rng.any_vec3().map(t));
    let tol = T::EPSILON.to_f64() * 1e3;

    // Calibration::new with arbitrary (or nearly valid) b and W.
    let b = vec3(rng);
    let w =
        match rng.below(3) {
            0 => Matrix3::from_fn(|_, _| t(rng.any_f64())),
            1 => Matrix3::from_fn(|i, j| {
                t(if i == j { 1.0 } else { 0.0 } * rng.log_uniform(-40.0, 40.0))
            }),
            _ => Matrix3::from_fn(|_, _| t(rng.range(-2.0, 2.0))),
        };
    // Raw readings as the API takes them: f64 arrays (any value, as in the
    // working precision after conversion) and i16 tuples.
    let raw = rng.any_vec3().map(|x| t(x).to_f64());
    let counts = (
        rng.next_u64() as i16,
        rng.next_u64() as i16,
        rng.next_u64() as i16,
    );
    if let Ok(cal) = Calibration::new(b.into(), rows(&w)) {
        let rho = cal.field_strength();
        if !(rho > T::zero() && rho.is_finite()) {
            return Err(format!("Calibration::new: bad field strength {cal:?}"));
        }
        if !cal
            .hard_iron_vector()
            .iter()
            .chain(cal.soft_iron_matrix().iter())
            .all(|v| v.is_finite())
        {
            return Err(format!("Calibration::new: non-finite parameters {cal:?}"));
        }
        let _ = cal.apply(raw);
        let _ = cal.apply(counts);
        let _ = cal.apply_scaled(raw);
        let _ = cal.shape();
        // Offsets-only refits of this calibration on arbitrary readings:
        // a result or an error, never a panic, and a result is finite.
        let n = rng.length();
        let readings: Vec<[f64; 3]> = (0..n).map(|_| rng.any_vec3()).collect();
        for strength in [Strength::Unchanged, Strength::Unknown] {
            if let Ok(fit) = refit_offsets::<T, _>(&readings, &cal, strength) {
                let b = fit.calibration.hard_iron();
                if !b.iter().all(|v| v.is_finite()) || !fit.determinacy.is_finite() {
                    return Err(format!("refit_offsets: non-finite result {fit:?}"));
                }
            }
        }
        // Planar fits of the same readings: a result or an error, and a
        // result gives finite headings and counts every row once.
        let up = rng.any_vec3();
        let planar = calibrate_planar::<T, _>(&readings, &PlanarConfig::with_up(up));
        if let Ok(fit) = planar {
            let c = fit.calibration;
            let finite = c
                .axis()
                .iter()
                .chain(c.centre().iter())
                .all(|v| v.is_finite());
            let h = c.heading_deg(raw);
            if !finite || !h.is_finite() || h.abs() > T::lit(180.0) {
                return Err(format!("calibrate_planar: bad result {fit:?}, heading {h}"));
            }
            let r = &fit.report;
            if r.samples_used + r.drops.total() + r.dwell + r.screened + r.rejected
                != readings.len()
            {
                return Err(format!(
                    "calibrate_planar: rows not counted once ({} rows): {r:?}",
                    readings.len()
                ));
            }
        }
        // A rotation, a nearly-rotation, or garbage.
        let r = match rng.below(3) {
            0 => Matrix3::from_fn(|_, _| t(rng.any_f64())),
            1 => {
                let a = rng.range(-10.0, 10.0);
                let (s, c) = a.sin_cos();
                Matrix3::new(
                    t(c),
                    t(-s),
                    t(0.0),
                    t(s),
                    t(c),
                    t(0.0),
                    t(0.0),
                    t(0.0),
                    t(1.0),
                )
            }
            _ => Matrix3::from_fn(|i, j| t(if i == j { 1.0 } else { 0.0 } + rng.normal() * 1e-6)),
        };
        if let Ok(aligned) = AlignedCalibration::new(cal, rows(&r)) {
            let _ = aligned.apply(raw);
            if !is_rotation(&aligned.rotation_matrix(), tol * 2.0) {
                return Err(format!("AlignedCalibration accepted a non-rotation {r:?}"));
            }
        }
    }

    // procrustes on arbitrary pairs (lengths may differ), on rotated
    // copies, and on degenerate sets.
    let n = rng.length();
    let u: Vec<[T; 3]> = (0..n).map(|_| rng.any_vec3().map(t)).collect();
    let h: Vec<[T; 3]> = match rng.below(4) {
        0 => (0..n + rng.index(2))
            .map(|_| rng.any_vec3().map(t))
            .collect(),
        1 => u.clone(),
        2 => u.iter().map(|v| [v[1], v[0], v[2]]).collect(), // a reflection
        _ => u.iter().map(|v| [-v[1], v[0], v[2]]).collect(), // a quarter turn
    };
    let dirs: Vec<[T; 3]> = (0..n)
        .map(|_| {
            let d = rng.direction();
            let s = rng.special_f64();
            let k = if rng.chance(0.1) { s } else { 1.0 };
            d.map(|c| t(c * k))
        })
        .collect();
    for (a, b) in [(&u, &h), (&dirs, &dirs), (&u, &u)] {
        if let Ok(q) = procrustes::<T>(a, b) {
            let q = Matrix3::from_row_slice(q.as_flattened());
            if !q.iter().all(|x| x.is_finite()) || !is_rotation(&q, tol) {
                return Err(format!("procrustes: not a rotation {q:?}"));
            }
        }
    }

    // Headings.
    let f = vec3(rng);
    let a = vec3(rng);
    let hd = heading_deg(f.into());
    if !in_heading_range(hd) {
        return Err(format!("heading_deg({f:?}) = {hd:?}"));
    }
    if let Some(h) = tilt_compensated_heading_deg(f.into(), a.into()) {
        if !in_heading_range(h) {
            return Err(format!(
                "tilt_compensated_heading_deg({f:?}, {a:?}) = {h:?}"
            ));
        }
    }
    let x = t(rng.any_f64());
    let wd = wrap_deg(x);
    if x.is_finite() && !in_heading_range(wd) {
        return Err(format!("wrap_deg({x:?}) = {wd:?}"));
    }

    // The smoother: any window (including invalid ones), any values.
    let window = match rng.below(3) {
        0 => rng.index(40),
        1 => 1 + rng.index(16),
        _ => usize::MAX - rng.index(2),
    };
    match HeadingSmoother::<T, 16>::with_window(window) {
        Ok(mut s) => {
            if window == 0 || window > 16 {
                return Err(format!("with_window({window}) accepted"));
            }
            for _ in 0..rng.below(60) {
                let v = if rng.chance(0.7) {
                    t(rng.range(-720.0, 720.0))
                } else {
                    t(rng.any_f64())
                };
                if let Some(m) = s.push(v) {
                    if !in_heading_range(m) {
                        return Err(format!("smoother mean {m:?}"));
                    }
                }
                if s.len() > s.window() {
                    return Err("smoother holds more than its window".into());
                }
                if rng.chance(0.05) {
                    s.clear();
                }
            }
        }
        Err(e) => {
            if (1..=16).contains(&window) {
                return Err(format!("with_window({window}) refused: {e:?}"));
            }
        }
    }
    let mut s = HeadingSmoother::<T, 1>::new();
    let _ = s.push(t(rng.any_f64()));
    let _ = s.push(t(rng.any_f64()));
    let _ = s.mean();
    Ok(())
}

/// One `fuzz_calibration_align_heading` case.
fn others_case(seed: u64, index: u64) -> Result<u64, String> {
    let mut rng = Rng::for_case(seed, index);
    if rng.chance(0.5) {
        others_case_in::<f64>(&mut rng)?;
    } else {
        others_case_in::<f32>(&mut rng)?;
    }
    // SampleStore beyond its capacity.
    let mut store: SampleStore<[i16; 3], 8> = SampleStore::new();
    for i in 0..rng.below(12) {
        let sample = [i as i16, 0, rng.next_u64() as i16];
        let r = store.push(sample);
        // A full store hands the sample back.
        if (i < 8) != r.is_ok() || (r.is_err() && r != Err(sample)) {
            return Err(format!("SampleStore push {i}: {r:?}"));
        }
    }
    if rng.chance(0.2) {
        store.clear();
    }
    let _ = calibrate::<f32, _>(store.as_slice(), &Config::default());
    Ok(1)
}

/// Whether a single case is replayed (`MAGCAL_FUZZ_CASE`): then the case
/// and every result are printed.
fn replaying() -> bool {
    std::env::var_os("MAGCAL_FUZZ_CASE").is_some()
}

/// One `fuzz_collector_persist` case: `Collector::offer` on arbitrary
/// samples, `persist` on arbitrary and mutated records.
fn collector_persist_case(seed: u64, index: u64) -> Result<u64, String> {
    let mut rng = Rng::for_case(seed, index);
    let (_, y) = sample_set(&mut rng);
    let angle = if rng.chance(0.7) {
        rng.range(-10.0, 200.0) as f32
    } else {
        rng.any_f32()
    };
    let mut calls = 0;
    macro_rules! collect {
        ($samples:expr, $n:literal) => {{
            let mut c: Collector<_, $n> = Collector::new(angle);
            for s in $samples {
                calls += 1;
                let full = c.len() == c.capacity();
                let offer = c.offer(s);
                if full != (offer == Offer::Full) {
                    return Err(format!("offer {offer:?} with len {} of {}", c.len(), $n));
                }
                if offer == Offer::Restarted && (!c.is_empty() || c.centre().is_some()) {
                    return Err(format!("restarted but holds {} samples", c.len()));
                }
                if c.len() > $n || c.samples().len() != c.len() {
                    return Err(format!("collector len {} of {}", c.len(), $n));
                }
                let p = c.progress();
                if p.percent > 100 || p.ready != (p.percent == 100) || p.cells_visited > p.cells {
                    return Err(format!("progress {p:?}"));
                }
                if let Some(centre) = c.centre() {
                    if !centre.iter().all(|v| v.is_finite()) {
                        return Err(format!("non-finite centre {centre:?}"));
                    }
                }
                if rng.chance(0.002) {
                    c.clear();
                }
            }
            if rng.chance(0.2) {
                let _ = calibrate::<f32, _>(c.samples(), &Config::default());
            }
        }};
    }
    match rng.below(4) {
        0 => collect!(y.iter().map(|v| v.map(|c| c as i16)), 64),
        1 => collect!(y.iter().map(|v| v.map(|c| c as f32)), 300),
        2 => collect!(y.iter().copied(), 7),
        _ => collect!(y.iter().map(|v| v.map(|c| c as i32)), 1),
    }

    // persist: a valid record (from an arbitrary calibration), mutated or
    // not; arbitrary bytes; any length.
    let b = Vector3::from(rng.any_vec3());
    let w = Matrix3::from_fn(|i, j| {
        if i == j {
            rng.log_uniform(-20.0, 20.0)
        } else if rng.chance(0.5) {
            rng.range(-0.1, 0.1)
        } else {
            0.0
        }
    });
    let mut record: Vec<u8> = match Calibration::<f64>::from_nalgebra(b, w) {
        Ok(cal) => {
            let bytes = persist::to_bytes(&cal);
            let back = persist::from_bytes::<f64>(&bytes);
            if back != Ok(cal) {
                return Err(format!("f64 round trip: {cal:?} -> {back:?}"));
            }
            if let Ok(c32) = Calibration::<f32>::from_nalgebra(b.cast(), w.cast()) {
                let back = persist::from_bytes::<f32>(&persist::to_bytes(&c32));
                if back != Ok(c32) {
                    return Err(format!("f32 round trip: {c32:?} -> {back:?}"));
                }
            }
            bytes.to_vec()
        }
        Err(_) => (0..persist::ENCODED_LEN)
            .map(|_| rng.next_u64() as u8)
            .collect(),
    };
    let valid = persist::from_bytes::<f64>(&record).is_ok();
    let mutated = match rng.below(5) {
        0 => false,
        1 => {
            let i = rng.index(record.len());
            let old = record[i];
            record[i] = loop {
                let b = rng.next_u64() as u8;
                if b != old {
                    break b;
                }
            };
            true
        }
        2 => {
            record.truncate(rng.index(record.len()));
            true
        }
        3 => {
            record.extend((0..rng.index(10)).map(|_| rng.next_u64() as u8));
            false // trailing bytes are ignored
        }
        _ => {
            record = (0..rng.index(200)).map(|_| rng.next_u64() as u8).collect();
            true
        }
    };
    for result in [
        persist::from_bytes::<f64>(&record).map(|c| c.cast_f64()),
        persist::from_bytes::<f32>(&record).map(|c| c.cast_f64()),
    ] {
        calls += 1;
        match result {
            Ok((b, w, rho)) => {
                if !(b.iter().chain(w.iter()).all(|v| v.is_finite())
                    && rho > 0.0
                    && rho.is_finite())
                {
                    return Err(format!("from_bytes gave {b:?} {w:?} {rho}"));
                }
                if valid && mutated {
                    return Err("a one-byte change or truncation was accepted".into());
                }
            }
            Err(e) => {
                if valid
                    && !mutated
                    && !matches!(e, persist::Error::OutOfRange | persist::Error::Singular)
                {
                    return Err(format!("a valid record was refused: {e:?}"));
                }
            }
        }
    }
    let _ = persist::crc32(&record);
    Ok(calls)
}

/// The parameters of a calibration in `f64`, to compare both precisions.
trait CastF64 {
    fn cast_f64(&self) -> (Vector3<f64>, Matrix3<f64>, f64);
}

impl<T: Real> CastF64 for Calibration<T> {
    fn cast_f64(&self) -> (Vector3<f64>, Matrix3<f64>, f64) {
        (
            self.hard_iron_vector().map(Real::to_f64),
            self.soft_iron_matrix().map(Real::to_f64),
            self.field_strength().to_f64(),
        )
    }
}

// --- The driver ------------------------------------------------------------------

fn env_u64(name: &str) -> Option<u64> {
    let v = std::env::var(name).ok()?;
    let v = v.trim().replace('_', "");
    let parsed = if let Some(hex) = v.strip_prefix("0x") {
        u64::from_str_radix(hex, 16)
    } else {
        v.parse()
    };
    Some(parsed.unwrap_or_else(|_| panic!("{name}={v} is not a number")))
}

/// Runs `cases` cases of `case` on worker threads, catching panics; fails
/// with every failing case's index (and message) when any fails.
fn drive(name: &str, default_cases: u64, case: fn(u64, u64) -> Result<u64, String>) {
    let seed = env_u64("MAGCAL_FUZZ_SEED").unwrap_or(DEFAULT_SEED);
    let (first, cases) = match env_u64("MAGCAL_FUZZ_CASE") {
        Some(i) => (i, 1),
        None => (0, env_u64("MAGCAL_FUZZ_CASES").unwrap_or(default_cases)),
    };
    let threads = env_u64("MAGCAL_FUZZ_THREADS")
        .map(|t| t.max(1) as usize)
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));

    // Per worker: the case it runs (u64::MAX when idle) and since when (ms).
    let running: Vec<(AtomicU64, AtomicU64)> = (0..threads)
        .map(|_| (AtomicU64::new(u64::MAX), AtomicU64::new(0)))
        .collect();
    let slow: Mutex<Vec<(u64, f64)>> = Mutex::new(Vec::new());
    let done = std::sync::atomic::AtomicBool::new(false);
    let next = AtomicU64::new(first);
    let calls = AtomicU64::new(0);
    let failures: Mutex<Vec<(u64, String)>> = Mutex::new(Vec::new());
    let end = first + cases;
    let start = Instant::now();
    let progress = cases >= 100_000;
    std::thread::scope(|scope| {
        // A watchdog: a case that runs for more than SLOW_SECS is named on
        // stderr while it runs (a hang would otherwise be silent).
        scope.spawn(|| {
            let mut reported = std::collections::HashSet::new();
            while !done.load(Ordering::Relaxed) {
                std::thread::sleep(std::time::Duration::from_millis(200));
                let now = start.elapsed().as_millis() as u64;
                for (case, since) in &running {
                    let (i, t0) = (case.load(Ordering::Relaxed), since.load(Ordering::Relaxed));
                    if i != u64::MAX
                        && now.saturating_sub(t0) > SLOW_SECS * 1000
                        && reported.insert(i)
                    {
                        eprintln!(
                            "{name}: case {i} has been running for {} s",
                            (now - t0) / 1000
                        );
                    }
                }
            }
        });
        let workers: Vec<_> = running
            .iter()
            .map(|slot| {
                let (next, calls, failures, slow) = (&next, &calls, &failures, &slow);
                scope.spawn(move || loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= end {
                        slot.0.store(u64::MAX, Ordering::Relaxed);
                        break;
                    }
                    let t0 = start.elapsed();
                    slot.1.store(t0.as_millis() as u64, Ordering::Relaxed);
                    slot.0.store(i, Ordering::Relaxed);
                    if progress && i > first && (i - first) % 100_000 == 0 {
                        eprintln!(
                            "{name}: {} cases, {:.0} s",
                            i - first,
                            start.elapsed().as_secs_f64()
                        );
                    }
                    match catch_unwind(AssertUnwindSafe(|| case(seed, i))) {
                        Ok(Ok(n)) => {
                            calls.fetch_add(n, Ordering::Relaxed);
                        }
                        Ok(Err(msg)) => failures.lock().unwrap().push((i, msg)),
                        Err(panic) => {
                            let msg = panic
                                .downcast_ref::<&str>()
                                .map(|s| s.to_string())
                                .or_else(|| panic.downcast_ref::<String>().cloned())
                                .unwrap_or_else(|| "panic".into());
                            failures.lock().unwrap().push((i, format!("PANIC: {msg}")));
                        }
                    }
                    let took = (start.elapsed() - t0).as_secs_f64();
                    if took > SLOW_SECS as f64 {
                        slow.lock().unwrap().push((i, took));
                    }
                })
            })
            .collect();
        for w in workers {
            let _ = w.join();
        }
        done.store(true, Ordering::Relaxed);
    });
    let elapsed = start.elapsed().as_secs_f64();
    let calls = calls.into_inner();
    eprintln!(
        "{name}: {cases} cases ({calls} calls) from case {first}, seed {seed:#x}, \
         {threads} threads, {elapsed:.1} s"
    );
    let mut slow = slow.into_inner().unwrap();
    slow.sort_by(|a, b| b.1.total_cmp(&a.1));
    for (i, took) in slow.iter().take(10) {
        eprintln!("  slow: case {i} took {took:.1} s");
    }
    // Only `fuzz_calibrate` tallies (the store and collector cases' calls
    // are not checked, so they are not counted).
    if name == "fuzz_calibrate" {
        let outcomes = OUTCOMES.lock().unwrap();
        let total: u64 = outcomes.values().sum();
        eprintln!("{name}: outcomes of the {total} calibrate calls:");
        for (k, n) in outcomes.iter() {
            eprintln!(
                "  {k:<24} {n:>10} ({:.2} %)",
                100.0 * *n as f64 / total.max(1) as f64
            );
        }
    }
    let mut failures = failures.into_inner().unwrap();
    failures.sort();
    if !failures.is_empty() {
        // By kind: the message up to its first ':', '(', '{' or '['.
        let mut kinds: BTreeMap<String, (u64, u64)> = BTreeMap::new();
        for (i, msg) in &failures {
            let kind = msg.split([':', '(', '{', '[']).next().unwrap_or("").trim();
            let entry = kinds.entry(kind.to_string()).or_insert((0, *i));
            entry.0 += 1;
        }
        eprintln!("{name}: failures by kind (count, first case):");
        for (kind, (count, first)) in &kinds {
            eprintln!("  {count:>8}  {kind} (first: case {first})");
        }
        let list = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
            .join(format!("{name}-{seed:x}-failures.txt"));
        let text: String = failures
            .iter()
            .map(|(i, m)| format!("{i}\t{m}\n"))
            .collect();
        if std::fs::write(&list, text).is_ok() {
            eprintln!("{name}: every failing case in {}", list.display());
        }
        for (i, msg) in failures.iter().take(20) {
            let msg: String = msg.chars().take(400).collect();
            eprintln!("  case {i}: {msg}");
        }
        panic!(
            "{name}: {} of {cases} cases failed (seed {seed:#x}); replay one with \
             MAGCAL_FUZZ_SEED={seed:#x} MAGCAL_FUZZ_CASE=<index>",
            failures.len()
        );
    }
}

#[test]
fn fuzz_calibrate() {
    drive("fuzz_calibrate", 4000, calibrate_case);
}

#[test]
fn fuzz_calibration_align_heading() {
    drive("fuzz_calibration_align_heading", 5000, others_case);
}

/// The background calibrator on arbitrary readings: any configuration,
/// pushes and steps in any order; bounded state, finite calibrations.
fn background_case(seed: u64, index: u64) -> Result<u64, String> {
    use mag_cal_core::background::{Background, BackgroundConfig};
    let mut rng = Rng::for_case(seed, index);
    let (_, y) = sample_set(&mut rng);
    let mut config = BackgroundConfig::default();
    config.min_angle_deg = if rng.chance(0.5) {
        rng.range(-5.0, 30.0) as f32
    } else {
        rng.any_f32()
    };
    config.refit_after = rng.index(100);
    config.min_cells = rng.index(60);
    config.slice = rng.index(70);
    config.max_age = rng.below(3000) as u32;
    config.stale_rms = if rng.chance(0.8) {
        rng.range(-1.0, 6.0) as f32
    } else {
        rng.any_f32()
    };
    config.stale_readings = rng.below(300) as u32;
    // The configuration is validated once: a value that cannot be used
    // is refused by name (an independent statement of the ranges).
    let valid = (0.0..=180.0).contains(&config.min_angle_deg)
        && config.stale_rms > 0.0
        && config.stale_rms.is_finite()
        && config.slice > 0
        && config.min_cells <= 48;
    let made: Result<Background<f32, [f64; 3], 96, 2>, _> = Background::new(config);
    let mut bg = match (made, valid) {
        (Ok(bg), true) => bg,
        (Err(mag_cal_core::Error::InvalidConfig { .. }), false) => return Ok(1),
        (made, _) => return Err(format!("{config:?} (valid: {valid}) gave {:?}", made.err())),
    };
    let mut calls = 0u64;
    for _ in 0..3 {
        for s in &y {
            calls += 1;
            bg.push(*s);
            for _ in 0..rng.index(3) {
                bg.step();
            }
            if bg.samples().len() > 96 || bg.progress() > 100 || bg.cells_filled() > 48 {
                return Err(format!(
                    "bounds: {} samples, progress {}, {} cells",
                    bg.samples().len(),
                    bg.progress(),
                    bg.cells_filled()
                ));
            }
            if let Some(c) = bg.calibration() {
                let finite = c
                    .hard_iron()
                    .iter()
                    .chain(c.soft_iron().iter().flatten())
                    .all(|v| v.is_finite());
                if !finite
                    || c.field_strength().partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)
                {
                    return Err(format!("non-finite calibration {c:?}"));
                }
            }
        }
    }
    Ok(calls)
}

#[test]
fn fuzz_background() {
    drive("fuzz_background", 600, background_case);
}

#[test]
fn fuzz_collector_persist() {
    drive("fuzz_collector_persist", 2000, collector_persist_case);
}

/// The generator is deterministic: a case is a function of (seed, index).
#[test]
fn cases_are_reproducible() {
    for i in [0, 1, 12345] {
        let a = sample_set(&mut Rng::for_case(DEFAULT_SEED, i));
        let b = sample_set(&mut Rng::for_case(DEFAULT_SEED, i));
        assert_eq!(format!("{a:?}"), format!("{b:?}"));
    }
}
