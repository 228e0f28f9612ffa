//! The on-device collector: acceptance, coverage, readiness, capacity.

use mag_cal_core::collector::{
    Collector, Offer, CELLS, DEFAULT_MIN_ANGLE_DEG, NOISE_READINGS, READY_CELLS, READY_SAMPLES,
    STALL_OFFERS,
};
use mag_cal_core::{calibrate, Config};
use nalgebra::{Matrix3, Rotation3, Vector3};

/// SplitMix64 with Box-Muller: deterministic noise without a dependency.
struct Rng(u64);

impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }

    fn gauss(&mut self) -> f64 {
        let u = self.uniform().max(1e-300);
        let v = self.uniform();
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
    }
}

/// A firmware-like sensor: `y = b + rho T h + noise`, rounded to counts.
struct Sensor {
    t: Matrix3<f64>,
    b: Vector3<f64>,
    rho: f64,
    noise: f64,
    rng: Rng,
}

impl Sensor {
    /// Field 320 counts, noise 2.5 counts, hard iron a few hundred counts;
    /// soft iron `V diag(0.8, 1, 1.25) V^T` (tilted) or none.
    fn new(soft_iron: bool) -> Self {
        let t = if soft_iron {
            let v = Rotation3::from_euler_angles(0.87, -0.35, 0.61);
            v.matrix()
                * Matrix3::from_diagonal(&Vector3::new(0.8, 1.0, 1.25))
                * v.matrix().transpose()
        } else {
            Matrix3::identity()
        };
        Sensor {
            t,
            b: Vector3::new(180.0, -95.0, 240.0),
            rho: 320.0,
            noise: 2.5,
            rng: Rng(0x6d61_672d_6361_6c21),
        }
    }

    fn read(&mut self, h: &Vector3<f64>) -> [i16; 3] {
        let e = Vector3::new(self.rng.gauss(), self.rng.gauss(), self.rng.gauss());
        let y = self.b + self.t * h * self.rho + e * self.noise;
        [y.x.round() as i16, y.y.round() as i16, y.z.round() as i16]
    }
}

/// Field directions on a spiral from `z = z_hi` down to `z = z_lo`,
/// `dphi` radians of longitude a step: a device turned steadily.
fn spiral(z_hi: f64, z_lo: f64, n: usize, dphi: f64) -> Vec<Vector3<f64>> {
    (0..n)
        .map(|k| {
            let z = z_hi - (z_hi - z_lo) * (k as f64 / (n - 1) as f64);
            let r = (1.0 - z * z).max(0.0).sqrt();
            let p = k as f64 * dphi;
            Vector3::new(r * p.cos(), r * p.sin(), z)
        })
        .collect()
}

fn sin_deg(a: f64) -> f64 {
    a.to_radians().sin()
}

/// Offers every direction; checks after each offer that `percent` is 100
/// exactly when `ready`; returns the offer at which it first became ready.
fn feed<const N: usize>(
    collector: &mut Collector<[i16; 3], N>,
    sensor: &mut Sensor,
    dirs: &[Vector3<f64>],
) -> Option<usize> {
    let mut ready_at = None;
    for (k, h) in dirs.iter().enumerate() {
        collector.offer(sensor.read(h));
        let p = collector.progress();
        assert_eq!(p.percent == 100, p.ready, "{p:?}");
        assert!(p.percent <= 100 && p.cells == CELLS && p.cells_visited <= CELLS);
        assert_eq!(p.samples, collector.len());
        if p.ready && ready_at.is_none() {
            ready_at = Some(k);
        }
    }
    ready_at
}

