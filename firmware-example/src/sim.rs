//! The physics of a simulated, distorted three-axis magnetometer.
//!
//! Pure `no_std` + `libm` with no embedded dependency, so that host tests can
//! reuse it as is. [`crate::sim_sensor`] wraps it in a register-level
//! LSM303AGR for the QEMU build.
//!
//! # Model
//!
//! A reading, in sensor counts (1 count = 1.5 mG = 150 nT), is
//!
//! ```text
//! y = round(F T h + b + e),   e ~ N(0, sigma^2 I)
//! ```
//!
//! - `h`: unit direction of the Earth's field in the sensor (body) frame,
//!   given by the motion (below);
//! - `F`: field strength in counts (48 uT = 320 counts);
//! - `T`: soft-iron matrix, dimensionless, `V diag(0.8, 1.0, 1.25) V^T` with
//!   `V` a rotation, so the distortion is not aligned with the sensor axes and
//!   `det T = 1` (so the true `rho = |det F T|^(1/3) = F`);
//! - `b`: hard-iron offset, counts;
//! - `e`: per-axis Gaussian noise (SplitMix64 + Box-Muller), then rounding
//!   to `i16` counts.
//!
//! `T` is symmetric positive definite on purpose. A calibration only
//! determines `M = W^T W` (any rotation of the calibrated frame fits equally
//! well) and the core returns `W` in the canonical symmetric form
//! `M^(1/2)`. For a symmetric positive definite `T`, `W_true = (F T)^-1` is
//! already canonical, so the calibrated frame *is* the sensor frame and the
//! calibrated heading can be compared with the true heading directly. A
//! non-symmetric `T = Q P` (polar form) would rotate the calibrated frame by
//! `Q`, which only an alignment step (planned in the core) can undo.
//!
//! # Motion
//!
//! The frame convention is NED: Earth field `F (cos dip, 0, sin dip)`
//! (north, east, down); body axes x forward, y right, z down.
//!
//! - [`Motion::Sweep`]: the sensor first lies still for `still_samples`
//!   samples (at the direction the spiral starts from: a user who starts
//!   the collection, then picks the device up), then is tumbled so that `h`
//!   follows a spherical spiral from `+z` to `-z` (Saff and Kuijlaars'
//!   generalised spiral) over `sweep_samples` samples, consecutive samples
//!   about 8 deg apart; then back up, and so on. It covers the sphere
//!   evenly, which is what a careful user turning the device in all
//!   directions achieves. Only the body-frame direction of the field is
//!   observable by a magnetometer, so the motion is specified by it.
//! - [`Motion::LevelTurn`]: a compass swing. The sensor is level and stops at
//!   `stops` headings `psi_j = offset + j 360 / stops` for `dwell` samples
//!   each; then `h = (cos dip cos psi, -cos dip sin psi, sin dip)` and the
//!   level heading is `atan2(-h_y, h_x) = psi`.
//!
//! # Faults
//!
//! A [`Scenario`] carries a [`Faults`] schedule ([`Faults::NONE`] in the
//! clean run, [`Faults::RUN`] in the fault run). The physics here decides
//! *when* a sample is faulty and adds the field of the physical faults:
//!
//! - saturation: a strong field (beyond the +-49 G range) for a few
//!   samples; every reading is clipped at +-32767 counts, as the
//!   sensor's 16-bit output is;
//! - disturbance: a magnet passing, a field added with the profile
//!   `peak sin^2(pi (t + 1/2) / len)` over the `len` samples of its window
//!   (smooth rise and fall, like a dipole approaching and leaving);
//! - stuck output: only marked here ([`Injected::stuck`]); the register
//!   model ([`crate::sim_sensor`]) then leaves the output registers
//!   unchanged while STATUS still reports new data;
//! - glitches (collections only, [`Glitches`]): isolated readings that
//!   the fault monitor's episode tests (repeats, rails, the norm against a
//!   reference) cannot see: a few *wild* readings (thousands of counts
//!   off, inside the range) among the first readings of a collection,
//!   before the disturbance test has a reference, and *displaced* readings
//!   (a fixed share of the field added in a pseudo-random direction)
//!   throughout the sweep, too small for the disturbance threshold. They
//!   are marked ([`Injected::glitch`]) but are no fault in the sense of
//!   [`Injected::any`]: they may reach the collector, and the fault run
//!   checks that the calibration did not use them, not that they never
//!   arrived. (The firmware drops the wild ones with a reference-free test
//!   of its own, because the core's collector cannot take them; the
//!   displaced ones are the core's to leave out.)
//!
//! I2C NACK bursts are purely a bus matter and live in the register model.
//! The windows count samples from the start of a motion phase (of a
//! collection: from the end of its still start), so every
//! collection (a [`Motion::Sweep`]) and every compass swing
//! ([`Motion::LevelTurn`]) meets the same faults. Each reading says which
//! faults it carries ([`Reading::injected`]), and the simulator counts the
//! episodes (and glitches) it injected ([`Simulator::injected`]), so the
//! fault run can check the firmware against the truth. The displacements'
//! pseudo-random directions come from their own hash of the seed and the
//! sample, not from the noise generator, so the noise of every reading is
//! the same with and without glitches.

