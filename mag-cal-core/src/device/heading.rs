//! Heading from calibrated readings, tilt compensation and circular
//! smoothing.
//!
//! Conventions: the body frame has x forward, y right, z down (right-handed,
//! as NED); the heading is the angle from magnetic north to the body's x
//! axis, positive towards east, in degrees in `(-180, 180]`. The field
//! passed in is a calibrated reading (and, where the sensor axes are not the
//! body axes, aligned: [`crate::device::align`]); its scale does not matter.
//!
//! ```
//! use mag_cal_core::heading::{heading_deg, HeadingSmoother, DEFAULT_WINDOW};
//!
//! let mut smoother: HeadingSmoother<f32, DEFAULT_WINDOW> = HeadingSmoother::new();
//! let mut smoothed = None;
//! for k in 0..21 {
//!     // A level sensor at heading psi sees (H cos psi, -H sin psi, V).
//!     let psi = (179.0 + 2.0 * (k % 2) as f32).to_radians(); // 179, 181, ...
//!     let field = [0.5 * psi.cos(), -0.5 * psi.sin(), 0.87];
//!     smoothed = smoother.push(heading_deg(field));
//! }
//! // The circular mean of 179 and -179 (= 181) deg is 180, not 0; here
//! // 179.93, as the last 15 hold one more 179 than 181.
//! assert!((smoothed.unwrap() - 180.0).abs() < 0.1);
//! ```

use nalgebra::Vector3;

use crate::{Error, Real};

/// Window the paper's heading test found best among 3..67.
pub const DEFAULT_WINDOW: usize = 15;

/// Degrees per radian, rounded once from `f64` (more accurate in `f32` than
/// `180 / pi` computed in `f32`).
fn deg_per_rad<T: Real>() -> T {
    T::lit(180.0 / core::f64::consts::PI)
}

/// An angle in degrees, wrapped to `(-180, 180]`; `-180` maps to `180`.
///
/// Exact: the remainder and the one correction by 360 add no rounding. A
/// non-finite input gives NaN.
///
/// ```
/// use mag_cal_core::heading::wrap_deg;
/// assert_eq!(wrap_deg(-180.0_f64), 180.0);
/// assert_eq!(wrap_deg(540.0_f64), 180.0);
/// assert_eq!(wrap_deg(-190.0_f32), 170.0);
/// assert_eq!(wrap_deg(359.5_f32), -0.5);
/// ```
pub fn wrap_deg<T: Real>(deg: T) -> T {
    let full = T::lit(360.0);
    let half = T::lit(180.0);
    // `%` is the exact fmod: the result is in (-360, 360) with deg's sign.
    let r = deg % full;
    if r > half {
        r - full
    } else if r <= -half {
        r + full
    } else {
        r
    }
}

/// `atan2(y, x)` in degrees in `(-180, 180]`; both arguments finite and
/// not both zero. The conversion of `+-pi` may round just past 180; that is
/// clamped, and `-180` (from a `-0` numerator) becomes `180`.
pub(crate) fn atan2_deg<T: Real>(y: T, x: T) -> T {
    let half = T::lit(180.0);
    let d = y.atan2(x) * deg_per_rad::<T>();
    if d > half || d <= -half {
        half
    } else {
        d
    }
}

/// Level heading in degrees in `(-180, 180]`: `atan2(-f_y, f_x)` of a
/// calibrated (and aligned) reading `field`; magnetic north along x is 0,
/// east (the field pointing to `-y` in the body) is 90.
///
/// Only meaningful while the sensor is level; see
/// [`tilt_compensated_heading_deg`] otherwise. Never NaN: when the
/// horizontal component is zero, or `f_x` or `f_y` is not finite, the
/// heading is undefined and 0 is returned.
///
/// ```
/// use mag_cal_core::heading::heading_deg;
/// // A level sensor turned to heading psi sees (H cos psi, -H sin psi, V).
/// assert_eq!(heading_deg([0.5, 0.0, 0.8]), 0.0);
/// assert_eq!(heading_deg([0.0, -0.5, 0.8]), 90.0);
/// assert_eq!(heading_deg([-0.5, 0.0, 0.8]), 180.0);
/// assert_eq!(heading_deg([0.0, 0.5, 0.8]), -90.0);
/// assert_eq!(heading_deg([0.0, 0.0, 0.8]), 0.0);
/// ```
pub fn heading_deg<T: Real>(field: [T; 3]) -> T {
    let [x, y, _] = field;
    if !x.is_finite() || !y.is_finite() || (x == T::zero() && y == T::zero()) {
        return T::zero();
    }
    atan2_deg(-y, x)
}

