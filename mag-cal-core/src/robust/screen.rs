//! Step 1 of the robust pipeline: screening and the crude sphere
//! (design document, section 14, steps 2 and 4).
//!
//! Before any fit sees them, samples far from the cloud are screened out:
//!
//! 1. a coordinate-wise median centre `c`, from nested histograms per axis
//!    (nested linear histograms) of a subsample (`SUBSAMPLE_ROWS`): each
//!    pass narrows every axis's window to the bins holding its middle
//!    half, until that half spans at least `RESOLVED_BINS` bins (1-2
//!    passes on data without wild values, 3-4 with values 100 times the
//!    field away). The first of these passes also finds the clip levels:
//!    an axis's extreme value that many rows share (one more pass over
//!    every row confirms it, only when there is one). A level inside the
//!    range (an axis clipped on some reads only) is not searched for: it
//!    changed no target of the contamination table (`docs/robustness.md`,
//!    section 5);
//! 2. the median distance `m = median |y - c|` (one pass, a logarithmic histogram);
//!    samples farther than [`SCREEN_RADIUS`]` m` are screened out;
//! 3. the crude sphere `(c, m)`: one more pass measures `| |y - c| - m |`
//!    of the samples kept, giving the band around the sphere that holds
//!    `CRUDE_SHARE` of them (the crude LS start fits only those, which
//!    escapes a displaced patch of the trajectory) and the sphere's own
//!    robust fit error (the refusal figure when no ellipsoid can be fitted
//!    at all: a device lying still, a noise ball).
//! 4. re-centring, beyond the design document: the coordinate-wise median
//!    follows the device's dwell. An on-device collection of a device swung
//!    flat many times before it was tilted crowds on one side of the
//!    sphere; the median centre then sits near that side and the ball of
//!    step 2 leaves out the far side (on such a real recording, 37 % of
//!    the samples, and the fit was refused as planar). When the ball
//!    leaves out at least a sixteenth more of the rows within
//!    `RECENTRE_RADIUS`` m` than it holds (`RECENTRE_MORE_ROWS`), an
//!    algebraic (Kasa) sphere fit of those rows gives a second centre
//!    (three more passes), which replaces the median centre when its
//!    sphere's fit error is less than half (`RECENTRE_GAIN`) and its
//!    ball holds that many more rows. Wild rows lie beyond the radius, so
//!    contaminated data with even coverage do not pay for it.
//!
//! Every pass is a cheap histogram pass (10-25 instructions a sample on a
//! Cortex-M4F); nothing is sorted or stored per sample.

use crate::numerics::histogram::{AxisHistograms, LogHistogram, Place, AXIS_BINS};
use crate::numerics::linalg::{cholesky_in_place, cholesky_solve, larger, smaller};
use crate::sample::Sample;
use crate::steps::methods::MAD_TO_SIGMA;
use crate::steps::moments::BLOCK;
use crate::steps::normalize::{Normalization, Scan};
use crate::steps::rules::{check, count_drops, every, pieces, Ball, Drops, Gate, Rules};
use crate::tuning::{
    CLIP_HINT_ROWS, CLIP_MIN_ROWS, CLIP_SHARE, CRUDE_SHARE, MAX_LEVELS, RECENTRE_GAIN,
    RECENTRE_MORE_ROWS, RECENTRE_RADIUS, RESOLVED_BINS, SCREEN_RADIUS, SUBSAMPLE_ROWS,
};
use crate::Real;

/// The subsample stride for `rows` rows (`SUBSAMPLE_ROWS`).
pub(crate) fn stride(rows: usize) -> usize {
    (rows / SUBSAMPLE_ROWS).max(1)
}