#[test]
fn spiral_over_the_sphere_becomes_ready_and_calibrates() {
    for soft_iron in [false, true] {
        let mut sensor = Sensor::new(soft_iron);
        let mut c: Collector<[i16; 3], 1000> = Collector::default();
        let ready_at = feed(&mut c, &mut sensor, &spiral(1.0, -1.0, 900, 0.25));
        let p = c.progress();
        println!("soft iron {soft_iron}: {p:?}, ready at offer {ready_at:?}");
        // Going from +z to -z, readiness comes past two thirds of the way.
        let at = ready_at.expect("never ready");
        assert!((500..800).contains(&at), "{at}");
        assert!(p.ready && p.percent == 100);
        assert!(p.cells_visited >= CELLS - 2, "{p:?}");
        // The running centre is a rough hard iron.
        let centre = Vector3::from(c.centre().unwrap()).cast::<f64>();
        assert!((centre - sensor.b).norm() < 0.01 * sensor.rho, "{centre}");
        // What the collector kept calibrates.
        let fit = calibrate::<f32, _>(c.samples(), &Config::default()).unwrap();
        let b = Vector3::from(fit.calibration.hard_iron()).cast::<f64>();
        assert!((b - sensor.b).norm() < 0.005 * sensor.rho, "{b}");
        let rho = f64::from(fit.calibration.field_strength());
        assert!((rho - sensor.rho).abs() < 0.005 * sensor.rho, "{rho}");
    }
}

#[test]
fn a_planar_circle_never_becomes_ready() {
    let dip = 60f64.to_radians();
    // A level compass swing (the field on a cone, the samples on a plane),
    // and a tumble about one tilted axis (a great circle of directions).
    let level: Vec<_> = (0..5000)
        .map(|k| {
            let p = k as f64 * 0.05;
            Vector3::new(dip.cos() * p.cos(), -dip.cos() * p.sin(), dip.sin())
        })
        .collect();
    let r = Rotation3::from_euler_angles(0.4, 0.7, 0.1);
    let great: Vec<_> = (0..5000)
        .map(|k| {
            let p = k as f64 * 0.05;
            r * Vector3::new(p.cos(), p.sin(), 0.0)
        })
        .collect();
    for soft_iron in [false, true] {
        for (name, dirs) in [("level turn", &level), ("great circle", &great)] {
            let mut sensor = Sensor::new(soft_iron);
            let mut c: Collector<[i16; 3], 2000> = Collector::default();
            assert_eq!(feed(&mut c, &mut sensor, dirs), None, "{name}");
            let p = c.progress();
            println!("{name}, soft iron {soft_iron}: {p:?}");
            // A circle of directions crosses at most about 20 of the cells.
            assert!(p.cells_visited <= 24 && p.percent <= 66, "{name}: {p:?}");
            assert!(p.samples >= READY_SAMPLES);
        }
    }
}

#[test]
fn a_band_of_30_deg_reaches_partial_coverage_only() {
    // Elevation within +-30 deg: z/r within +-0.5 touches the four middle
    // bands (32 cells, 67 %), short of the 36 needed; the module
    // documentation lists 31-32 cells.
    for soft_iron in [false, true] {
        let mut sensor = Sensor::new(soft_iron);
        let mut c: Collector<[i16; 3], 1000> = Collector::default();
        let dirs = spiral(sin_deg(30.0), -sin_deg(30.0), 900, 0.25);
        assert_eq!(feed(&mut c, &mut sensor, &dirs), None);
        let p = c.progress();
        println!("band +-30, soft iron {soft_iron}: {p:?}");
        assert!((28..=32).contains(&p.cells_visited), "{p:?}");
        assert!((77..=88).contains(&p.percent), "{p:?}");
        assert!(!p.ready);
        // Offering on (a device held still, in the band) refreshes the
        // coverage through the round robin.
        for _ in 0..1000 {
            c.offer(sensor.read(&Vector3::x()));
        }
        let p = c.progress();
        assert!((30..=32).contains(&p.cells_visited) && !p.ready, "{p:?}");
    }
}

#[test]
fn caps_are_not_mistaken_for_the_sphere() {
    // The midrange centre would make a cap of 35 % of the sphere look ready
    // (38 cells); the sphere fit sees about half of the cells.
    for soft_iron in [false, true] {
        let mut sensor = Sensor::new(soft_iron);
        let mut c: Collector<[i16; 3], 1000> = Collector::default();
        assert_eq!(
            feed(&mut c, &mut sensor, &spiral(1.0, 0.3, 900, 0.25)),
            None
        );
        let p = c.progress();
        println!("cap z > 0.3, soft iron {soft_iron}: {p:?}");
        assert!(p.cells_visited <= 26, "{p:?}");
    }
}

