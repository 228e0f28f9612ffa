//! Ordinary use for the background calibrator (`mag_cal_core::background`):
//! an orientation random walk biased to upright, with heading changes and
//! occasional tilts but no full tumble; a sensor whose hard iron may jump or
//! drift; a magnet passing by. Used by `tests/background.rs` and the
//! `background-table` binary.

use mag_cal_core::background::{Background, BackgroundConfig, Stepped};
use mag_cal_core::{calibrate, Config};
use nalgebra::{Matrix3, Rotation3, Vector3};

use crate::contamination::fit_errors;
use crate::scenarios::Truth;
use crate::sim::Rng;

/// The calibrator the tests run: 48 cells of 6 samples (288), in `f32`.
pub type Calibrator = Background<f32, [i16; 3], 288, 6>;

/// The earth's field in NED, inclination 60 deg, unit strength.
pub fn earth() -> Vector3<f64> {
    let inc = 60f64.to_radians();
    Vector3::new(inc.cos(), 0.0, inc.sin())
}

/// The sensor: soft iron with a mounting rotation, field 450 counts, and a
/// hard iron.
pub fn truth() -> Truth {
    let s = Matrix3::new(1.12, 0.05, -0.03, 0.05, 0.93, 0.04, -0.03, 0.04, 1.0);
    let r = Rotation3::from_euler_angles(0.03, -0.02, 0.2);
    Truth {
        t: r.matrix() * s * 450.0,
        b: Vector3::new(180.0, -95.0, 60.0),
    }
}

/// `n` body-frame field directions of ordinary use: the heading walks
/// (with turns now and then), roll and pitch wander about level (12 deg),
/// and about every 600 readings the device is tilted by 30-80 deg for a
/// few hundred readings (picked up, put on its side). Never a full tumble.
pub fn ordinary_use(n: usize, seed: u64) -> Vec<Vector3<f64>> {
    let mut rng = Rng::for_case(seed, 11);
    let (mut psi, mut theta, mut phi) = (rng.uniform() * std::f64::consts::TAU, 0.0f64, 0.0f64);
    let (mut target_theta, mut target_phi, mut episode) = (0.0f64, 0.0f64, 0usize);
    let mut turn = 0.0f64;
    (0..n)
        .map(|_| {
            if episode == 0 && rng.chance(1.0 / 600.0) {
                episode = 150 + rng.index(300);
                let tilt = (30.0 + 50.0 * rng.uniform()).to_radians();
                let side = rng.uniform() * std::f64::consts::TAU;
                target_theta = tilt * side.cos();
                target_phi = tilt * side.sin();
            }
            if episode > 0 {
                episode -= 1;
                if episode == 0 {
                    target_theta = 0.0;
                    target_phi = 0.0;
                }
            }
            if rng.chance(1.0 / 200.0) {
                turn = rng.normal() * 0.03;
            }
            psi += turn + rng.normal() * 0.01;
            let k = 0.02;
            theta += k * (target_theta - theta) + rng.normal() * 0.012;
            phi += k * (target_phi - phi) + rng.normal() * 0.012;
            let body_to_world = Rotation3::from_euler_angles(phi, theta, psi);
            body_to_world.matrix().transpose() * earth()
        })
        .collect()
}

/// Readings of `dirs` by the sensor whose hard iron at reading `i` is
/// `b(i)`, noise 1 % of the field per axis, rounded to counts.
pub fn readings(
    dirs: &[Vector3<f64>],
    truth: &Truth,
    b: impl Fn(usize) -> Vector3<f64>,
    seed: u64,
) -> Vec<[i16; 3]> {
    let mut rng = Rng::for_case(seed, 12);
    dirs.iter()
        .enumerate()
        .map(|(i, h)| {
            let noise = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 4.5;
            let y = truth.t * h + b(i) + noise;
            [y.x, y.y, y.z].map(|v| v.round().clamp(-32767.0, 32767.0) as i16)
        })
        .collect()
}