/// Whether an extreme of an axis over the subsample (every
/// [`stride`]`(used)`-th row that `gate` passes) is shared by at least
/// `CLIP_HINT_ROWS` of its rows and at most half of them: one pass over
/// the subsample (about 47 instructions a subsampled row on a Cortex-M4F
/// when no rule drops a row).
#[inline(never)]
pub(crate) fn clip_hint<T: Real, S: Sample>(samples: &[S], gate: &Gate<T>, used: usize) -> bool {
    if cfg!(mag_cal_ablate = "clip-hint") {
        // Ablation (docs/robustness.md): the plain path is always tried.
        return false;
    }
    let step = stride(used);
    // One loop for both gates: the plain one (no rule to apply, no row
    // before to look at) takes the conversion alone (for integer rows)
    // inline. A copy of the loop for each took 392 bytes of flash more
    // (LS9 + ADC2) for 2 760 instructions less (clean, n = 1000).
    let plain = gate.is_plain();
    let rules = Rules::<T>::PLAIN;
    shared_extreme(samples, step, |s, prev| {
        if plain {
            check::<T, S>(s, None, &rules).ok()
        } else {
            gate.pass(s, prev)
        }
    })
}

/// [`clip_hint`] with the rows that `pass` keeps (given the row and the
/// row before it).
#[inline(always)]
fn shared_extreme<T: Real, S: Sample>(
    samples: &[S],
    step: usize,
    pass: impl Fn(&S, Option<&S>) -> Option<[T; 3]>,
) -> bool {
    // Per axis (smallest, largest, rows at the smallest, at the largest):
    // the first row kept sets both.
    let none = (T::MAX, -T::MAX, 0u32, 0u32);
    let [mut x0, mut x1, mut x2] = [none; 3];
    let mut rows = 0u32;
    let mut i = 0;
    while let Some(s) = samples.get(i) {
        let prev = i.checked_sub(1).and_then(|j| samples.get(j));
        i = i.saturating_add(step);
        let Some(y) = pass(s, prev) else {
            continue;
        };
        rows += 1;
        // Written out per axis: a loop over the axes stays one at
        // opt-level "s", with the row in memory.
        extremes(y[0], &mut x0);
        extremes(y[1], &mut x1);
        extremes(y[2], &mut x2);
    }
    [x0.2, x0.3, x1.2, x1.3, x2.2, x2.3]
        .iter()
        .any(|&n| n >= CLIP_HINT_ROWS && n <= rows / 2)
}

/// Updates an axis's `(smallest, largest, rows at the smallest, rows at
/// the largest)` with the value `v` ([`clip_hint`]). A row inside both
/// extremes, the usual one, costs two compares.
#[inline(always)]
fn extremes<T: Real>(v: T, x: &mut (T, T, u32, u32)) {
    if v <= x.0 {
        if v < x.0 {
            (x.0, x.2) = (v, 1);
        } else {
            x.2 += 1;
        }
    }
    if v >= x.1 {
        if v > x.1 {
            (x.1, x.3) = (v, 1);
        } else {
            x.3 += 1;
        }
    }
}

/// What screening found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Screening<T: Real> {
    /// The scan's rules with the clip levels found.
    pub rules: Rules<T>,
    /// Rows dropped by each rule (the clipped ones included).
    pub drops: Drops,
    /// Rows the rules keep.
    pub valid: usize,
    /// The screening ball: median centre, radius [`SCREEN_RADIUS`]` m`.
    pub ball: Ball<T>,
    /// The normalisation of the robust path: median centre, scale `m`.
    pub norm: Normalization<T>,
    /// Half-width of the band `| |y - c| - m | <= band` that holds
    /// `CRUDE_SHARE` of the screened samples, sensor units.
    pub band: T,
    /// Robust fit error of the crude sphere:
    /// `1.4826 median | |y - c| / m - 1 |` over the screened samples.
    pub sphere_error: T,
    /// Passes over the samples.
    pub passes: u32,
}