/// Noise-free readings of a device turning about z by `step` radians a
/// reading (a field of 100 units around the origin).
fn turning(n: usize, step: f32) -> Vec<[f32; 3]> {
    (0..n)
        .map(|k| {
            let a = k as f32 * step;
            [100.0 * a.cos(), 100.0 * a.sin(), 30.0]
        })
        .collect()
}

#[test]
fn identical_samples_are_too_close_after_the_first() {
    let mut c: Collector<[i16; 3], 100> = Collector::default();
    assert_eq!(c.offer([100, 200, 300]), Offer::Accepted);
    for _ in 0..50 {
        assert_eq!(c.offer([100, 200, 300]), Offer::TooClose);
    }
    assert_eq!(c.len(), 1);
    // Also later, and with a minimum angle of zero: a device turning 10 deg
    // a reading is kept from the end of the noise estimate's warm-up on,
    // and an exact repeat of the last sample is refused.
    let mut c: Collector<[f32; 3], 100> = Collector::new(0.0);
    let path = turning(20, 10f32.to_radians());
    let answers: Vec<Offer> = path.iter().map(|&y| c.offer(y)).collect();
    assert_eq!(answers[0], Offer::Accepted);
    assert!(answers[1..NOISE_READINGS - 1]
        .iter()
        .all(|&a| a == Offer::TooClose));
    assert!(answers[NOISE_READINGS - 1..]
        .iter()
        .all(|&a| a == Offer::Accepted));
    let last = *c.samples().last().unwrap();
    assert_eq!(c.offer(last), Offer::TooClose);
    assert_eq!(c.len(), 2 + path.len() - NOISE_READINGS);
}

#[test]
fn a_device_held_still_adds_nothing() {
    let mut sensor = Sensor::new(true);
    let mut c: Collector<[i16; 3], 1000> = Collector::default();
    feed(&mut c, &mut sensor, &spiral(1.0, -1.0, 900, 0.25));
    let before = c.len();
    let h = Vector3::new(0.3, -0.5, 0.8).normalize();
    let mut accepted = 0;
    for _ in 0..2000 {
        if c.offer(sensor.read(&h)) == Offer::Accepted {
            accepted += 1;
        }
    }
    // Noise of 0.45 deg never fakes a 4 deg turn; at most the first reading
    // is new.
    assert!(accepted <= 1, "{accepted}");
    assert!(c.len() <= before + 1);
}

#[test]
fn the_minimum_angle_is_measured_from_the_last_sample_kept() {
    // Noise-free samples on a sphere: once it is covered the centre is
    // exact, so directions are the true ones.
    let b = [180.0f32, -95.0, 240.0];
    let point = |h: Vector3<f64>| {
        let h = h.cast::<f32>() * 320.0;
        [b[0] + h.x, b[1] + h.y, b[2] + h.z]
    };
    let mut c: Collector<[f32; 3], 2000> = Collector::default();
    for h in spiral(1.0, -1.0, 900, 0.25) {
        c.offer(point(h));
    }
    let centre = c.centre().unwrap();
    assert!(
        (0..3).all(|k| (centre[k] - b[k]).abs() < 1e-2),
        "{centre:?}"
    );
    // Turning in 0.3 deg steps keeps every 14th reading (4.2 deg; steps
    // that land on exactly 4 deg would test rounding, not the rule).
    let mut kept = Vec::new();
    for k in 0..=150 {
        let a = (k as f64 * 0.3).to_radians();
        if c.offer(point(Vector3::new(a.cos(), 0.0, a.sin()))) == Offer::Accepted {
            kept.push(k);
        }
    }
    println!("kept {kept:?}");
    assert_eq!(kept, (0..=150).step_by(14).collect::<Vec<_>>());
    // Larger minimum angle, same rule.
    let mut c10: Collector<[f32; 3], 2000> = Collector::new(10.0);
    for h in spiral(1.0, -1.0, 900, 0.25) {
        c10.offer(point(h));
    }
    let mut kept = Vec::new();
    for k in 0..=150 {
        let a = (k as f64 * 0.3).to_radians();
        if c10.offer(point(Vector3::new(a.cos(), 0.0, a.sin()))) == Offer::Accepted {
            kept.push(k);
        }
    }
    assert_eq!(kept, (0..=150).step_by(34).collect::<Vec<_>>());
}