/// Tilt-compensated heading in degrees in `(-180, 180]`, from a calibrated
/// (and aligned) field reading and the accelerometer's specific force at
/// rest, both in the body frame.
///
/// `accel` is what an accelerometer reads at rest: it points up (minus
/// gravity), so a level sensor with z down reads `(0, 0, -g)`; its unit
/// does not matter. With `Down = -accel / |accel|`, `East = Down x field`
/// and `North = East x Down` (normalised), the heading is
/// `atan2(East_x, North_x)`: the direction of the body's x axis in the
/// horizontal plane. For a level sensor it equals [`heading_deg`].
///
/// `None` when `accel` or `field` is zero or has a non-finite component, or
/// when they are parallel: the angle between the field and the vertical is
/// below `sqrt(eps)` rad (`2e-2` deg in `f32`), where the rounding of the
/// inputs alone could turn the result by more than that angle. The heading
/// is also ill-conditioned when the body x axis is near vertical (pitch
/// near +-90 deg); that is not refused, and an exactly vertical x axis
/// gives 0.
///
/// ```
/// use mag_cal_core::heading::tilt_compensated_heading_deg;
/// // Level, heading 90 (east): the field points to -y in the body.
/// let field = [0.0, -0.5, 0.866];
/// let h = tilt_compensated_heading_deg(field, [0.0, 0.0, -9.81]).unwrap();
/// assert!((h - 90.0_f64).abs() < 1e-12);
/// // Same attitude rolled 30 deg right (about x): both vectors turn with the body.
/// let (s, c) = (30.0_f64.to_radians().sin(), 30.0_f64.to_radians().cos());
/// let roll = |v: [f64; 3]| [v[0], c * v[1] + s * v[2], -s * v[1] + c * v[2]];
/// let h = tilt_compensated_heading_deg(roll(field), roll([0.0, 0.0, -9.81])).unwrap();
/// assert!((h - 90.0).abs() < 1e-12);
/// assert_eq!(tilt_compensated_heading_deg(field, [0.0; 3]), None);
/// ```
pub fn tilt_compensated_heading_deg<T: Real>(field: [T; 3], accel: [T; 3]) -> Option<T> {
    // Unit vectors, scaled by the largest component first so that no square
    // overflows or underflows.
    let unit = |v: [T; 3]| {
        let v = Vector3::from(v);
        let m = v.amax();
        if !v.iter().all(|c| c.is_finite()) || !(m > T::zero()) {
            return None;
        }
        let v = v / m;
        Some(v / v.norm())
    };
    let f = unit(field)?;
    let down = -unit(accel)?;
    let east = down.cross(&f);
    // |east| = sin of the angle between the field and the vertical.
    let east_norm = east.norm();
    if !(east_norm > T::EPSILON.sqrt()) {
        return None;
    }
    let east = east / east_norm;
    let north = east.cross(&down);
    if east.x == T::zero() && north.x == T::zero() {
        // Body x exactly vertical: no horizontal direction to report.
        return Some(T::zero());
    }
    Some(atan2_deg(east.x, north.x))
}