/// Why screening found no sphere to screen by (crate-private: the caller
/// turns it into a [`crate::Error`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Unscreened {
    /// No spread: most rows share each axis's value
    /// ([`crate::Error::AllSamplesEqual`]).
    AllEqual,
    /// More than half the rows sit on the median centre: the crude
    /// sphere's fit error is infinite, a figure for the judging (which
    /// refuses it as [`crate::Error::NoSphere`] with the caller's limit).
    Crowded,
}

/// Screens the rows the scan's rules keep. Out of line: its histograms
/// take stack only while it runs.
#[inline(never)]
pub(crate) fn screen<T: Real, S: Sample>(
    samples: &[S],
    scan: &Scan<T>,
) -> Result<Screening<T>, Unscreened> {
    let (centre, spread, rules, mut passes) = median_centre(samples, scan);
    let gate = Gate::of(rules, scan.dwell);
    if !(spread > T::zero()) || !spread.is_finite() {
        return Err(Unscreened::AllEqual);
    }
    // Median distance, on the scale of the spread (the mean inter-quartile
    // range: a sphere's radius).
    let inv_spread = T::one() / spread;
    let every = stride(scan.used);
    let mut dist = LogHistogram::new();
    distances(samples, &gate, centre, inv_spread, every, false, &mut dist);
    passes += 1;
    let m = dist
        .quantile(T::lit(0.5))
        .map(|q| q.square_root() * spread)
        .unwrap_or(T::zero());
    // Rows within the re-centring radius (the histogram counts squared
    // distances over the spread's square).
    let near = m * inv_spread * T::from_single(RECENTRE_RADIUS);
    let rows_near = dist.count_below(near * near);
    if !(m > T::zero()) || !m.is_finite() {
        // More than half the rows sit on the median centre.
        return Err(Unscreened::Crowded);
    }
    // The median centre follows the device's dwell: samples crowded on one
    // side of the sphere put it near that side, and the far side beyond
    // the ball. The algebraic sphere fit does not depend on coverage; it
    // replaces the median centre when its sphere fits the shell much
    // better (see `recentre`).
    let median_sphere = shell(samples, &gate, centre, m, every);
    passes += 1;
    let enough_more = |inside: u32| {
        inside.saturating_sub(median_sphere.inside) >= median_sphere.inside / RECENTRE_MORE_ROWS
    };
    // Only when the median centre's ball leaves out so many rows that
    // another ball could hold the required share more.
    // (Ablation, docs/robustness.md: `recentre` keeps the median centre.)
    let (kasa, kasa_passes) = if !cfg!(mag_cal_ablate = "recentre") && enough_more(rows_near) {
        recentre(samples, &gate, centre, m, every)
    } else {
        (None, 0)
    };
    passes += kasa_passes;
    let better = |k: &Shell<T>| {
        k.error < T::lit(RECENTRE_GAIN) * median_sphere.error && enough_more(k.inside)
    };
    let chosen = kasa
        .map(|(c, r)| shell(samples, &gate, c, r, every))
        .filter(better);
    passes += u32::from(kasa.is_some());
    let Shell {
        centre,
        m,
        ball,
        band,
        error,
        ..
    } = chosen.unwrap_or(median_sphere);
    let sphere_error = error;
    let inv_m = T::one() / m;
    let norm = Normalization {
        centre: nalgebra::Vector3::new(centre[0], centre[1], centre[2]),
        scale: m,
        inv_scale: inv_m,
    };
    let drops = if rules.clipping {
        count_drops::<T, S>(samples, &rules, scan.dwell)
    } else {
        scan.drops
    };
    let valid = scan.used.saturating_sub(drops.clipped);
    Ok(Screening {
        rules,
        drops,
        valid,
        ball,
        norm,
        band,
        sphere_error,
        passes,
    })
}