#[test]
fn non_finite_samples_are_refused() {
    let mut c: Collector<[f32; 3], 10> = Collector::default();
    assert_eq!(c.offer([f32::NAN, 1.0, 2.0]), Offer::NotFinite);
    assert_eq!(c.offer([1.0, f32::INFINITY, 2.0]), Offer::NotFinite);
    assert_eq!(c.offer([1.0, 2.0, f32::NEG_INFINITY]), Offer::NotFinite);
    assert!(c.is_empty() && c.centre().is_none());
    assert_eq!(c.offer([1.0, 2.0, 3.0]), Offer::Accepted);
    // Finite but so far away that the sums would overflow f32 (before the
    // noise estimate, which never sees them).
    assert_eq!(c.offer([1e30, 0.0, 0.0]), Offer::NotFinite);
    assert_eq!(c.offer([f32::MAX, f32::MAX, f32::MAX]), Offer::NotFinite);
    assert_eq!(c.len(), 1);
    assert_eq!(c.centre(), Some([1.0, 2.0, 3.0]));

    let mut c: Collector<[f64; 3], 10> = Collector::default();
    assert_eq!(c.offer([1e300, 0.0, 0.0]), Offer::NotFinite);
    assert_eq!(c.offer([f64::NAN, 0.0, 0.0]), Offer::NotFinite);
    assert!(c.is_empty());
}

#[test]
fn capacity_is_respected() {
    let mut c: Collector<[f32; 3], 3> = Collector::default();
    assert_eq!((c.len(), c.capacity(), c.is_empty()), (0, 3, true));
    let answers: Vec<Offer> = turning(NOISE_READINGS + 4, 0.5)
        .into_iter()
        .map(|y| c.offer(y))
        .collect();
    // The first reading, two after the warm-up, then full.
    assert_eq!(answers[0], Offer::Accepted);
    assert_eq!(answers[NOISE_READINGS - 1], Offer::Accepted);
    assert_eq!(answers[NOISE_READINGS], Offer::Accepted);
    assert!(answers[NOISE_READINGS + 1..]
        .iter()
        .all(|&a| a == Offer::Full));
    assert_eq!(c.len(), 3);
    assert_eq!(c.offer([0.0, 0.0, 100.0]), Offer::Full);
    // Full before anything else, even for a NaN.
    let mut f: Collector<[f32; 3], 1> = Collector::default();
    assert_eq!(f.offer([0.0, 0.0, 1.0]), Offer::Accepted);
    assert_eq!(f.offer([f32::NAN; 3]), Offer::Full);
    // A small collector is ready when full, if coverage allows: here it
    // cannot reach 36 cells with 3 samples.
    assert!(!c.is_ready());
    c.clear();
    assert!(c.is_empty() && c.centre().is_none());
    let p = c.progress();
    assert_eq!(
        (p.samples, p.cells_visited, p.percent, p.ready),
        (0, 0, 0, false)
    );
    assert_eq!(c.offer([0.0, -100.0, 0.0]), Offer::Accepted);
    // Capacity zero: always full, never ready.
    let mut z: Collector<[i16; 3], 0> = Collector::default();
    assert_eq!(z.offer([1, 2, 3]), Offer::Full);
    assert!(!z.is_ready());
}

#[test]
fn works_at_capacity_2000() {
    // offer() is O(1): no loop over the stored samples (the running sums,
    // one 3x3 solve, and a round robin of 4 stored samples per call); the
    // collector fills up and keeps answering.
    let mut sensor = Sensor::new(true);
    let mut c: Collector<[i16; 3], 2000> = Collector::default();
    let dirs = spiral(1.0, -1.0, 1950, 0.25);
    let mut full = 0;
    for pass in 0..2 {
        for h in &dirs {
            if c.offer(sensor.read(h)) == Offer::Full {
                full += 1;
            }
        }
        println!("pass {pass}: {:?}", c.progress());
    }
    assert_eq!(c.len(), 2000);
    assert!(full > 0);
    let p = c.progress();
    assert!(p.ready && p.cells_visited >= CELLS - 2, "{p:?}");
    let fit = calibrate::<f32, _>(c.samples(), &Config::default()).unwrap();
    assert!((Vector3::from(fit.calibration.hard_iron()).cast::<f64>() - sensor.b).norm() < 1.5);
}