/// Moving average of headings on the circle over the last `window`
/// headings: the direction of the sum of their unit vectors
/// `(cos psi, sin psi)`, never the mean of raw degrees (which puts the mean
/// of 179 and -179 at 0 instead of 180).
///
/// The capacity `N` is a const generic: a fixed ring of `N` unit vectors
/// inline (`2 N` scalars), no heap. `N = 0` does not compile.
///
/// Each push sums the ring afresh (in chronological order) instead of
/// keeping running sums: the window is small (15 by default, 67 the largest
/// the paper studied, so at most ~130 additions against the sine, cosine and
/// arctangent each push costs anyway), a running sum with periodic re-sums
/// has the same worst-case push, and this way nothing can drift, however
/// long the run, and the result depends only on the headings in the window,
/// bit for bit.
///
/// ```
/// use mag_cal_core::heading::HeadingSmoother;
/// let mut s: HeadingSmoother<f64, 4> = HeadingSmoother::with_window(2)?;
/// assert_eq!(s.push(10.0), Some(10.0));
/// assert!((s.push(20.0).unwrap() - 15.0).abs() < 1e-12);
/// assert!((s.push(30.0).unwrap() - 25.0).abs() < 1e-12); // 10 has left the window
/// assert_eq!(s.push(f64::NAN).map(|h| (h - 25.0).abs() < 1e-12), Some(true)); // ignored
/// assert_eq!(s.len(), 2);
/// # Ok::<(), mag_cal_core::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct HeadingSmoother<T: Real, const N: usize> {
    /// Unit vectors `(cos, sin)`; slots `0..window` are used.
    ring: [(T, T); N],
    /// Headings averaged, `1..=N`.
    window: usize,
    /// Headings stored, `0..=window`.
    len: usize,
    /// Slot of the next heading, `0..window`; once the window is full it
    /// is also the oldest.
    next: usize,
}

impl<T: Real, const N: usize> HeadingSmoother<T, N> {
    /// An empty smoother over a window of `N` headings.
    ///
    /// A capacity of 0 is refused at compile time:
    /// ```compile_fail
    /// let s = mag_cal_core::heading::HeadingSmoother::<f32, 0>::new();
    /// ```
    pub fn new() -> Self {
        const { assert!(N > 0, "HeadingSmoother needs a capacity N of at least 1") };
        Self {
            ring: [(T::zero(), T::zero()); N],
            window: N,
            len: 0,
            next: 0,
        }
    }

    /// An empty smoother over a window of `window` headings, at most the
    /// capacity `N`.
    ///
    /// # Errors
    /// [`Error::OutOfRange`] unless `1 <= window <= N`.
    pub fn with_window(window: usize) -> Result<Self, Error> {
        if window == 0 || window > N {
            return Err(Error::OutOfRange);
        }
        Ok(Self {
            ring: [(T::zero(), T::zero()); N],
            window,
            len: 0,
            next: 0,
        })
    }

    /// Headings averaged once the window is full.
    pub fn window(&self) -> usize {
        self.window
    }

    /// Headings currently stored (at most [`window`](Self::window)).
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether no heading is stored.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Forgets every heading; the window stays.
    pub fn clear(&mut self) {
        self.len = 0;
        self.next = 0;
    }

    /// Adds a heading in degrees (any finite value; it is wrapped) and
    /// returns the smoothed heading, as [`mean`](Self::mean) does after it.
    ///
    /// A non-finite heading is ignored: not stored, the window unchanged.
    pub fn push(&mut self, heading_deg: T) -> Option<T> {
        if heading_deg.is_finite() && self.window > 0 {
            let rad = wrap_deg(heading_deg) / deg_per_rad::<T>();
            let (sin, cos) = rad.sin_cos();
            if let Some(slot) = self.ring.get_mut(self.next) {
                *slot = (cos, sin);
            }
            // Wrap by comparison, not `%`: no division-by-zero path.
            self.next += 1;
            if self.next >= self.window {
                self.next = 0;
            }
            self.len = (self.len + 1).min(self.window);
        }
        self.mean()
    }

    /// The circular mean of the stored headings in degrees in
    /// `(-180, 180]`, or `None` when there is none or it is undefined.
    ///
    /// Undefined means the resultant of the unit vectors is about zero (the
    /// headings cancel, e.g. 0 and 180): its length is at most
    /// `len sqrt(eps)`, where the rounding of the unit vectors could turn it
    /// by more than `sqrt(eps)` rad.
    pub fn mean(&self) -> Option<T> {
        // Chronological order: slots next..len hold the older headings once
        // the window has wrapped (and are empty before).
        let older = self.ring.get(self.next..self.len).unwrap_or(&[]);
        let newer = self.ring.get(..self.next).unwrap_or(&[]);
        let (c, s) = older
            .iter()
            .chain(newer)
            .fold((T::zero(), T::zero()), |(c, s), &(ci, si)| (c + ci, s + si));
        let bound = T::from_count(self.len) * T::EPSILON.sqrt();
        if self.len == 0 || !(c * c + s * s > bound * bound) {
            return None;
        }
        Some(atan2_deg(s, c))
    }
}