/// A candidate crude sphere and how well the rows inside its ball fit it.
#[derive(Clone, Copy)]
struct Shell<T: Real> {
    centre: [T; 3],
    /// Median distance of the rows from `centre` (the radius).
    m: T,
    /// The screening ball, radius [`SCREEN_RADIUS`]` m`.
    ball: Ball<T>,
    /// Half-width of the band holding `CRUDE_SHARE` of the rows inside
    /// the ball, sensor units.
    band: T,
    /// `1.4826 median | |y - c| / m - 1 |` over the rows inside the ball.
    error: T,
    /// Subsampled rows inside the ball.
    inside: u32,
}

/// The shell residuals `| |y - c| / m - 1 |` of the (subsampled) rows
/// inside the ball of radius [`SCREEN_RADIUS`]` m` about `c`: one pass.
/// Out of line: its histogram takes stack only while it runs.
#[inline(never)]
fn shell<T: Real, S: Sample>(
    samples: &[S],
    gate: &Gate<T>,
    centre: [T; 3],
    m: T,
    every: usize,
) -> Shell<T> {
    let ball = Ball {
        centre,
        radius_sq: m * m * T::lit(SCREEN_RADIUS * SCREEN_RADIUS),
    };
    let inside = Gate {
        screen: Some(ball),
        ..*gate
    };
    let mut h = LogHistogram::new();
    distances(samples, &inside, centre, T::one() / m, every, true, &mut h);
    Shell {
        centre,
        m,
        ball,
        band: h.quantile(T::lit(CRUDE_SHARE)).unwrap_or(T::zero()) * m,
        error: h.quantile(T::lit(0.5)).unwrap_or(T::zero()) * T::lit(MAD_TO_SIGMA),
        inside: h.total(),
    }
}

/// The algebraic sphere fit's centre and its median distance, or `None`
/// when it has none; and the passes it took (two, subsampled).
///
/// Kasa's fit (algebraic: linear least squares, normal equations) over
/// the subsampled rows within `RECENTRE_RADIUS`` m` of the median centre
/// `c`, in units of `m` about `c` (so that `f32` suffices whatever the
/// offset): exact for samples on any part of a sphere, however unevenly
/// the device dwelt. Its least-squares weights make it sensitive to wild
/// rows inside that ball, which is why it only replaces the median centre
/// when it fits the shell better (`RECENTRE_GAIN`). Out of line, as
/// [`shell`].
#[inline(never)]
fn recentre<T: Real, S: Sample>(
    samples: &[S],
    gate: &Gate<T>,
    c: [T; 3],
    m: T,
    every: usize,
) -> (Option<([T; 3], T)>, u32) {
    let inv_m = T::one() / m;
    // Normal equations of `|x|^2 = 2 a . x + d` over `z = [x, 1]`, `x`
    // the row about `c` in units of `m` (within `RECENTRE_RADIUS`, so the
    // sums stay small in `f32`): `(sum z z^T) [2a, d] = sum z |x|^2`.
    let mut zz = [[T::zero(); 4]; 4];
    let mut zq = [T::zero(); 4];
    let limit_sq = T::from_single(RECENTRE_RADIUS * RECENTRE_RADIUS);
    visit(samples, BLOCK, gate, every, &mut |y| {
        let z = [
            (y[0] - c[0]) * inv_m,
            (y[1] - c[1]) * inv_m,
            (y[2] - c[2]) * inv_m,
            T::one(),
        ];
        let q = z[0] * z[0] + z[1] * z[1] + z[2] * z[2];
        if q <= limit_sq {
            for (row, &zi) in zz.iter_mut().zip(&z) {
                for (e, &zj) in row.iter_mut().zip(&z) {
                    *e += zi * zj;
                }
            }
            for (e, &zi) in zq.iter_mut().zip(&z) {
                *e += zi * q;
            }
        }
    });
    if !cholesky_in_place(&mut zz) {
        return (None, 1);
    }
    let [a0, a1, a2, _] = cholesky_solve(&zz, &zq);
    let half = T::lit(0.5) * m;
    let centre = [c[0] + a0 * half, c[1] + a1 * half, c[2] + a2 * half];
    let mut dist = LogHistogram::new();
    distances(samples, gate, centre, inv_m, every, false, &mut dist);
    let r = dist
        .quantile(T::lit(0.5))
        .map(|q| q.square_root() * m)
        .unwrap_or(T::zero());
    let ok = r > T::zero() && r.is_finite() && centre.iter().all(|v| v.is_finite());
    (ok.then_some((centre, r)), 2)
}