#[test]
fn percent_combines_cells_and_count() {
    // Every cell of a collector of capacity 50 reached with 50 samples:
    // count fraction 100 % (capacity below READY_SAMPLES), cells decide.
    // A fast, noise-free turn from pole to pole (one sample a reading once
    // the noise is known: the first readings stay near the pole).
    let mut sensor = Sensor::new(false);
    sensor.noise = 0.0;
    let mut c: Collector<[i16; 3], 50> = Collector::default();
    let start = spiral(1.0, 0.99, NOISE_READINGS - 1, 0.1);
    for h in start.iter().chain(&spiral(0.98, -1.0, 52, 1.2)) {
        c.offer(sensor.read(h));
    }
    for _ in 0..100 {
        c.offer([0, 0, 0]); // Full; refreshes the coverage
    }
    let p = c.progress();
    println!("{p:?}");
    assert_eq!(p.samples, 50);
    assert!(
        p.cells_visited >= READY_CELLS && p.ready && p.percent == 100,
        "{p:?}"
    );
}

#[test]
fn min_angle_arguments_are_sanitised() {
    for a in [
        f32::NAN,
        -5.0,
        0.0,
        1e9,
        f32::INFINITY,
        f32::NEG_INFINITY,
        DEFAULT_MIN_ANGLE_DEG,
    ] {
        let mut c: Collector<[f32; 3], 8> = Collector::new(a);
        let path = turning(NOISE_READINGS - 1, 0.3);
        assert_eq!(c.offer(path[0]), Offer::Accepted, "{a}");
        assert_eq!(c.offer(path[0]), Offer::TooClose, "{a}");
        for &y in &path[2..] {
            c.offer(y);
        }
        // With one sample stored, the centre is that sample: any direction
        // is new, at every minimum angle (even 180 deg).
        assert_eq!(c.len(), 1, "{a}");
        assert_eq!(c.offer([-100.0, 0.0, 30.0]), Offer::Accepted, "{a}");
        assert_eq!(c.offer([-100.0, 0.0, 30.0]), Offer::TooClose, "{a}");
    }
}

#[test]
fn hostile_input_never_panics() {
    let mut rng = Rng(1);
    let mut cf: Collector<[f32; 3], 64> = Collector::default();
    let mut ci: Collector<[i32; 3], 64> = Collector::new(0.0);
    let mut ch: Collector<[i16; 3], 64> = Collector::new(180.0);
    for k in 0..20_000 {
        let bits = [0, 1, 2].map(|_| (rng.uniform() * 4_294_967_296.0) as u32);
        cf.offer(bits.map(f32::from_bits));
        ci.offer(bits.map(|b| b as i32));
        ch.offer(bits.map(|b| b as i16));
        if k % 1000 == 0 {
            let _ = (cf.progress(), ci.progress(), ch.progress());
            cf.clear();
        }
    }
    let _ = (cf.progress(), ci.progress(), ch.progress());
    assert!(ci.len() <= 64 && ch.len() <= 64);
}

/// Wild readings (I2C glitches over the i16 range), zero rows and rows on
/// the rails, offered among a collection, are refused and named; the
/// collection, its centre and its calibration are those of the clean
/// readings alone.
#[test]
fn wild_readings_and_glitches_are_refused() {
    let dirs = spiral(1.0, -1.0, 900, 0.25);
    let mut clean: Collector<[i16; 3], 1000> = Collector::default();
    feed(&mut clean, &mut Sensor::new(true), &dirs);
    let mut dirty: Collector<[i16; 3], 1000> = Collector::default();
    let mut sensor = Sensor::new(true);
    let mut rng = Rng(99);
    let (mut outliers, mut glitches) = (0, 0);
    for (k, h) in dirs.iter().enumerate() {
        let reading = sensor.read(h);
        if k >= 40 && k % 7 == 0 {
            let wild = [0, 1, 2].map(|_| (rng.uniform() * 60000.0 - 30000.0) as i16);
            // A wild reading may land near the sphere by chance (then it is
            // an ordinary, if noisy, sample); those far off are refused.
            let d =
                Vector3::new(f64::from(wild[0]), f64::from(wild[1]), f64::from(wild[2])) - sensor.b;
            let offer = dirty.offer(wild);
            if d.norm() > 4.0 * sensor.rho {
                assert_eq!(offer, Offer::Outlier, "{wild:?}");
                outliers += 1;
            }
        }
        if k % 50 == 3 {
            assert_eq!(dirty.offer([0, 0, 0]), Offer::Glitch);
            assert_eq!(
                dirty.offer([reading[0], i16::MAX, reading[2]]),
                Offer::Glitch
            );
            glitches += 2;
        }
        dirty.offer(reading);
    }
    assert!(outliers > 100 && glitches == 36, "{outliers} {glitches}");
    // The same clean readings were offered (the sensor's noise is drawn in
    // the same order), so the same were kept.
    assert_eq!(dirty.len(), clean.len());
    assert_eq!(dirty.samples(), clean.samples());
    assert_eq!(dirty.progress(), clean.progress());
    let (a, b) = (
        calibrate::<f32, _>(dirty.samples(), &Config::default()).unwrap(),
        calibrate::<f32, _>(clean.samples(), &Config::default()).unwrap(),
    );
    assert_eq!(a.calibration, b.calibration);
}