use core::f64::consts::PI;

/// Magnetometer sensitivity of the LSM303AGR: nanotesla per count.
pub const NT_PER_COUNT: f64 = 150.0;

/// The fixed parameters of a simulation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scenario {
    /// Earth field strength, nT.
    pub field_nt: f64,
    /// Inclination (dip) of the field below the horizon, degrees.
    pub dip_deg: f64,
    /// Singular values of the soft-iron matrix `T` (dimensionless).
    pub soft_iron_singular_values: [f64; 3],
    /// Rotation of `T`'s principal axes: Euler angles z-y-x, degrees.
    pub soft_iron_axes_deg: [f64; 3],
    /// Hard-iron offset, counts.
    pub hard_iron: [f64; 3],
    /// Standard deviation of the per-axis noise, counts.
    pub noise: f64,
    /// Samples of one pole-to-pole pass of the sweep.
    pub sweep_samples: u32,
    /// Samples the sensor lies still at the start of a sweep, before it
    /// turns.
    pub still_samples: u32,
    /// PRNG seed.
    pub seed: u64,
    /// Faults to inject ([`Faults::NONE`]: a clean sensor).
    pub faults: Faults,
}

impl Scenario {
    /// The scenario of the firmware example: a mid-latitude field (48 uT,
    /// dip 60 deg), a tilted soft iron of +-25 %, a hard iron of a few hundred
    /// counts, and 2.5 counts of noise (the LSM303AGR's datasheet RMS noise
    /// is about 1.5-3 mG, i.e. 1-2 counts, so this is on the pessimistic
    /// side).
    pub const DEFAULT: Scenario = Scenario {
        field_nt: 48_000.0,
        dip_deg: 60.0,
        soft_iron_singular_values: [0.8, 1.0, 1.25],
        soft_iron_axes_deg: [35.0, -20.0, 50.0],
        hard_iron: [180.0, -95.0, 240.0],
        noise: 2.5,
        sweep_samples: 600,
        still_samples: 0,
        seed: 0x6d61_672d_6361_6c21,
        faults: Faults::NONE,
    };
}

/// A stretch of consecutive samples of a motion phase: the samples
/// `start..start + len`, counted from the start of the phase (0 is the
/// first sample after [`Simulator::set_motion`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Window {
    /// First sample of the stretch.
    pub start: u32,
    /// Samples in the stretch.
    pub len: u32,
}

impl Window {
    /// Position of sample `k` in the window, if it is in it.
    pub fn position(&self, k: u32) -> Option<u32> {
        k.checked_sub(self.start).filter(|&t| t < self.len)
    }
}