impl<T: Real, const N: usize> Default for HeadingSmoother<T, N> {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // The tests speak nalgebra; the API takes arrays.
    fn heading_deg<T: Real>(v: &Vector3<T>) -> T {
        super::heading_deg((*v).into())
    }

    fn tilt_compensated_heading_deg<T: Real>(f: &Vector3<T>, a: &Vector3<T>) -> Option<T> {
        super::tilt_compensated_heading_deg((*f).into(), (*a).into())
    }
    use nalgebra::{Matrix3, Rotation3};

    use crate::test_support::Rng;

    const RAD: f64 = core::f64::consts::PI / 180.0;

    /// Body-frame field of a level sensor at heading `psi` (degrees).
    fn level_field(psi: f64, h: f64, v: f64) -> Vector3<f64> {
        Vector3::new(h * libm::cos(psi * RAD), -h * libm::sin(psi * RAD), v)
    }

    /// `a - b` wrapped to `(-180, 180]`.
    fn angle_diff(a: f64, b: f64) -> f64 {
        wrap_deg(a - b)
    }

    fn in_range<T: Real>(deg: T) -> bool {
        deg > T::lit(-180.0) && deg <= T::lit(180.0)
    }

    #[test]
    fn wrap_deg_is_exact_and_half_open() {
        for (x, w) in [
            (0.0, 0.0),
            (180.0, 180.0),
            (-180.0, 180.0),
            (540.0, 180.0),
            (-540.0, 180.0),
            (360.0, 0.0),
            (190.0, -170.0),
            (-190.0, 170.0),
            (179.999, 179.999),
            (-179.999, -179.999),
            (3600.25, 0.25),
            (-3600.25, -0.25),
        ] {
            assert_eq!(wrap_deg(x), w, "{x}");
            assert_eq!(wrap_deg(x as f32), w as f32, "{x}");
        }
        let mut rng = Rng(3);
        for _ in 0..10_000 {
            let x = rng.range(-1e6, 1e6);
            let w = wrap_deg(x);
            assert!(in_range(w));
            // Exact: x - w is a multiple of 360.
            let turns = (x - w) / 360.0;
            assert_eq!(turns, libm::round(turns));
            assert!(in_range(wrap_deg(x as f32)));
        }
        assert!(in_range(wrap_deg(1e30_f32)) && in_range(wrap_deg(-1e300_f64)));
        assert!(wrap_deg(f64::NAN).is_nan() && wrap_deg(f32::INFINITY).is_nan());
    }

    #[test]
    fn level_heading_of_the_cardinal_directions() {
        // A level sensor turned to heading psi sees (H cos psi, -H sin psi, V).
        let (h, v) = (0.5, 0.866);
        for (psi, expected) in [
            (0.0, 0.0),
            (90.0, 90.0),
            (180.0, 180.0),
            (270.0, -90.0),
            (-90.0, -90.0),
            (45.0, 45.0),
            (-135.0, -135.0),
        ] {
            let got = heading_deg(&level_field(psi, h, v));
            assert!(libm::fabs(got - expected) < 1e-12, "{psi}: {got}");
            let got32 = heading_deg(&level_field(psi, h, v).cast::<f32>());
            assert!(libm::fabs(angle_diff(f64::from(got32), expected)) < 1e-4);
        }
        // Exact cases: north, east, south, west.
        assert_eq!(heading_deg(&Vector3::new(2.0, 0.0, -1.0)), 0.0);
        assert_eq!(heading_deg(&Vector3::new(0.0, -2.0, 1.0)), 90.0);
        assert_eq!(heading_deg(&Vector3::new(-2.0, 0.0, 1.0)), 180.0);
        assert_eq!(heading_deg(&Vector3::new(0.0, 2.0, 1.0)), -90.0);
    }