/// Offers every direction and counts the collector's restarts.
fn restarts<const N: usize>(
    collector: &mut Collector<[i16; 3], N>,
    sensor: &mut Sensor,
    dirs: &[Vector3<f64>],
) -> usize {
    dirs.iter()
        .filter(|h| collector.offer(sensor.read(h)) == Offer::Restarted)
        .count()
}

/// Hard-iron error of a calibration of what the collector kept, relative
/// to the field.
fn hard_iron_error<const N: usize>(collector: &Collector<[i16; 3], N>, sensor: &Sensor) -> f64 {
    let fit = calibrate::<f32, _>(collector.samples(), &Config::default()).unwrap();
    let b = Vector3::from(fit.calibration.hard_iron()).cast::<f64>();
    (b - sensor.b).norm() / sensor.rho
}

#[test]
fn clean_motion_never_restarts() {
    // Fast and slow turns (0.25 and 0.002 rad of longitude a reading: the
    // slow one adds a sample only every 30-60 readings at first), bands and
    // caps: no stall, no restart.
    let cases = [
        ("sphere", spiral(1.0, -1.0, 900, 0.25)),
        ("slow sphere", spiral(1.0, -1.0, 30_000, 0.002)),
        ("band", spiral(0.5, -0.5, 900, 0.25)),
        ("cap", spiral(1.0, 0.3, 900, 0.25)),
        ("slow cap", spiral(1.0, 0.6, 20_000, 0.002)),
    ];
    for soft_iron in [false, true] {
        for (name, dirs) in &cases {
            let mut sensor = Sensor::new(soft_iron);
            let mut c: Collector<[i16; 3], 1000> = Collector::default();
            assert_eq!(restarts(&mut c, &mut sensor, dirs), 0, "{name}");
            assert!(c.len() >= READY_SAMPLES, "{name}: {}", c.len());
        }
    }
}

/// Readings of a device lying still: the field direction `h` plus
/// independent noise of `sigma` counts per axis (or noise that is
/// correlated from reading to reading by `a`, an AR(1) process with the
/// same standard deviation), in counts, not rounded.
fn still_f64(sensor: &mut Sensor, h: &Vector3<f64>, n: usize, sigma: f64, a: f64) -> Vec<[f64; 3]> {
    let mut e = Vector3::zeros();
    let innovation = sigma * (1.0 - a * a).sqrt();
    (0..n)
        .map(|_| {
            let g = Vector3::new(sensor.rng.gauss(), sensor.rng.gauss(), sensor.rng.gauss());
            e = e * a + g * innovation;
            (sensor.b + sensor.t * h * sensor.rho + e).into()
        })
        .collect()
}

/// [`still_f64`] rounded to counts.
fn still(sensor: &mut Sensor, h: &Vector3<f64>, n: usize, sigma: f64, a: f64) -> Vec<[i16; 3]> {
    let rows = still_f64(sensor, h, n, sigma, a);
    rows.iter().map(|y| y.map(|v| v.round() as i16)).collect()
}