/// The faults of one motion phase (`None`: not injected).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PhaseFaults {
    /// Output registers frozen (see [`crate::sim_sensor`]).
    pub stuck: Option<Window>,
    /// A field beyond the range: the output clips at +-32767.
    pub saturation: Option<Window>,
    /// A magnet passing.
    pub disturbance: Option<Window>,
}

impl PhaseFaults {
    /// No fault.
    pub const NONE: PhaseFaults = PhaseFaults {
        stuck: None,
        saturation: None,
        disturbance: None,
    };
}

/// A wild reading: an offset added to one sample of a collection.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WildGlitch {
    /// The sample of the phase (counted as in [`Window`]).
    pub sample: u32,
    /// Added to the reading, counts (the result stays inside +-32767, so
    /// neither the monitor's rail test nor the core's rails rule sees it).
    pub offset: [f64; 3],
}

/// Isolated glitches of a collection that the fault monitor's episode
/// tests cannot see (see the module documentation). A glitch is injected only into a sample
/// that carries no fault of its phase's windows (it is isolated).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Glitches {
    /// Wild readings.
    pub wild: &'static [WildGlitch],
    /// Every `displaced_every`-th sample of the phase, from
    /// `displaced_first` on, is displaced (0: none).
    pub displaced_every: u32,
    /// The first displaced sample.
    pub displaced_first: u32,
    /// Size of a displacement, in units of the field strength `F`
    /// ([`Scenario::field_nt`] in counts), in a direction drawn uniformly
    /// on the sphere.
    pub displaced_share: f64,
}

impl Glitches {
    /// No glitch.
    pub const NONE: Glitches = Glitches {
        wild: &[],
        displaced_every: 0,
        displaced_first: 0,
        displaced_share: 0.0,
    };
}

/// Sensor faults to inject.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Faults {
    /// I2C NACK bursts: after every `nack_every` bus transactions answered,
    /// the next transactions are NACKed (0: never). Implemented by the
    /// register model.
    pub nack_every: u32,
    /// Bursts NACK 1, 2, .., `nack_burst_max` consecutive transactions in
    /// turn.
    pub nack_burst_max: u32,
    /// Faults during a [`Motion::Sweep`] (each collection).
    pub sweep: PhaseFaults,
    /// Faults during a [`Motion::LevelTurn`] (each compass swing).
    pub level_turn: PhaseFaults,
    /// Field added during a saturation window, counts.
    pub saturation_field: [f64; 3],
    /// Peak field of a disturbance, counts.
    pub disturbance_peak: [f64; 3],
    /// Glitches during a [`Motion::Sweep`] (each collection).
    pub sweep_glitches: Glitches,
}

impl Faults {
    /// A clean sensor.
    pub const NONE: Faults = Faults {
        nack_every: 0,
        nack_burst_max: 0,
        sweep: PhaseFaults::NONE,
        level_turn: PhaseFaults::NONE,
        saturation_field: [0.0; 3],
        disturbance_peak: [0.0; 3],
        sweep_glitches: Glitches::NONE,
    };