    #[test]
    fn level_heading_at_the_seam_stays_in_range() {
        // South, with either sign of zero and tiny y either side.
        for y in [0.0, -0.0, 1e-300, -1e-300, 1e-17, -1e-17] {
            let got = heading_deg(&Vector3::new(-1.0, y, 0.5));
            assert!(in_range(got), "{y}: {got}");
            assert!(libm::fabs(angle_diff(got, 180.0)) < 1e-12);
        }
        for y in [0.0f32, -0.0, 1e-40, -1e-40, 1e-8, -1e-8] {
            let got = heading_deg(&Vector3::new(-1.0f32, y, 0.5));
            assert!(in_range(got), "{y}: {got}");
        }
        assert_eq!(heading_deg(&Vector3::new(-1.0, -0.0, 0.0)), 180.0);
        assert_eq!(heading_deg(&Vector3::new(-1.0, 0.0, 0.0)), 180.0);
        // Just either side of south.
        let east_of_south = heading_deg(&level_field(179.9, 1.0, 0.0));
        let west_of_south = heading_deg(&level_field(-179.9, 1.0, 0.0));
        assert!(libm::fabs(east_of_south - 179.9) < 1e-10);
        assert!(libm::fabs(west_of_south + 179.9) < 1e-10);
        let mut rng = Rng(11);
        for _ in 0..10_000 {
            let psi = rng.range(-720.0, 720.0);
            let got = heading_deg(&level_field(psi, 1.0, 2.0));
            assert!(in_range(got));
            assert!(libm::fabs(angle_diff(got, psi)) < 1e-10);
            assert!(in_range(heading_deg(
                &level_field(psi, 1.0, 2.0).cast::<f32>()
            )));
        }
    }

    #[test]
    fn level_heading_without_a_horizontal_field_is_zero() {
        assert_eq!(heading_deg(&Vector3::new(0.0, 0.0, 1.0)), 0.0);
        assert_eq!(heading_deg(&Vector3::new(-0.0, -0.0, -1.0)), 0.0);
        assert_eq!(heading_deg(&Vector3::<f32>::zeros()), 0.0);
        assert_eq!(heading_deg(&Vector3::new(f64::NAN, 1.0, 0.0)), 0.0);
        assert_eq!(heading_deg(&Vector3::new(1.0, f32::INFINITY, 0.0)), 0.0);
        // z does not matter, even when it is not finite.
        assert_eq!(heading_deg(&Vector3::new(0.0, -1.0, f64::NAN)), 90.0);
    }

    /// Body-frame field and specific force of a sensor at attitude
    /// (roll, pitch, yaw) in degrees (ZYX: body to NED is
    /// `Rz(yaw) Ry(pitch) Rx(roll)`), in a field of dip 60 deg.
    fn body_readings(roll: f64, pitch: f64, yaw: f64) -> (Vector3<f64>, Vector3<f64>) {
        let r: Matrix3<f64> =
            *Rotation3::from_euler_angles(roll * RAD, pitch * RAD, yaw * RAD).matrix();
        let dip = 60.0 * RAD;
        let strength = 48.0; // uT: the unit does not matter
        let field_ned = Vector3::new(libm::cos(dip), 0.0, libm::sin(dip)) * strength;
        let force_ned = Vector3::new(0.0, 0.0, -9.81);
        (r.transpose() * field_ned, r.transpose() * force_ned)
    }

    #[test]
    fn tilt_compensation_recovers_yaw() {
        let mut rng = Rng(0x1234_5678);
        for _ in 0..10_000 {
            let roll = rng.range(-180.0, 180.0);
            let pitch = rng.range(-80.0, 80.0);
            let yaw = rng.range(-180.0, 180.0);
            let (field, accel) = body_readings(roll, pitch, yaw);
            let got = tilt_compensated_heading_deg(&field, &accel).unwrap();
            assert!(in_range(got));
            let err = angle_diff(got, yaw);
            assert!(libm::fabs(err) < 1e-9, "{roll} {pitch} {yaw}: {err:e}");

            let got32 =
                tilt_compensated_heading_deg(&field.cast::<f32>(), &accel.cast::<f32>()).unwrap();
            assert!(in_range(got32));
            let err32 = angle_diff(f64::from(got32), yaw);
            // f32 rounding, amplified by 1 / cos(pitch) at 80 deg.
            assert!(libm::fabs(err32) < 2e-3, "{roll} {pitch} {yaw}: {err32:e}");
        }
    }

