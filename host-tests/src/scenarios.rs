//! The simulation scenarios of the design document, section 11: the
//! parameter study A-G (Table I) and the heading scenario H (Table II).
//!
//! Every run is generated from its own seed ([`run_seed`]), so a run does not
//! depend on how many runs came before it, and the tables are reproducible
//! bit for bit (timings aside).

use nalgebra::{Matrix3, Rotation3, Vector3};

use crate::sim::{band, make_samples_axes, scenario_t, sphere, Rng};

/// Samples per run in A-G.
pub const N_SAMPLES: usize = 1000;

/// Hard iron of A-G.
pub const HARD_IRON: [f64; 3] = [0.3, -0.2, 0.1];

/// Elevation limit of the band scenarios (C, D, G), degrees.
pub const BAND_DEG: f64 = 30.0;

/// The truth of A-G: `y = T h + b + e`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Truth {
    /// Distortion `T = Ssi diag(1.25, 0.85, 1.05) N Rm`.
    pub t: Matrix3<f64>,
    /// Hard iron `b`.
    pub b: Vector3<f64>,
}

impl Truth {
    /// The design document's truth.
    pub fn paper() -> Self {
        Self {
            t: scenario_t(),
            b: Vector3::from(HARD_IRON),
        }
    }

    /// The noise-free reading of direction `h`.
    pub fn reading(&self, h: &Vector3<f64>) -> Vector3<f64> {
        self.t * h + self.b
    }
}

/// One of the scenarios A-G.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scenario {
    /// `'A'` to `'G'`.
    pub id: char,
    /// Per-axis noise standard deviation (same units as the unit field).
    pub noise: [f64; 3],
    /// Directions within +-30 deg of elevation instead of the full sphere.
    pub banded: bool,
}

/// Scenarios A-G (design document, section 11).
pub const SCENARIOS: [Scenario; 7] = [
    Scenario {
        id: 'A',
        noise: [0.01, 0.02, 0.03],
        banded: false,
    },
    Scenario {
        id: 'B',
        noise: [0.05, 0.075, 0.10],
        banded: false,
    },
    Scenario {
        id: 'C',
        noise: [0.01, 0.02, 0.03],
        banded: true,
    },
    Scenario {
        id: 'D',
        noise: [0.05, 0.075, 0.10],
        banded: true,
    },
    Scenario {
        id: 'E',
        noise: [0.10, 0.15, 0.20],
        banded: false,
    },
    Scenario {
        id: 'F',
        noise: [0.075; 3],
        banded: false,
    },
    Scenario {
        id: 'G',
        noise: [0.075; 3],
        banded: true,
    },
];

/// A generated run: the true directions and the noisy samples.
#[derive(Clone, Debug, PartialEq)]
pub struct Run {
    /// The true unit directions `h_i` (the "training directions").
    pub dirs: Vec<Vector3<f64>>,
    /// `y_i = T h_i + b + e_i`.
    pub samples: Vec<[f64; 3]>,
}

/// The seed of run `run` of the scenario with index `scenario` (0 = A,
/// 7 = H). SplitMix64 hashes its state, so consecutive seeds give
/// independent streams.
pub fn run_seed(scenario: usize, run: usize) -> u64 {
    0x4D41_4743_0000_0000 ^ ((scenario as u64) << 24) ^ run as u64
}

impl Scenario {
    /// Index in [`SCENARIOS`].
    pub fn index(&self) -> usize {
        (self.id as u8 - b'A') as usize
    }

    /// Human-readable description, e.g. `noise (0.01, 0.02, 0.03), full sphere`.
    pub fn describe(&self) -> String {
        let [a, b, c] = self.noise;
        let coverage = if self.banded {
            "band +-30 deg"
        } else {
            "full sphere"
        };
        if a == b && b == c {
            format!("noise {a} isotropic, {coverage}")
        } else {
            format!("noise ({a}, {b}, {c}), {coverage}")
        }
    }