    /// The fault run (`--features qemu,faults`): every class, in every
    /// collection and every compass swing.
    ///
    /// - NACK bursts of 1 to 4 transactions after every 997 answered (a
    ///   prime, so the bursts hit status polls, output reads and
    ///   configuration writes alike; about 6 transactions a sample at
    ///   20 Hz, so a burst every 8 s or so);
    /// - stuck output for 25 samples (1.25 s) of each collection and 20 of
    ///   each swing;
    /// - saturation for 6 samples: 45000 counts (6.8 mT, a magnet touching
    ///   the board) on x, beyond the +-32767 rail;
    /// - a magnet passing within a few cm: peak 1500 counts (225 uT, about
    ///   5 times the Earth's field) over 40 samples (2 s) of a collection
    ///   and 30 of a swing;
    /// - glitches in each collection, which the monitor's episode tests
    ///   cannot see (the firmware drops the wild ones with a test of its
    ///   own):
    ///   - 3 wild readings, at samples 4, 11 and 19, before the firmware's
    ///     disturbance test arms (once the collector holds
    ///     `faults::ARM_SAMPLES` = 30 samples: after sample 85 or so, the
    ///     spiral starting slowly near the pole and the quarantine
    ///     delaying every reading by `faults::GUARD` = 10): 2400-3200
    ///     counts added on one to three axes, 7-10 times the field, far
    ///     from the rails;
    ///   - every 25th sample from sample 112 on displaced by 0.3 of the
    ///     field (96 counts) in a pseudo-random direction: at most 0.3 on
    ///     the monitor's statistic, whose clean spread on this soft iron
    ///     is up to 0.22 (0.30 early in a collection), so with the 0.5
    ///     threshold almost all pass (measured on the host, 1000 seeds:
    ///     0.85 % of them reach 0.50-0.57, where the long and short axes
    ///     of the soft iron meet an outward or inward displacement; the
    ///     monitor then takes one for a disturbance); about 20 of them in
    ///     a collection. Not earlier: the monitor's reference (the
    ///     collector's running centre) arms on a cap of 30 samples, on
    ///     which one displaced sample moves it so far that clean readings
    ///     cross the threshold (from sample 12 on: 347 clean readings
    ///     flagged over 1000 seeds, up to 0.72; from 112 on: none, at most
    ///     0.31, the clean spread).
    ///
    /// The windows do not overlap and lie well inside the phases: a
    /// collection takes 600-700 samples, a swing 550.
    pub const RUN: Faults = Faults {
        nack_every: 997,
        nack_burst_max: 4,
        sweep: PhaseFaults {
            stuck: Some(Window { start: 60, len: 25 }),
            saturation: Some(Window { start: 130, len: 6 }),
            disturbance: Some(Window {
                start: 200,
                len: 40,
            }),
        },
        level_turn: PhaseFaults {
            stuck: Some(Window {
                start: 100,
                len: 20,
            }),
            saturation: Some(Window { start: 250, len: 6 }),
            disturbance: Some(Window {
                start: 380,
                len: 30,
            }),
        },
        saturation_field: [45_000.0, 0.0, -4_000.0],
        disturbance_peak: [900.0, -720.0, 960.0],
        sweep_glitches: Glitches {
            wild: &[
                WildGlitch {
                    sample: 4,
                    offset: [2_400.0, 0.0, 0.0],
                },
                WildGlitch {
                    sample: 11,
                    offset: [0.0, -2_000.0, 1_600.0],
                },
                WildGlitch {
                    sample: 19,
                    offset: [-1_800.0, 1_500.0, -2_200.0],
                },
            ],
            displaced_every: 25,
            displaced_first: 112,
            displaced_share: 0.3,
        },
    };
}

/// A glitch of a collection ([`Glitches`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Glitch {
    /// A wild reading: thousands of counts off.
    Wild,
    /// A moderate displacement, below the monitor's threshold.
    Displaced,
}

/// The faults a sample carries.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Injected {
    /// The output registers were not updated with this sample.
    pub stuck: bool,
    /// A field beyond the range was added.
    pub saturated: bool,
    /// A disturbance field was added.
    pub disturbed: bool,
    /// A glitch was added: not a fault for [`Injected::any`] (it may reach
    /// the collector, and the core is to leave it out).
    pub glitch: Option<Glitch>,
}

impl Injected {
    /// Whether any fault the monitor must keep out is present (stuck,
    /// saturated, disturbed; not a glitch).
    pub fn any(&self) -> bool {
        self.stuck || self.saturated || self.disturbed
    }
}