    #[test]
    fn tilt_compensation_of_a_level_sensor_is_the_level_heading() {
        let mut rng = Rng(5);
        for _ in 0..1000 {
            let psi = rng.range(-180.0, 180.0);
            let field = level_field(psi, 0.3, 0.45);
            let level = Vector3::new(0.0, 0.0, -9.81);
            let tilt = tilt_compensated_heading_deg(&field, &level).unwrap();
            assert!(libm::fabs(angle_diff(tilt, heading_deg(&field))) < 1e-12);
            // Same through the attitude helper, at zero roll and pitch.
            let (f, a) = body_readings(0.0, 0.0, psi);
            assert!(
                libm::fabs(angle_diff(
                    tilt_compensated_heading_deg(&f, &a).unwrap(),
                    psi
                )) < 1e-9
            );
        }
        assert_eq!(
            tilt_compensated_heading_deg(
                &Vector3::new(-0.5, 0.0, 0.8),
                &Vector3::new(0.0, 0.0, -1.0)
            ),
            Some(180.0)
        );
    }

    #[test]
    fn tilt_compensation_refuses_degenerate_input() {
        let field = Vector3::new(0.2, -0.1, 0.4);
        let up = Vector3::new(0.0, 0.0, -9.81);
        let none = |f: Vector3<f64>, a: Vector3<f64>| tilt_compensated_heading_deg(&f, &a);
        assert_eq!(none(field, Vector3::zeros()), None);
        assert_eq!(none(Vector3::zeros(), up), None);
        assert_eq!(none(Vector3::new(f64::NAN, 0.0, 1.0), up), None);
        assert_eq!(none(field, Vector3::new(0.0, f64::INFINITY, -1.0)), None);
        // Field along gravity (at a magnetic pole), either way round.
        assert_eq!(none(Vector3::new(0.0, 0.0, 0.5), up), None);
        assert_eq!(none(Vector3::new(0.0, 0.0, -0.5), up), None);
        // Tilted, still parallel (to rounding).
        let (f, a) = body_readings(10.0, 20.0, 30.0);
        assert_eq!(none(-a * 3.0, a), None);
        assert!(none(f, a).is_some());
        let f32_none = tilt_compensated_heading_deg(
            &Vector3::new(1e-4f32, 0.0, 1.0),
            &Vector3::new(0.0f32, 0.0, -1.0),
        );
        assert_eq!(f32_none, None);
        // Extreme but finite magnitudes work.
        let big = tilt_compensated_heading_deg(
            &(level_field(30.0, 0.5, 0.8).cast::<f32>() * 1e35),
            &Vector3::new(0.0f32, 0.0, -1e-35),
        )
        .unwrap();
        assert!(libm::fabsf(big - 30.0) < 1e-3);
    }

    /// Circular mean (degrees) of a slice, in f64, straight from the definition.
    fn reference_mean(headings: &[f32]) -> f64 {
        let (c, s) = headings.iter().fold((0.0, 0.0), |(c, s), &h| {
            let r = f64::from(h) * RAD;
            (c + libm::cos(r), s + libm::sin(r))
        });
        libm::atan2(s, c) / RAD
    }

    #[test]
    fn smoother_averages_across_the_seam() {
        let mut s: HeadingSmoother<f64, DEFAULT_WINDOW> = HeadingSmoother::new();
        assert_eq!(s.window(), DEFAULT_WINDOW);
        assert!(s.is_empty());
        for k in 0..100 {
            let h = if k % 2 == 0 { 179.0 } else { -179.0 };
            let m = s.push(h).unwrap();
            assert!(in_range(m));
            // Never near 0 (the mean of the raw degrees).
            assert!(libm::fabs(angle_diff(m, 180.0)) <= 1.0, "{m}");
        }
        // With an even window the alternation averages to exactly 180.
        let mut even: HeadingSmoother<f32, 16> = HeadingSmoother::default();
        let mut last = None;
        for k in 0..40 {
            last = even.push(if k % 2 == 0 { 179.0 } else { -179.0 });
        }
        let m = last.unwrap();
        assert!(in_range(m));
        assert!(libm::fabsf(wrap_deg(m - 180.0)) < 1e-4, "{m}");
    }