/// The coordinate-wise median of the rows the scan's rules keep, the mean
/// of the axes' inter-quartile ranges, the rules with the clip levels found
/// in the first pass (rows at the scan's extremes, `CLIP_SHARE`),
/// and the passes it took.
fn median_centre<T: Real, S: Sample>(samples: &[S], scan: &Scan<T>) -> ([T; 3], T, Rules<T>, u32) {
    let rows = Gate::of(scan.rules, scan.dwell);
    // The window of the first histograms: the bounds of the subsample
    // (rows beyond them count below or above the window; a clip level is
    // an extreme that many rows share, so the subsample has it too).
    let every = stride(scan.used);
    let mut first: Option<([T; 3], [T; 3])> = None;
    visit(samples, BLOCK, &rows, every, &mut |y| {
        let (lo, hi) = first.get_or_insert((y, y));
        for ((l, u), v) in lo.iter_mut().zip(hi.iter_mut()).zip(y) {
            *l = smaller(*l, v);
            *u = larger(*u, v);
        }
    });
    let (box_lo, box_hi) = first.unwrap_or(([T::zero(); 3], [T::zero(); 3]));
    let (mut lo, mut hi) = (box_lo, box_hi);
    let mut median = [T::zero(); 3];
    let mut iqr = [T::zero(); 3];
    let mut done = [false; 3];
    let mut passes = 0;
    let mut level_passes = 0;
    let mut rules = scan.rules;
    while passes < MAX_LEVELS && !done.iter().all(|&d| d) {
        let mut h = AxisHistograms::new(lo, hi);
        let gate = Gate::of(rules, scan.dwell);
        // One pass fills the histograms; the first also counts per axis
        // the rows at the smallest and the largest value of the bounds
        // (the candidate clip levels).
        let first = passes == 0;
        let mut at = [[0usize; 2]; 3];
        let mut sub_rows = 0;
        visit(samples, BLOCK, &gate, every, &mut |y| {
            if first {
                sub_rows += 1;
                for (((n, l), u), v) in at.iter_mut().zip(&box_lo).zip(&box_hi).zip(y) {
                    n[0] += usize::from(v == *l);
                    n[1] += usize::from(v == *u);
                }
            }
            h.add(y);
        });
        if first {
            let mut levels = clip_levels(sub_rows, (&box_lo, &box_hi), &at);
            level_passes = confirm_levels(samples, &gate, scan.used, &mut levels);
            rules = Rules {
                glitches: scan.rules.glitches,
                ..Rules::with_clip(levels)
            };
        }
        passes += 1;
        for a in 0..3 {
            if done[a] {
                continue;
            }
            if !(h.width(a) > T::zero()) {
                // One value on this axis.
                median[a] = lo[a];
                done[a] = true;
                continue;
            }
            let (q1, q2, q3) = (
                h.quantile(a, T::lit(0.25)),
                h.quantile(a, T::lit(0.5)),
                h.quantile(a, T::lit(0.75)),
            );
            let (Place::In(k1, v1), Place::In(_, v2), Place::In(k3, v3)) = (q1, q2, q3) else {
                // The window lost the middle half (halved counters): keep
                // the last estimate.
                done[a] = true;
                continue;
            };
            median[a] = v2;
            iqr[a] = v3 - v1;
            if k3 - k1 + 1 >= RESOLVED_BINS || k3 - k1 + 1 >= AXIS_BINS {
                done[a] = true;
            } else {
                (lo[a], hi[a]) = h.window(a, k1, k3);
            }
        }
    }
    let spread = (iqr[0] + iqr[1] + iqr[2]) / T::lit(3.0);
    // The bounds took a pass too.
    (median, spread, rules, passes + 1 + level_passes)
}