/// Fault episodes (and glitches) injected so far, per class.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct InjectedCounts {
    /// NACK bursts (counted by the register model).
    pub nack: u32,
    /// Stuck-output windows.
    pub stuck: u32,
    /// Saturation windows.
    pub saturated: u32,
    /// Disturbance windows.
    pub disturbance: u32,
    /// Wild readings ([`Glitch::Wild`]).
    pub wild: u32,
    /// Displaced readings ([`Glitch::Displaced`]).
    pub displaced: u32,
}

/// What the simulated sensor is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Motion {
    /// Tumbling: the field direction follows a spiral over the sphere.
    Sweep,
    /// Level, stopping at `stops` evenly spaced headings for `dwell` samples.
    LevelTurn {
        /// Number of headings in a full turn.
        stops: u32,
        /// Samples at each heading.
        dwell: u32,
        /// Heading of the first stop, degrees.
        offset_deg: u32,
    },
    /// Ordinary use, no calibration dance: the heading walks and turns now
    /// and then, roll and pitch wander about level (about 12 deg), and
    /// about every 600 samples the device is tilted by 30-80 deg for a few
    /// hundred samples (picked up, put on its side); never a full tumble.
    OrdinaryUse,
}

/// The state of [`Motion::OrdinaryUse`]: attitude, tilt episode, turn rate.
#[derive(Clone, Debug)]
struct Walk {
    rng: Gaussian,
    psi: f64,
    theta: f64,
    phi: f64,
    target_theta: f64,
    target_phi: f64,
    episode: u32,
    turn: f64,
}

impl Walk {
    fn new(seed: u64) -> Self {
        Self {
            rng: Gaussian::new(seed ^ 0x5741_4c4b),
            psi: 0.0,
            theta: 0.0,
            phi: 0.0,
            target_theta: 0.0,
            target_phi: 0.0,
            episode: 0,
            turn: 0.0,
        }
    }

    /// The next attitude; the field direction in the body frame and the
    /// heading, degrees.
    fn next(&mut self, dip_deg: f64) -> ([f64; 3], f64) {
        let u = self.rng.rng.uniform();
        if self.episode == 0 && u < 1.0 / 600.0 {
            self.episode = 150 + (self.rng.rng.uniform() * 300.0) as u32;
            let tilt = (30.0 + 50.0 * self.rng.rng.uniform()).to_radians();
            let (s, c) = libm::sincos(2.0 * PI * self.rng.rng.uniform());
            self.target_theta = tilt * c;
            self.target_phi = tilt * s;
        }
        if self.episode > 0 {
            self.episode -= 1;
            if self.episode == 0 {
                self.target_theta = 0.0;
                self.target_phi = 0.0;
            }
        }
        if self.rng.rng.uniform() < 1.0 / 200.0 {
            self.turn = self.rng.sample() * 0.03;
        }
        self.psi += self.turn + self.rng.sample() * 0.01;
        self.theta += 0.02 * (self.target_theta - self.theta) + self.rng.sample() * 0.012;
        self.phi += 0.02 * (self.target_phi - self.phi) + self.rng.sample() * 0.012;
        // h = R^T f with R = Rz(psi) Ry(theta) Rx(phi) (body to NED).
        let (sd, cd) = libm::sincos(dip_deg.to_radians());
        let r = rotation_zyx([self.psi, self.theta, self.phi].map(f64::to_degrees));
        let f = [cd, 0.0, sd];
        let h = [0, 1, 2].map(|j| (0..3).map(|i| r[i][j] * f[i]).sum::<f64>());
        let d = libm::fmod(self.psi.to_degrees(), 360.0);
        let heading = if d < 0.0 { d + 360.0 } else { d };
        (h, heading)
    }
}

/// One simulated sample and its truth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reading {
    /// The quantised reading, counts.
    pub counts: [i16; 3],
    /// The true unit field direction in the sensor frame.
    pub direction: [f64; 3],
    /// The true level heading `atan2(-h_y, h_x)` in degrees, `[0, 360)`
    /// (meaningful during [`Motion::LevelTurn`]).
    pub heading_deg: f64,
    /// The faults injected into this sample.
    pub injected: Injected,
}