/// What a run of the calibrator gave.
#[derive(Clone, Debug, Default)]
pub struct Trace {
    /// Reading at which the first calibration was adopted.
    pub first: Option<usize>,
    /// Readings at which a refit adopted a calibration.
    pub adopted: Vec<usize>,
    /// Readings at which an offsets-only fit was adopted.
    pub offsets: Vec<usize>,
    /// Errors `(e_M, e_b)` of the calibration in use after each reading
    /// (`None` before the first), against the hard iron of that reading.
    pub errors: Vec<Option<(f64, f64)>>,
}

/// Runs the calibrator over `samples` (one `step` per reading), with the
/// truth's hard iron at reading `i` given by `b(i)`.
pub fn run(
    bg: &mut Calibrator,
    samples: &[[i16; 3]],
    truth: &Truth,
    b: impl Fn(usize) -> Vector3<f64>,
) -> Trace {
    let mut trace = Trace::default();
    for (i, s) in samples.iter().enumerate() {
        bg.push(*s);
        match bg.step() {
            Stepped::Adopted => {
                trace.adopted.push(i);
                trace.first.get_or_insert(i);
            }
            Stepped::OffsetsAdopted => trace.offsets.push(i),
            _ => {}
        }
        let at = Truth {
            t: truth.t,
            b: b(i),
        };
        trace.errors.push(bg.calibration().map(|c| {
            let w = Matrix3::from_fn(|r, k| f64::from(c.soft_iron()[r][k]));
            let hb = Vector3::from(c.hard_iron().map(f64::from));
            let e = fit_errors(&hb, &w, &at);
            (e.e_m, e.e_b)
        }));
    }
    trace
}

/// The errors of batch ADC2 (`f32`) on the calibrator's buffered samples,
/// against `truth`; `None` when it refuses them.
pub fn batch_on_buffer(bg: &Calibrator, truth: &Truth) -> Option<(f64, f64)> {
    let fit = calibrate::<f32, _>(bg.samples(), &Config::default()).ok()?;
    let c = fit.calibration;
    let w = Matrix3::from_fn(|r, k| f64::from(c.soft_iron()[r][k]));
    let e = fit_errors(&Vector3::from(c.hard_iron().map(f64::from)), &w, truth);
    Some((e.e_m, e.e_b))
}

/// A fresh calibrator with the default configuration.
pub fn calibrator() -> Calibrator {
    Background::new(BackgroundConfig::default()).expect("the default configuration is valid")
}

/// Readings of one simulated run.
pub const READINGS: usize = 30_000;

/// Where the change of a run happens.
pub const CHANGE_AT: usize = 15_000;

/// The hard-iron jump of [`Kind::Jump`], sensor units (0.16 of the field).
pub fn jump() -> Vector3<f64> {
    Vector3::new(50.0, -40.0, 25.0)
}

/// What happens during a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Ordinary use, nothing changes.
    Steady,
    /// The hard iron jumps by [`jump`] at [`CHANGE_AT`] (a part magnetised).
    Jump,
    /// The hard iron drifts by [`jump`] over the second half, linearly.
    Drift,
    /// A magnet passes at [`CHANGE_AT`]: for 150 readings (3 s at 50 Hz)
    /// the readings are displaced by up to half the field, rising and
    /// falling; the hard iron does not change.
    Magnet,
}

impl Kind {
    /// Every kind.
    pub const ALL: [Kind; 4] = [Kind::Steady, Kind::Jump, Kind::Drift, Kind::Magnet];

    /// A name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Kind::Steady => "ordinary use",
            Kind::Jump => "hard-iron jump",
            Kind::Drift => "slow drift",
            Kind::Magnet => "magnet passing",
        }
    }

    /// The hard iron at reading `i`.
    pub fn hard_iron(self, truth: &Truth, i: usize) -> Vector3<f64> {
        match self {
            Kind::Jump if i >= CHANGE_AT => truth.b + jump(),
            Kind::Drift if i >= CHANGE_AT => {
                let f = (i - CHANGE_AT) as f64 / (READINGS - CHANGE_AT) as f64;
                truth.b + jump() * f
            }
            _ => truth.b,
        }
    }
}

/// Readings a magnet displaces, and by how much at most (sensor units).
pub const MAGNET_READINGS: usize = 150;