    #[test]
    fn smoother_window_shorter_than_capacity() {
        let mut s: HeadingSmoother<f64, 67> = HeadingSmoother::with_window(3).unwrap();
        assert_eq!(s.window(), 3);
        for _ in 0..3 {
            assert_eq!(s.push(0.0), Some(0.0));
        }
        // 0, 0, 90: atan2(1, 2).
        let m = s.push(90.0).unwrap();
        assert!(libm::fabs(m - libm::atan2(1.0, 2.0) / RAD) < 1e-12);
        assert_eq!(s.len(), 3);
        s.push(90.0);
        // Wrapped input: 450 is 90.
        let m = s.push(450.0).unwrap();
        assert!(libm::fabs(m - 90.0) < 1e-12, "{m}");
        assert_eq!(s.len(), 3);
        s.clear();
        assert!(s.is_empty() && s.mean().is_none());
        assert_eq!(s.window(), 3);
        assert_eq!(s.push(-45.0), Some(-45.0));
        // The largest window equals the capacity.
        assert_eq!(
            HeadingSmoother::<f32, 5>::with_window(5).map(|s| s.window()),
            Ok(5)
        );
    }

    #[test]
    fn smoother_rejects_bad_windows() {
        assert_eq!(
            HeadingSmoother::<f32, 15>::with_window(0).err(),
            Some(Error::OutOfRange)
        );
        assert_eq!(
            HeadingSmoother::<f32, 15>::with_window(16).err(),
            Some(Error::OutOfRange)
        );
        assert_eq!(
            HeadingSmoother::<f64, 1>::with_window(usize::MAX).err(),
            Some(Error::OutOfRange)
        );
    }

    #[test]
    fn smoother_ignores_non_finite_headings() {
        let mut s: HeadingSmoother<f64, 4> = HeadingSmoother::new();
        assert_eq!(s.push(f64::NAN), None);
        assert!(s.is_empty());
        s.push(10.0);
        s.push(20.0);
        let before = s.mean();
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert_eq!(s.push(bad), before);
        }
        assert_eq!(s.len(), 2);
        // The window still holds 10 and 20 only.
        assert!(libm::fabs(before.unwrap() - 15.0) < 1e-12);
    }

    #[test]
    fn smoother_mean_undefined_when_headings_cancel() {
        let mut s: HeadingSmoother<f32, 2> = HeadingSmoother::new();
        assert_eq!(s.push(0.0), Some(0.0));
        assert_eq!(s.push(180.0), None);
        // 180 and 90 remain.
        let m = s.push(90.0).unwrap();
        assert!(libm::fabsf(m - 135.0) < 1e-4);
        let mut four: HeadingSmoother<f64, 4> = HeadingSmoother::new();
        for h in [0.0, 90.0, 180.0] {
            four.push(h);
        }
        assert_eq!(four.push(-90.0), None);
        assert_eq!(four.len(), 4);
    }

    #[test]
    fn smoother_single_heading_window() {
        let mut s: HeadingSmoother<f32, 1> = HeadingSmoother::new();
        assert_eq!(s.push(-180.0), Some(180.0));
        assert_eq!(s.push(12.5), Some(12.5));
    }

    #[test]
    fn smoother_in_f32_does_not_drift() {
        // 1e6 headings turning slowly (two full turns through the seam)
        // with a wobble; every smoothed f32 value against the f64 circular
        // mean of the same window.
        const W: usize = DEFAULT_WINDOW;
        let mut s: HeadingSmoother<f32, W> = HeadingSmoother::new();
        let mut window = [0.0f32; W];
        let mut worst = 0.0f64;
        for k in 0..1_000_000usize {
            let t = k as f64;
            let h = wrap_deg(-170.0 + 720.0 * t / 1e6 + 3.0 * libm::sin(t * 0.01)) as f32;
            let got = s.push(h).unwrap();
            assert!(in_range(got));
            window[k % W] = h;
            let filled = (k + 1).min(W);
            let expected = reference_mean(&window[..filled]);
            worst = worst.max(libm::fabs(angle_diff(f64::from(got), expected)));
        }
        assert!(worst < 1e-3, "{worst:e}");
    }
}