/// SplitMix64 (Steele, Lea, Flood 2014): a tiny, seedable, well-mixed PRNG.
#[derive(Clone, Debug)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A generator with the given seed.
    pub const fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `(0, 1]` (never 0, so its logarithm is finite).
    pub fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) + 1) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// Standard normal deviates by the Box-Muller transform.
#[derive(Clone, Debug)]
pub struct Gaussian {
    rng: SplitMix64,
    spare: Option<f64>,
}

impl Gaussian {
    /// A generator with the given seed.
    pub const fn new(seed: u64) -> Self {
        Self {
            rng: SplitMix64::new(seed),
            spare: None,
        }
    }

    /// The next `N(0, 1)` deviate.
    pub fn sample(&mut self) -> f64 {
        if let Some(z) = self.spare.take() {
            return z;
        }
        let r = libm::sqrt(-2.0 * libm::log(self.rng.uniform()));
        let phi = 2.0 * PI * self.rng.uniform();
        self.spare = Some(r * libm::sin(phi));
        r * libm::cos(phi)
    }
}

type Mat3 = [[f64; 3]; 3];

fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut c = [[0.0; 3]; 3];
    for (i, row) in c.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

fn mat_vec(a: &Mat3, v: &[f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| a[i][0] * v[0] + a[i][1] * v[1] + a[i][2] * v[2])
}

/// Rotation `R_z(yaw) R_y(pitch) R_x(roll)`, angles in degrees.
fn rotation_zyx(deg: [f64; 3]) -> Mat3 {
    let [(sz, cz), (sy, cy), (sx, cx)] = deg.map(|d| libm::sincos(d.to_radians()));
    let rz = [[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]];
    let ry = [[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]];
    let rx = [[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]];
    mat_mul(&rz, &mat_mul(&ry, &rx))
}

/// The simulated magnetometer: truth, motion and noise.
#[derive(Clone, Debug)]
pub struct Simulator {
    scenario: Scenario,
    /// `F T`, counts.
    soft_iron: Mat3,
    noise: Gaussian,
    motion: Motion,
    /// Samples since the motion was set.
    step: u32,
    /// Longitude of the sweep spiral, radians.
    spiral_phi: f64,
    /// Fault episodes injected.
    injected: InjectedCounts,
    /// The attitude of [`Motion::OrdinaryUse`].
    walk: Walk,
}

impl Simulator {
    /// A simulator of `scenario`, starting with [`Motion::Sweep`].
    pub fn new(scenario: Scenario) -> Self {
        let v = rotation_zyx(scenario.soft_iron_axes_deg);
        let f = scenario.field_nt / NT_PER_COUNT;
        let s = scenario.soft_iron_singular_values;
        // F V diag(s) V^T
        let mut t = [[0.0; 3]; 3];
        for (i, row) in t.iter_mut().enumerate() {
            for (j, x) in row.iter_mut().enumerate() {
                *x = f * (0..3).map(|k| v[i][k] * s[k] * v[j][k]).sum::<f64>();
            }
        }
        Self {
            scenario,
            soft_iron: t,
            noise: Gaussian::new(scenario.seed),
            motion: Motion::Sweep,
            step: 0,
            spiral_phi: 0.0,
            injected: InjectedCounts::default(),
            walk: Walk::new(scenario.seed),
        }
    }

    /// The scenario.
    pub fn scenario(&self) -> &Scenario {
        &self.scenario
    }

    /// The true soft-iron matrix `F T` in counts (symmetric positive
    /// definite): `y = F T h + b`. Its inverse is the true canonical `W`.
    pub fn soft_iron(&self) -> Mat3 {
        self.soft_iron
    }

    /// The true hard-iron offset `b`, counts.
    pub fn hard_iron(&self) -> [f64; 3] {
        self.scenario.hard_iron
    }