    /// Run number `run` (deterministic).
    pub fn generate(&self, truth: &Truth, run: usize) -> Run {
        let mut rng = Rng(run_seed(self.index(), run));
        let dirs = if self.banded {
            band(N_SAMPLES, BAND_DEG, &mut rng)
        } else {
            sphere(N_SAMPLES, &mut rng)
        };
        let samples = make_samples_axes(&truth.t, &truth.b, &dirs, self.noise, &mut rng);
        Run { dirs, samples }
    }
}

/// Scenario H: the heading experiment, after the paper's Table II settings
/// (our own reconstruction; the paper's simulator was MATLAB's
/// `magparams`/`imuSensor`).
///
/// The sensor model per sample is `y = clip(quantise(K f_body + bias + e))`
/// with `f_body = R^T f` the field in the sensor frame for attitude `R`
/// (sensor to navigation frame; navigation frame x north, y east, z down).
///
/// Trajectory: three full turns about the navigation x axis, then three about
/// y, then three about z, starting level each time (a full turn ends where it
/// began, so the sequence is continuous). We take [`HEADING_SAMPLES_PER_TURN`]
/// = 400 samples per turn: at the 15 ms period that is 6 s per turn, 60 deg/s,
/// 0.9 deg between samples, a deliberate hand or turntable rotation (a person
/// turning on the spot does 45-180 deg/s). A run is 3600 samples (54 s).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeadingScenario {
    /// Earth field in the navigation frame, uT.
    pub field: [f64; 3],
    /// Constant bias, uT.
    pub bias: [f64; 3],
    /// Cross-axis coupling (MATLAB's axes misalignment [20 40 3] %).
    pub coupling: Matrix3<f64>,
    /// White noise density per axis, uT/sqrt(Hz).
    pub noise_density: [f64; 3],
    /// Sampling period, s.
    pub period: f64,
    /// Quantisation step, uT.
    pub resolution: f64,
    /// Clipping limit, +-uT.
    pub range: f64,
    /// Samples per full turn.
    pub samples_per_turn: usize,
    /// Full turns about each axis.
    pub turns: usize,
}

/// Samples per full turn in scenario H (see [`HeadingScenario`]).
pub const HEADING_SAMPLES_PER_TURN: usize = 400;

/// Index of scenario H for [`run_seed`].
pub const HEADING_SCENARIO_INDEX: usize = 7;

/// A generated run of scenario H.
#[derive(Clone, Debug, PartialEq)]
pub struct HeadingRun {
    /// Raw readings, uT (quantised and clipped).
    pub samples: Vec<[f64; 3]>,
    /// The true field in the sensor frame, normalised to unit length
    /// (the alignment target).
    pub true_dirs: Vec<Vector3<f64>>,
    /// Where the three turns about z (level) are in `samples`.
    pub level: std::ops::Range<usize>,
}

impl Default for HeadingScenario {
    fn default() -> Self {
        Self::paper()
    }
}

impl HeadingScenario {
    /// The settings of the design document (section 11, scenario H).
    pub fn paper() -> Self {
        Self {
            field: [27.555, -2.4169, -16.0849],
            bias: [2.0, -3.0, 1.0],
            coupling: Matrix3::new(1.0, 0.20, 0.40, 0.0, 1.0, 0.03, 0.0, 0.0, 1.0),
            noise_density: [0.15, 0.15, 0.20],
            period: 0.015,
            resolution: 0.0625,
            range: 200.0,
            samples_per_turn: HEADING_SAMPLES_PER_TURN,
            turns: 3,
        }
    }

    /// Per-axis noise standard deviation, uT: density x sqrt(bandwidth) with
    /// the Nyquist bandwidth `1 / (2 period)` (0.866, 0.866, 1.155 uT here).
    pub fn noise_std(&self) -> [f64; 3] {
        let bw = (1.0 / (2.0 * self.period)).sqrt();
        self.noise_density.map(|d| d * bw)
    }