/// The candidate clip levels: an axis's extreme value that at least
/// `CLIP_SHARE` of the `used` rows of the subsample (and
/// `CLIP_MIN_ROWS`) share, but not most of them: an axis
/// that hardly varies (planar data) is no clipping ([`confirm_levels`]
/// counts them on every row).
fn clip_levels<T: Real>(
    used: usize,
    (lo, hi): (&[T; 3], &[T; 3]),
    at: &[[usize; 2]; 3],
) -> [[T; 2]; 3] {
    let level = |v: T, n: usize| {
        if shared_by_many(n, used) {
            v
        } else {
            T::MAX
        }
    };
    let mut out = [[T::MAX; 2]; 3];
    if cfg!(mag_cal_ablate = "clip-extremes") {
        // Ablation (docs/robustness.md): no extreme is a clip level.
        return out;
    }
    for (o, ((&lo, &hi), &[nl, nh])) in out.iter_mut().zip(lo.iter().zip(hi).zip(at)) {
        if lo < hi {
            *o = [level(lo, nl), level(hi, nh)];
        }
    }
    out
}

/// Keeps the candidate clip levels (`levels`, `T::MAX` for none) that
/// at least `CLIP_SHARE` of the `used` rows `gate`
/// passes (and `CLIP_MIN_ROWS`) share exactly, but not
/// most of them: one pass over every row, only when there is a
/// candidate. Returns the passes taken. The candidates come from a
/// subsample, whose counts are too few to decide: on a real recording
/// (`imu_gnss_1252.csv`, 1252 rows) 5 of the 313 rows of the subsample
/// shared an axis's extreme, 12 of all the rows (a clip level needs 19).
#[inline(never)]
fn confirm_levels<T: Real, S: Sample>(
    samples: &[S],
    gate: &Gate<T>,
    used: usize,
    levels: &mut [[T; 2]; 3],
) -> u32 {
    if !levels.as_flattened().iter().any(|l| l.abs() < T::MAX) {
        return 0;
    }
    let mut shared = [[0usize; 2]; 3];
    visit(samples, BLOCK, gate, 1, &mut |y| {
        for ((n, l), v) in shared.iter_mut().zip(levels.iter()).zip(y) {
            n[0] += usize::from(v == l[0]);
            n[1] += usize::from(v == l[1]);
        }
    });
    for (l, &n) in levels
        .as_flattened_mut()
        .iter_mut()
        .zip(shared.as_flattened())
    {
        if !shared_by_many(n, used) {
            *l = T::MAX;
        }
    }
    1
}

/// The rows a clip level needs of `rows` rows:
/// `CLIP_SHARE` of them, and at least
/// `CLIP_MIN_ROWS` (in integers: no soft-float `f64` on
/// the target).
fn clip_rows(rows: usize) -> usize {
    const PER_ROW: usize = (1.0 / CLIP_SHARE) as usize;
    (rows / PER_ROW).max(CLIP_MIN_ROWS)
}

/// Whether `n` of `rows` rows sharing a value make it a clip level: a clip
/// level's share ([`clip_rows`]), but not most of the rows (an axis that
/// hardly varies is no clipping).
fn shared_by_many(n: usize, rows: usize) -> bool {
    n >= clip_rows(rows) && n <= rows / 2
}