/// Offers every reading to an empty collector of 600: the samples stored
/// and the highest progress seen, after checking that it never restarted
/// and was never ready.
fn offer_still<S: mag_cal_core::Sample + Copy>(rows: &[S]) -> (usize, u8) {
    let mut c: Collector<S, 600> = Collector::default();
    let mut percent = 0;
    for &y in rows {
        assert_ne!(c.offer(y), Offer::Restarted);
        let p = c.progress();
        assert!(!p.ready, "{p:?}");
        percent = percent.max(p.percent);
    }
    (c.len(), percent)
}

/// A device lying still, however long and whatever its noise, is never
/// ready, and its progress stays near 0 at every reading, in counts
/// (`i16`) and unquantised (`f32`). Its noise points every way from a
/// centre inside it; spaced by direction alone it would fill the 36 cells
/// readiness asks for within 300 readings. Noise correlated from reading
/// to reading (a low-pass filter) stores some samples; they lie within the
/// noise of the centre and mark few cells (`Progress::cells_visited`).
#[test]
fn a_device_lying_still_never_becomes_ready() {
    let h = Vector3::new(0.3, -0.5, 0.8).normalize();
    // Independent noise from a tenth of a count (readings that toggle a
    // count now and then) to 3 counts, and noise correlated from reading
    // to reading (a sensor's low-pass filter, a host's smoothing), with the
    // highest progress allowed: measured 0 % for independent noise, at
    // most 2 % at correlation 0.5, 6 % (i16) and 13 % (f32) at 0.7, 75 %
    // at 0.8.
    let cases = [
        (0.1, 0.0, 2),
        (0.3, 0.0, 2),
        (1.0, 0.0, 2),
        (2.5, 0.0, 2),
        (3.0, 0.0, 2),
        (2.5, 0.35, 2),
        (2.5, 0.5, 5),
        (2.5, 0.7, 15),
        (2.5, 0.8, 90),
    ];
    for (sigma, a, max_percent) in cases {
        for n in [300, 3_000, 30_000] {
            let (mut samples, mut percent) = ([0; 2], [0; 2]);
            for seed in 0..8 {
                let mut sensor = Sensor::new(true);
                sensor.rng = Rng(seed * 7919 + 1);
                let rows = still_f64(&mut sensor, &h, n, sigma, a);
                let counts: Vec<[i16; 3]> =
                    rows.iter().map(|y| y.map(|v| v.round() as i16)).collect();
                let floats: Vec<[f32; 3]> = rows.iter().map(|y| y.map(|v| v as f32)).collect();
                for (k, (kept, most)) in [offer_still(&counts), offer_still(&floats)]
                    .into_iter()
                    .enumerate()
                {
                    samples[k] = samples[k].max(kept);
                    percent[k] = percent[k].max(most);
                }
            }
            println!(
                "sigma {sigma} counts, correlation {a}, {n} readings: at most {} samples, {} % (i16), {} samples, {} % (f32)",
                samples[0], percent[0], samples[1], percent[1]
            );
            assert!(
                percent[0].max(percent[1]) <= max_percent,
                "sigma {sigma}, a {a}, {n} readings"
            );
        }
    }
}

/// A device lying still when the collection starts (for up to 30 000
/// readings, 25 min at 20 Hz) stores one sample; once it turns, the
/// collection fills as if it had started then.
#[test]
fn a_device_lying_still_at_first_does_not_stall_the_collection() {
    let dirs = spiral(1.0, -1.0, 900, 0.25);
    let mut alone: Collector<[i16; 3], 1000> = Collector::default();
    let ready_alone = feed(&mut alone, &mut Sensor::new(true), &dirs).unwrap();
    for n in [30, 300, 3_000, 30_000] {
        let mut sensor = Sensor::new(true);
        let sigma = sensor.noise;
        let h = Vector3::new(0.3, -0.5, 0.8).normalize();
        let mut c: Collector<[i16; 3], 1000> = Collector::default();
        for y in still(&mut sensor, &h, n, sigma, 0.0) {
            assert_ne!(c.offer(y), Offer::Restarted);
        }
        let p = c.progress();
        assert!(p.samples <= 2 && p.percent <= 2, "{p:?}");
        let mut restarts = 0;
        let mut ready_at = None;
        for (k, h) in dirs.iter().enumerate() {
            restarts += usize::from(c.offer(sensor.read(h)) == Offer::Restarted);
            if ready_at.is_none() && c.is_ready() {
                ready_at = Some(k);
            }
        }
        let p = c.progress();
        println!(
            "still {n}: ready {ready_at:?} readings into the turn (alone {ready_alone}), {restarts} restart(s), {p:?}"
        );
        assert_eq!(restarts, 0);
        assert!(p.ready, "{p:?}");
        let at = ready_at.expect("never ready");
        assert!(at <= ready_alone + 20, "{at} against {ready_alone}");
        let e = hard_iron_error(&c, &sensor);
        assert!(e < 0.005, "{e}");
    }
}