    /// The true field strength `rho = |det(F T)|^(1/3)`, counts.
    pub fn field_strength(&self) -> f64 {
        let t = &self.soft_iron;
        let det = t[0][0] * (t[1][1] * t[2][2] - t[1][2] * t[2][1])
            - t[0][1] * (t[1][0] * t[2][2] - t[1][2] * t[2][0])
            + t[0][2] * (t[1][0] * t[2][1] - t[1][1] * t[2][0]);
        libm::cbrt(libm::fabs(det))
    }

    /// Moves the hard iron to `b`, counts (a part got magnetised).
    pub fn set_hard_iron(&mut self, b: [f64; 3]) {
        self.scenario.hard_iron = b;
    }

    /// Changes the motion; its schedule restarts.
    pub fn set_motion(&mut self, motion: Motion) {
        self.motion = motion;
        self.step = 0;
        self.spiral_phi = 0.0;
    }

    /// Sample `k` of the current phase counted as its faults are: during a
    /// sweep, from the end of its still start (`None` before it).
    fn moving_sample(&self, k: u32) -> Option<u32> {
        match self.motion {
            Motion::Sweep => k.checked_sub(self.scenario.still_samples),
            Motion::LevelTurn { .. } | Motion::OrdinaryUse => Some(k),
        }
    }

    /// The true field direction and heading (degrees) of the next sample.
    fn next_direction(&mut self) -> ([f64; 3], f64) {
        let Some(step) = self.moving_sample(self.step) else {
            // Lying still where the spiral starts (the direction of its
            // first sample, without advancing it).
            self.step = self.step.wrapping_add(1);
            let n = self.scenario.sweep_samples.max(2);
            let z = 1.0 - 1.0 / f64::from(n);
            let r = libm::sqrt(1.0 - z * z);
            let (s, c) = libm::sincos(3.6 / libm::sqrt(f64::from(n)) / r);
            let h = [r * c, r * s, z];
            return (h, heading_deg(&h));
        };
        self.step = self.step.wrapping_add(1);
        match self.motion {
            Motion::Sweep => {
                let n = self.scenario.sweep_samples.max(2);
                let k = step % n;
                // Odd passes run back up, so the path stays continuous.
                let down = (step / n).is_multiple_of(2);
                let z = 1.0 - (2.0 * f64::from(k) + 1.0) / f64::from(n);
                let z = if down { z } else { -z };
                let r = libm::sqrt(1.0 - z * z);
                // Generalised spiral: longitude step 3.6 / sqrt(n) / r gives an
                // even spacing of about 3.6 / sqrt(n) rad along and across.
                self.spiral_phi =
                    (self.spiral_phi + 3.6 / libm::sqrt(f64::from(n)) / r) % (2.0 * PI);
                let (s, c) = libm::sincos(self.spiral_phi);
                let h = [r * c, r * s, z];
                (h, heading_deg(&h))
            }
            Motion::LevelTurn {
                stops,
                dwell,
                offset_deg,
            } => {
                let stop = (step / dwell.max(1)) % stops.max(1);
                let psi = (f64::from(offset_deg)
                    + f64::from(stop) * 360.0 / f64::from(stops.max(1)))
                    % 360.0;
                let (sd, cd) = libm::sincos(self.scenario.dip_deg.to_radians());
                let (sp, cp) = libm::sincos(psi.to_radians());
                ([cd * cp, -cd * sp, sd], psi)
            }
            Motion::OrdinaryUse => self.walk.next(self.scenario.dip_deg),
        }
    }

    /// Fault episodes injected so far (stuck, saturation, disturbance; the
    /// NACK count is the register model's) and glitches.
    pub fn injected(&self) -> InjectedCounts {
        self.injected
    }

