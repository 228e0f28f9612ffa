//! Simulated magnetometer data with known truth (design document, section 11).
//!
//! Seeded and dependency-free, so every test and table is reproducible.

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

/// SplitMix64: a tiny, seeded, dependency-free generator for test data.
pub struct Rng(pub u64);

impl Rng {
    /// The generator of case `index` under `seed` (for fuzzing: every case
    /// reproducible on its own), one draw past the seeding.
    pub fn for_case(seed: u64, index: u64) -> Self {
        let mut r = Rng(seed ^ index.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        r.next_u64();
        r
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (`n > 0`).
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n
    }

    /// Uniform in `0..n` (`n > 0`).
    pub fn index(&mut self, n: usize) -> usize {
        self.below(n as u64) as usize
    }

    /// Uniform in `[0, 1)`.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }

    /// Uniform in (0, 1).
    pub fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    pub fn unit_vector(&mut self) -> Vector3<f64> {
        Vector3::new(self.normal(), self.normal(), self.normal()).normalize()
    }

    pub fn rotation(&mut self) -> Matrix3<f64> {
        let q = Quaternion::new(self.normal(), self.normal(), self.normal(), self.normal());
        UnitQuaternion::from_quaternion(q)
            .to_rotation_matrix()
            .into_inner()
    }
}

/// `n` nearly uniform directions on the unit sphere (Fibonacci lattice).
pub fn fibonacci_sphere(n: usize) -> Vec<Vector3<f64>> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let phi = golden * i as f64;
            Vector3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect()
}

/// Random directions with elevation within +-`max_elev_deg`.
pub fn band(n: usize, max_elev_deg: f64, rng: &mut Rng) -> Vec<Vector3<f64>> {
    let zmax = max_elev_deg.to_radians().sin();
    (0..n)
        .map(|_| {
            let z = zmax * (2.0 * rng.uniform() - 1.0);
            let phi = std::f64::consts::TAU * rng.uniform();
            let r = (1.0 - z * z).sqrt();
            Vector3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect()
}

/// The truth of ALGORITHMS.md section 11: `T = Ssi diag(1.25, 0.85, 1.05) N Rm`.
pub fn scenario_t() -> Matrix3<f64> {
    let ssi = Matrix3::new(1.0, 0.08, -0.05, 0.08, 1.0, 0.06, -0.05, 0.06, 1.0);
    let scale = Matrix3::from_diagonal(&Vector3::new(1.25, 0.85, 1.05));
    let nonorth = Matrix3::new(1.0, 0.0, 0.0, 0.05, 1.0, 0.0, -0.03, 0.04, 1.0);
    let rot = |axis: Vector3<f64>, deg: f64| {
        nalgebra::Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), deg.to_radians())
            .into_inner()
    };
    let rm = rot(Vector3::z(), 3.0) * rot(Vector3::y(), -2.0) * rot(Vector3::x(), 2.0);
    ssi * scale * nonorth * rm
}

/// A random distortion: rotation * diag(1.25, 0.85, 1.05) * rotation.
pub fn random_t(rng: &mut Rng) -> Matrix3<f64> {
    let scale = Matrix3::from_diagonal(&Vector3::new(1.25, 0.85, 1.05));
    rng.rotation() * scale * rng.rotation()
}

/// `y_i = T h_i + b + e_i`, `e_i ~ N(0, noise_std^2 I)`.
pub fn make_samples(
    t: &Matrix3<f64>,
    b: &Vector3<f64>,
    dirs: &[Vector3<f64>],
    noise_std: f64,
    rng: &mut Rng,
) -> Vec<[f64; 3]> {
    dirs.iter()
        .map(|h| {
            let e = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * noise_std;
            let y = t * h + b + e;
            [y.x, y.y, y.z]
        })
        .collect()
}

/// `y_i = T h_i + b + e_i` with per-axis noise standard deviations.
pub fn make_samples_axes(
    t: &Matrix3<f64>,
    b: &Vector3<f64>,
    dirs: &[Vector3<f64>],
    noise_std: [f64; 3],
    rng: &mut Rng,
) -> Vec<[f64; 3]> {
    dirs.iter()
        .map(|h| {
            let e = Vector3::new(
                noise_std[0] * rng.normal(),
                noise_std[1] * rng.normal(),
                noise_std[2] * rng.normal(),
            );
            (t * h + b + e).into()
        })
        .collect()
}

/// `n` random directions uniform on the sphere.
pub fn sphere(n: usize, rng: &mut Rng) -> Vec<Vector3<f64>> {
    (0..n).map(|_| rng.unit_vector()).collect()
}

/// The design document's truth (`T`, `b = (0.3, -0.2, 0.1)`) seen from
/// 1000 random directions on the sphere or on a +-30 deg band, with
/// per-axis noise: the parity tests' standard data.
pub fn scenario_samples(noise: [f64; 3], banded: bool, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = Rng(seed);
    let dirs = if banded {
        band(1000, 30.0, &mut rng)
    } else {
        sphere(1000, &mut rng)
    };
    make_samples_axes(
        &scenario_t(),
        &Vector3::new(0.3, -0.2, 0.1),
        &dirs,
        noise,
        &mut rng,
    )
}