    /// Samples in one run.
    pub fn len(&self) -> usize {
        3 * self.turns * self.samples_per_turn
    }

    /// Whether a run has no samples.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The attitudes (sensor to navigation frame) of one run, in order.
    pub fn attitudes(&self) -> Vec<Matrix3<f64>> {
        let per_axis = self.turns * self.samples_per_turn;
        let step = std::f64::consts::TAU / self.samples_per_turn as f64;
        [Vector3::x_axis(), Vector3::y_axis(), Vector3::z_axis()]
            .iter()
            .flat_map(|axis| {
                (0..per_axis)
                    .map(move |k| Rotation3::from_axis_angle(axis, step * k as f64).into_inner())
            })
            .collect()
    }

    /// The level turns (about z) within a run.
    pub fn level_range(&self) -> std::ops::Range<usize> {
        let per_axis = self.turns * self.samples_per_turn;
        2 * per_axis..3 * per_axis
    }

    /// The noise-free reading for attitude `r` (before quantisation).
    pub fn ideal_reading(&self, r: &Matrix3<f64>) -> Vector3<f64> {
        self.coupling * (r.transpose() * Vector3::from(self.field)) + Vector3::from(self.bias)
    }

    /// Run number `run` (deterministic).
    pub fn generate(&self, run: usize) -> HeadingRun {
        let mut rng = Rng(run_seed(HEADING_SCENARIO_INDEX, run));
        let sd = self.noise_std();
        let f = Vector3::from(self.field);
        let mut samples = Vec::with_capacity(self.len());
        let mut true_dirs = Vec::with_capacity(self.len());
        for r in self.attitudes() {
            let body = r.transpose() * f;
            let y = self.coupling * body
                + Vector3::from(self.bias)
                + Vector3::new(
                    sd[0] * rng.normal(),
                    sd[1] * rng.normal(),
                    sd[2] * rng.normal(),
                );
            let q = y.map(|v| {
                ((v / self.resolution).round() * self.resolution).clamp(-self.range, self.range)
            });
            samples.push([q.x, q.y, q.z]);
            true_dirs.push(body.normalize());
        }
        HeadingRun {
            samples,
            true_dirs,
            level: self.level_range(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_are_reproducible_and_distinct() {
        let truth = Truth::paper();
        let a = SCENARIOS[1].generate(&truth, 3);
        assert_eq!(a, SCENARIOS[1].generate(&truth, 3));
        assert_ne!(a.samples, SCENARIOS[1].generate(&truth, 4).samples);
        assert_ne!(a.samples, SCENARIOS[0].generate(&truth, 3).samples);
        assert_eq!(a.samples.len(), N_SAMPLES);
    }

    #[test]
    fn band_stays_in_band() {
        let run = SCENARIOS[2].generate(&Truth::paper(), 0);
        let zmax = BAND_DEG.to_radians().sin() + 1e-12;
        assert!(run.dirs.iter().all(|h| h.z.abs() <= zmax));
    }

    #[test]
    fn heading_scenario_geometry() {
        let h = HeadingScenario::paper();
        let sd = h.noise_std();
        assert!((sd[0] - 0.15 * (1.0f64 / 0.03).sqrt()).abs() < 1e-12);
        let run = h.generate(0);
        assert_eq!(run.samples.len(), 3600);
        assert_eq!(run.level, 2400..3600);
        // Level turns: the true field keeps its vertical component.
        let f = Vector3::from(h.field).normalize();
        assert!(run.true_dirs[run.level.clone()]
            .iter()
            .all(|d| (d.z - f.z).abs() < 1e-12));
        // Quantised to the resolution.
        assert!(run
            .samples
            .iter()
            .flatten()
            .all(|v| (v / 0.0625).fract() == 0.0));
    }
}