/// The samples of a run of `kind`.
pub fn samples(kind: Kind, seed: u64) -> Vec<[i16; 3]> {
    let t = truth();
    let dirs = ordinary_use(READINGS, seed);
    let mut s = readings(&dirs, &t, |i| kind.hard_iron(&t, i), seed);
    if kind == Kind::Magnet {
        // A dipole's field at the sensor: a fixed direction (the magnet's
        // side), a strength rising and falling as it passes.
        let mut rng = Rng::for_case(seed, 13);
        let d = rng.unit_vector() * 0.5 * 450.0;
        for (k, row) in s
            .iter_mut()
            .skip(CHANGE_AT)
            .take(MAGNET_READINGS)
            .enumerate()
        {
            let x = (k as f64 / MAGNET_READINGS as f64 - 0.5) * 6.0;
            let a = 1.0 / (1.0 + x * x).powf(1.5);
            for (v, dv) in row.iter_mut().zip(d.iter()) {
                *v = (f64::from(*v) + a * dv).round().clamp(-32767.0, 32767.0) as i16;
            }
        }
    }
    s
}

/// The figures of one run.
#[derive(Clone, Copy, Debug)]
pub struct Outcome {
    /// Readings to the first calibration.
    pub first: Option<usize>,
    /// Errors `(e_M, e_b)` just before the change.
    pub before: Option<(f64, f64)>,
    /// Errors at the end.
    pub end: Option<(f64, f64)>,
    /// Batch ADC2 on the buffer at the end (same truth).
    pub batch: Option<(f64, f64)>,
    /// Readings from the change to the first offsets-only adoption.
    pub detected: Option<usize>,
    /// Readings from the change until `e_b` is back to its level before it
    /// (at most 1.5 times that, or 0.02).
    pub recovered: Option<usize>,
    /// Largest `e_b` over the last 5000 readings.
    pub worst_late: f64,
    /// Adoptions caused by something that is not a change of the sensor:
    /// offsets-only adoptions without a moved hard iron (before the change,
    /// or in a run without one), and adoptions during a magnet's pass (and
    /// 500 readings after it) that made either error worse by 0.01.
    pub false_adoptions: usize,
    /// Refit adoptions that took either error from within 0.05 to above
    /// it (the estimation noise of a buffer of weak coverage).
    pub degrading: usize,
    /// Adoptions by refits, and offsets-only.
    pub adoptions: (usize, usize),
}

/// Runs the calibrator over a run of `kind`.
pub fn simulate(kind: Kind, seed: u64) -> Outcome {
    let t = truth();
    let s = samples(kind, seed);
    let mut bg = calibrator();
    let tr = run(&mut bg, &s, &t, |i| kind.hard_iron(&t, i));
    let changes = matches!(kind, Kind::Jump | Kind::Drift);
    let wrong = |e: Option<(f64, f64)>| e.is_some_and(|(m, b)| !(m <= 0.05 && b <= 0.05));
    let worse_than = |i: usize| {
        i > 0 && tr.errors[i - 1].is_some() && !wrong(tr.errors[i - 1]) && wrong(tr.errors[i])
    };
    let degrading = tr.adopted.iter().filter(|&&i| worse_than(i)).count();
    // Adopted because of something that is not a change of the sensor:
    // an offsets-only fit without a moved hard iron, or any adoption during
    // a magnet's pass (and 500 readings after it) that made either error
    // worse by more than 0.01.
    let burst = CHANGE_AT..CHANGE_AT + MAGNET_READINGS + 500;
    let worsened = |i: usize| {
        i > 0
            && match (tr.errors[i - 1], tr.errors[i]) {
                (Some(a), Some(b)) => b.0 > a.0 + 0.01 || b.1 > a.1 + 0.01,
                _ => false,
            }
    };
    let false_adoptions = tr
        .offsets
        .iter()
        .filter(|&&i| !changes || i < CHANGE_AT)
        .count()
        + if kind == Kind::Magnet {
            tr.adopted
                .iter()
                .chain(&tr.offsets)
                .filter(|&&i| burst.contains(&i) && worsened(i))
                .count()
        } else {
            0
        };
    let end_truth = Truth {
        t: t.t,
        b: kind.hard_iron(&t, READINGS - 1),
    };
    Outcome {
        first: tr.first,
        before: tr.errors[CHANGE_AT - 1],
        end: tr.errors[READINGS - 1],
        batch: batch_on_buffer(&bg, &end_truth),
        detected: tr
            .offsets
            .iter()
            .find(|&&i| i >= CHANGE_AT)
            .map(|i| i - CHANGE_AT),
        recovered: {
            // Back to the accuracy before the change.
            let target = tr.errors[CHANGE_AT - 1].map_or(0.02, |e| (1.5 * e.1).max(0.02));
            (CHANGE_AT..READINGS)
                .find(|&i| tr.errors[i].is_some_and(|e| e.1 <= target))
                .map(|i| i - CHANGE_AT)
        },
        worst_late: tr.errors[READINGS - 5000..]
            .iter()
            .map(|e| e.map_or(f64::INFINITY, |e| e.1))
            .fold(0.0, f64::max),
        false_adoptions,
        degrading,
        adoptions: (tr.adopted.len(), tr.offsets.len()),
    }
}