/// Calls `f` with every `stride`-th row of each piece of `piece` rows
/// (from the piece's first) that the gate passes.
///
/// The one loop of the screening's passes, each pass's work a closure
/// called through a pointer: a loop of its own for each pass (the
/// median centre's bounds and histograms, the clip levels' count, the
/// distances, the shell residuals, the algebraic sphere's rows) took
/// 1 232 bytes of flash more (LS9 + ADC2 on a Cortex-M4F) for 28 000 to
/// 38 000 instructions less on contaminated data (n = 1000, a tenth of the
/// rows displaced or wild). The clip hint keeps its own loop: clean data
/// take it, and through this one they paid 26 000 instructions more.
#[inline(never)]
fn visit<T: Real, S: Sample>(
    samples: &[S],
    piece: usize,
    gate: &Gate<T>,
    stride: usize,
    f: &mut dyn FnMut([T; 3]),
) {
    for (prev, block) in pieces(samples, piece) {
        for (_, s, last) in every(block, prev, stride) {
            if let Some(y) = gate.pass(s, last) {
                f(y);
            }
        }
    }
}

/// Counts into `h` `|y - c|^2 / scale^2` (with `shell`, the shell
/// residual `| |y - c| / scale - 1 |`) of every `stride`-th row of each
/// block that the gate passes, `inv` being `1 / scale`. Out of line: one
/// copy for its three callers.
#[inline(never)]
fn distances<T: Real, S: Sample>(
    samples: &[S],
    gate: &Gate<T>,
    c: [T; 3],
    inv: T,
    stride: usize,
    shell: bool,
    h: &mut LogHistogram,
) {
    visit(samples, BLOCK, gate, stride, &mut |y| {
        let d = [
            (y[0] - c[0]) * inv,
            (y[1] - c[1]) * inv,
            (y[2] - c[2]) * inv,
        ];
        let q = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        h.add(if !shell {
            q
        } else if q >= T::MIN_POSITIVE {
            // | |d| - 1 | = | q - 1 | / (|d| + 1): no cancellation near 1.
            (q - T::one()) / (q * q.rsqrt() + T::one())
        } else {
            T::one()
        });
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::steps::normalize::scan;

    /// The plain path is skipped when an axis's extreme may be a clip
    /// level: 2 % of the rows of a sphere of 1000 clipped to the level that
    /// leaves the other 98 % beyond (the level needs 16 rows, `n / 64`, of
    /// which the subsample of every third row holds about 7). Not on the
    /// clean sphere, nor for rows the rules drop (rails), nor on an axis
    /// that most rows share (planar data, refused as such later).
    #[test]
    fn a_shared_extreme_hints_at_a_clip_level() {
        let sphere: [[i16; 3]; 1000] = core::array::from_fn(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / 1000.0;
            let (r, phi) = ((1.0 - z * z).sqrt(), i as f64 * 2.399_963);
            let v = [r * phi.cos(), r * phi.sin(), z].map(|c| (400.0 * c).round() as i16);
            [v[0] + 150, v[1] - 80, v[2] + 20]
        });
        let hint = |rows: &[[i16; 3]]| {
            let s = scan::<f32, [i16; 3]>(rows, true).unwrap();
            let gate = Gate::of(s.rules, s.dwell);
            clip_hint(rows, &gate, s.used)
        };
        assert!(!hint(&sphere));
        // The 20 rows reaching farthest along +y, clipped to the 21st.
        let mut by_y: [usize; 1000] = core::array::from_fn(|i| i);
        by_y.sort_unstable_by_key(|&i| core::cmp::Reverse(sphere[i][1]));
        let level = sphere[by_y[20]][1];
        let mut clipped = sphere;
        for &i in &by_y[..20] {
            clipped[i][1] = level;
        }
        assert!(hint(&clipped));
        // Rows on the rails: the rules drop them before the hint looks.
        let mut rails = sphere;
        for row in rails.iter_mut().step_by(25) {
            row[2] = i16::MAX;
        }
        assert!(!hint(&rails));
        // One axis shared by every row: planar, no clip.
        let mut flat = sphere;
        for row in flat.iter_mut() {
            row[2] = 7;
        }
        assert!(!hint(&flat));
    }
}