    /// The glitch of sample `k` of a collection, if any, and the field it
    /// adds, counts; counts it.
    fn glitch_at(&mut self, k: u32) -> Option<(Glitch, [f64; 3])> {
        let g = self.scenario.faults.sweep_glitches;
        if let Some(w) = g.wild.iter().find(|w| w.sample == k) {
            self.injected.wild += 1;
            return Some((Glitch::Wild, w.offset));
        }
        let displaced = g.displaced_every > 0
            && k.checked_sub(g.displaced_first)
                .is_some_and(|t| t.is_multiple_of(g.displaced_every));
        if !displaced {
            return None;
        }
        self.injected.displaced += 1;
        // A direction uniform on the sphere from a hash of the seed and the
        // sample (not from the noise generator).
        let mut rng =
            SplitMix64::new(self.scenario.seed ^ u64::from(k).wrapping_mul(0xd1b5_4a32_d192_ed03));
        let z = 2.0 * rng.uniform() - 1.0;
        let r = libm::sqrt(libm::fmax(0.0, 1.0 - z * z));
        let (s, c) = libm::sincos(2.0 * PI * rng.uniform());
        let size = g.displaced_share * self.scenario.field_nt / NT_PER_COUNT;
        Some((Glitch::Displaced, [size * r * c, size * r * s, size * z]))
    }

    /// The faults of sample `k` of the current phase and the field they add,
    /// counts; counts a window's episode at its first sample.
    fn faults_at(&mut self, k: u32) -> (Injected, [f64; 3]) {
        let f = &self.scenario.faults;
        let phase = match self.motion {
            Motion::Sweep => &f.sweep,
            Motion::LevelTurn { .. } | Motion::OrdinaryUse => &f.level_turn,
        };
        let mut injected = Injected::default();
        let mut field = [0.0; 3];
        if let Some(t) = phase.stuck.and_then(|w| w.position(k)) {
            injected.stuck = true;
            self.injected.stuck += u32::from(t == 0);
        }
        if let Some(t) = phase.saturation.and_then(|w| w.position(k)) {
            injected.saturated = true;
            self.injected.saturated += u32::from(t == 0);
            field = f.saturation_field;
        }
        if let Some((t, w)) = phase
            .disturbance
            .and_then(|w| w.position(k).map(|t| (t, w)))
        {
            injected.disturbed = true;
            self.injected.disturbance += u32::from(t == 0);
            let s = libm::sin(PI * (f64::from(t) + 0.5) / f64::from(w.len));
            for (a, p) in field.iter_mut().zip(f.disturbance_peak) {
                *a += p * s * s;
            }
        }
        // Glitches: collections only, and only on samples free of faults.
        if matches!(self.motion, Motion::Sweep) && !injected.any() {
            if let Some((glitch, extra)) = self.glitch_at(k) {
                injected.glitch = Some(glitch);
                field = extra;
            }
        }
        (injected, field)
    }

    /// The next sample.
    pub fn next_reading(&mut self) -> Reading {
        let k = self.moving_sample(self.step);
        let (h, heading_deg) = self.next_direction();
        // No fault while a sweep's sensor lies still.
        let (injected, extra) = match k {
            Some(k) => self.faults_at(k),
            None => (Injected::default(), [0.0; 3]),
        };
        let th = mat_vec(&self.soft_iron, &h);
        let b = self.scenario.hard_iron;
        let mut counts = [0i16; 3];
        for (i, c) in counts.iter_mut().enumerate() {
            let y = th[i] + b[i] + extra[i] + self.scenario.noise * self.noise.sample();
            // The sensor's output clips at +-32767 counts.
            *c = libm::round(y).clamp(-32767.0, 32767.0) as i16;
        }
        Reading {
            counts,
            direction: h,
            heading_deg,
            injected,
        }
    }
}

/// Level heading of a field direction in the NED body frame, degrees in
/// `[0, 360)`: `atan2(-h_y, h_x)`.
pub fn heading_deg(h: &[f64; 3]) -> f64 {
    let d = libm::atan2(-h[1], h[0]).to_degrees();
    if d < 0.0 {
        d + 360.0
    } else {
        d
    }
}