/// The median of some values (`None` when there are none).
pub fn median(mut v: Vec<f64>) -> Option<f64> {
    v.retain(|x| !x.is_nan());
    v.sort_by(f64::total_cmp);
    (!v.is_empty()).then(|| v[v.len() / 2])
}

/// The table of `seeds` runs of every kind.
pub fn render(study: &[(Kind, Vec<Outcome>)]) -> String {
    let mut t = String::from(
        "| run | first calibration (readings, median / max) | e_M, e_b before the change | \
         e_M, e_b at the end | batch ADC2 on the buffer at the end | detected after (median / max) | \
         e_b back to its level before after (median / max) | worst e_b, last 5000 readings (median) | false adoptions | \
         adoptions (refit / offsets) | refit adoptions past 0.05 |\n\
         |---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let f = |x: Option<f64>, d: usize| x.map_or("-".to_string(), |x| format!("{x:.d$}"));
    for (kind, runs) in study {
        let col = |g: &dyn Fn(&Outcome) -> Option<f64>| -> Vec<f64> {
            runs.iter().map(|o| g(o).unwrap_or(f64::INFINITY)).collect()
        };
        let max = |v: Vec<f64>| v.into_iter().fold(0.0f64, f64::max);
        let pair = |g: &dyn Fn(&Outcome) -> Option<(f64, f64)>| {
            format!(
                "{}, {}",
                f(median(col(&|o| g(o).map(|e| e.0))), 4),
                f(median(col(&|o| g(o).map(|e| e.1))), 4)
            )
        };
        let counted = |g: &dyn Fn(&Outcome) -> Option<usize>| {
            let v = col(&|o| g(o).map(|x| x as f64));
            format!("{} / {}", f(median(v.clone()), 0), f(Some(max(v)), 0))
        };
        t.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} / {} | {} |\n",
            kind.name(),
            counted(&|o| o.first),
            pair(&|o| o.before),
            pair(&|o| o.end),
            pair(&|o| o.batch),
            if *kind == Kind::Jump {
                counted(&|o| o.detected)
            } else {
                "-".into()
            },
            if *kind == Kind::Jump {
                counted(&|o| o.recovered)
            } else {
                "-".into()
            },
            f(median(col(&|o| Some(o.worst_late))), 4),
            runs.iter().map(|o| o.false_adoptions).sum::<usize>(),
            runs.iter().map(|o| o.adoptions.0).sum::<usize>(),
            runs.iter().map(|o| o.adoptions.1).sum::<usize>(),
            runs.iter().map(|o| o.degrading).sum::<usize>(),
        ));
    }
    t
}

/// `seeds` runs of every kind, on up to two threads.
pub fn study(seeds: u64) -> Vec<(Kind, Vec<Outcome>)> {
    Kind::ALL
        .iter()
        .map(|&kind| {
            let runs = std::thread::scope(|scope| {
                let half = seeds / 2;
                let a =
                    scope.spawn(move || (0..half).map(|s| simulate(kind, s)).collect::<Vec<_>>());
                let mut b: Vec<Outcome> = (half..seeds).map(|s| simulate(kind, s)).collect();
                let mut all = a.join().expect("worker");
                all.append(&mut b);
                all
            });
            (kind, runs)
        })
        .collect()
}