/// A wild reading among the first samples (a start-up value) drags the
/// running centre before any outlier test applies; the collection starts
/// over, at most once, and then fills as usual.
#[test]
fn a_wild_reading_among_the_first_does_not_stall_the_collection() {
    let dirs = spiral(1.0, -1.0, 900, 0.25);
    for at in 0..20 {
        for wild in [
            [25_000, -20_000, 31_000],
            [0, 0, -30_000],
            [-400, 9_000, 240],
        ] {
            let mut sensor = Sensor::new(true);
            let mut c: Collector<[i16; 3], 1000> = Collector::default();
            let mut n = restarts(&mut c, &mut sensor, &dirs[..at]);
            if c.offer(wild) == Offer::Restarted {
                n += 1;
            }
            n += restarts(&mut c, &mut sensor, &dirs[at..]);
            let p = c.progress();
            assert!(n <= 1, "wild {wild:?} at {at}: {n} restarts");
            assert!(p.ready, "wild {wild:?} at {at}: {p:?}");
            assert!(!c.samples().contains(&wild), "wild {wild:?} at {at}");
            let e = hard_iron_error(&c, &sensor);
            assert!(e < 0.005, "wild {wild:?} at {at}: {e}");
        }
    }
}

/// A magnet held at the sensor for longer than STALL_OFFERS readings does
/// not discard a collection that holds more samples than that; the sensor
/// moved to a new place (another hard iron) restarts a small one.
#[test]
fn a_long_disturbance_restarts_only_a_small_collection() {
    let dirs = spiral(1.0, -1.0, 900, 0.25);
    let mut sensor = Sensor::new(true);
    let mut c: Collector<[i16; 3], 1000> = Collector::default();
    assert_eq!(restarts(&mut c, &mut sensor, &dirs[..600]), 0);
    let kept = c.len();
    assert!(kept > 2 * STALL_OFFERS, "{kept}");
    // A magnet at the sensor: readings 10 fields off, for 2 STALL_OFFERS.
    let magnet = sensor.b + Vector3::new(3200.0, 0.0, 0.0);
    let near = sensor.b;
    sensor.b = magnet;
    let held = vec![Vector3::x(); 2 * STALL_OFFERS];
    assert_eq!(restarts(&mut c, &mut sensor, &held), 0);
    assert_eq!(c.len(), kept);
    sensor.b = near;
    assert_eq!(restarts(&mut c, &mut sensor, &dirs[600..]), 0);
    assert!(c.is_ready());

    // A small collection (50 samples), then the sensor mounted elsewhere:
    // the new hard iron makes every reading an outlier; after STALL_OFFERS
    // of them the collection starts over, and collects the new place.
    let mut c: Collector<[i16; 3], 1000> = Collector::default();
    let mut sensor = Sensor::new(true);
    let mut k = 0;
    while c.len() < 50 {
        c.offer(sensor.read(&dirs[k]));
        k += 1;
    }
    sensor.b += Vector3::new(-2500.0, 1500.0, 2000.0);
    let answers: Vec<Offer> = dirs[k..k + STALL_OFFERS]
        .iter()
        .map(|h| c.offer(sensor.read(h)))
        .collect();
    assert!(answers[..STALL_OFFERS - 1]
        .iter()
        .all(|&a| a == Offer::Outlier));
    assert_eq!(answers[STALL_OFFERS - 1], Offer::Restarted);
    assert!(c.is_empty());
    assert_eq!(restarts(&mut c, &mut sensor, &dirs), 0);
    assert!(c.is_ready());
    let e = hard_iron_error(&c, &sensor);
    assert!(e < 0.005, "{e}");
}
