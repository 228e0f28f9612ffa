//! The 35 moments of the normalised samples (design document, section 3).
//!
//! The LS scatter matrix `S = sum phi phi^T` of the design row
//! `phi(x) = [x^2, y^2, z^2, 2xy, 2xz, 2yz, 2x, 2y, 2z, 1]` has only 35
//! distinct entries: the sums `sum x^p y^q z^r` with `p + q + r <= 4`. They
//! are accumulated in one pass; the `n x 10` design matrix is never stored.

use nalgebra::SMatrix;

use crate::numerics::histogram::LogHistogram;
use crate::robust::runs::{RunFinder, Runs};
use crate::sample::Sample;
use crate::steps::normalize::{Normalization, Projector};
use crate::steps::rules::{check, every, Gate, Rules};
use crate::Real;

/// Number of monomials `x^p y^q z^r` with `p + q + r <= 4`.
pub const COUNT: usize = 35;

/// Samples summed into a block accumulator before it is added to the total.
/// Blocked summation keeps the rounding error of `f32` sums growing with
/// `n / BLOCK + BLOCK` instead of `n`, for one extra add per moment per block.
pub(crate) const BLOCK: usize = 128;

/// Exponents `(p, q, r)` of each moment, ordered by total degree.
pub const EXPONENTS: [[u8; 3]; COUNT] = exponents();

const fn exponents() -> [[u8; 3]; COUNT] {
    let mut out = [[0u8; 3]; COUNT];
    let mut k = 0;
    let mut degree = 0u8;
    while degree <= 4 {
        let mut p = degree as i8;
        while p >= 0 {
            let mut q = (degree as i8) - p;
            while q >= 0 {
                let r = degree as i8 - p - q;
                out[k] = [p as u8, q as u8, r as u8];
                k += 1;
                q -= 1;
            }
            p -= 1;
        }
        degree += 1;
    }
    out
}

/// `INDEX[p][q][r]`: position of `x^p y^q z^r` in [`EXPONENTS`] (only
/// meaningful for `p + q + r <= 4`).
const INDEX: [[[u8; 5]; 5]; 5] = index();

const fn index() -> [[[u8; 5]; 5]; 5] {
    let mut out = [[[0u8; 5]; 5]; 5];
    let mut k = 0;
    while k < COUNT {
        let [p, q, r] = EXPONENTS[k];
        out[p as usize][q as usize][r as usize] = k as u8;
        k += 1;
    }
    out
}

/// The monomials of the design row: exponents and the constant factor.
const PHI: [([u8; 3], u8); 10] = [
    ([2, 0, 0], 1),
    ([0, 2, 0], 1),
    ([0, 0, 2], 1),
    ([1, 1, 0], 2),
    ([1, 0, 1], 2),
    ([0, 1, 1], 2),
    ([1, 0, 0], 2),
    ([0, 1, 0], 2),
    ([0, 0, 1], 2),
    ([0, 0, 0], 1),
];

/// The 35 power sums of the normalised samples.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Moments<T: Real> {
    /// `sums[k] = sum x^p y^q z^r` with `[p, q, r] = EXPONENTS[k]`.
    pub sums: [T; COUNT],
}

impl<T: Real> Moments<T> {
    /// One pass over the finite samples, normalised by `norm`.
    ///
    /// Each block of samples is read twice: once for the count and the 19
    /// monomials of degrees 1-3, once for the 15 of degree 4. Each loop's
    /// accumulators then stay in the Cortex-M4F's 32 floating-point
    /// registers (34 at once spill): about 111 instructions a sample for
    /// `f32` and `[i16; 3]` samples at opt-level "s" with the finite rows
    /// marked first (the gated pass's loops, `sum_low` and
    /// `sum_high`), 84 with a plain copy of the two loops, 134 for one
    /// loop (design document, section 13).
    pub fn accumulate<S: Sample>(samples: &[S], norm: &Normalization<T>) -> Self {
        let mut sums = [T::zero(); COUNT];
        for block in samples.chunks(BLOCK) {
            // The finite rows, marked for the gated pass's block sums
            // (their own copy of the two loops took 572 bytes of flash
            // more, LS9 + ADC2, for 27 640 instructions less at n = 1000).
            let mut mask = [0u32; MASK_WORDS];
            let mut kept = 0;
            for (i, s) in block.iter().enumerate() {
                if S::ALWAYS_FINITE || check::<T, S>(s, None, &Rules::PLAIN).is_ok() {
                    if let Some(w) = mask.get_mut(i / 32) {
                        *w |= 1 << (i % 32);
                        kept += 1;
                    }
                }
            }
            add_block(&mut sums, block, norm, &mask, kept);
        }
        Self { sums }
    }

    /// [`Moments::accumulate`] over the rows `gate` passes and, with a
    /// `cut`, only those whose algebraic residual under the cut's fit is
    /// within its limit (a weighted LS refit with 0/1 weights). `hist`, when
    /// given, counts the residuals of every row the gate passes. The count
    /// of the rows kept is the moment `sums[0]` ([`Moments::count`]).
    pub(crate) fn accumulate_with<S: Sample>(
        samples: &[S],
        norm: &Normalization<T>,
        gate: &Gate<T>,
        cut: Option<&Cut<T>>,
        hist: Option<&mut LogHistogram>,
    ) -> Self {
        Self::accumulate_every(samples, norm, gate, cut, hist, 1)
    }

    /// [`Moments::accumulate_with`] over every `stride`-th row of each
    /// block of [`BLOCK`] rows (a fixed subsample; the repetition rule still
    /// reads the row before each).
    pub(crate) fn accumulate_every<S: Sample>(
        samples: &[S],
        norm: &Normalization<T>,
        gate: &Gate<T>,
        cut: Option<&Cut<T>>,
        hist: Option<&mut LogHistogram>,
        stride: usize,
    ) -> Self {
        // A plain gate's rows (clean data) take the plain copy of the
        // loops: 148 bytes of flash for about 65 000 instructions less on
        // 1 000 rows, on the first moments pass of a fit whose scan dropped
        // no row and found no still period (the 10 % contaminated kinds stay
        // under 2.0 M: `robust-spike` 2 007 520 without it; `bash bench.sh
        // flash` and `bench`). Without the `robust` feature, the gated loops
        // alone.
        if cfg!(feature = "robust") && gate.is_plain() && cut.is_none() && stride <= 1 {
            return Self::accumulate(samples, norm);
        }
        Self::accumulate_finding(samples, norm, gate, &Runs::NONE, cut, hist, stride, None)
    }

    /// [`Moments::accumulate_every`] outside the spans of `skip` that, with
    /// `runs`, also finds the runs of rows whose residual is beyond the
    /// threshold given with them and writes them there ([`crate::robust::runs`]).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn accumulate_finding<S: Sample>(
        samples: &[S],
        norm: &Normalization<T>,
        gate: &Gate<T>,
        skip: &Runs,
        cut: Option<&Cut<T>>,
        mut hist: Option<&mut LogHistogram>,
        stride: usize,
        runs: Option<(&mut Runs, T)>,
    ) -> Self {
        let (runs, strong) = match runs {
            Some((r, strong)) => (Some(r), strong),
            None => (None, T::MAX),
        };
        let mut finder = runs.map(|r| RunFinder::new(r, stride));
        let mut sums = [T::zero(); COUNT];
        for (start, prev, block) in skip.pieces(samples, BLOCK) {
            let mut mask = [0u32; MASK_WORDS];
            let kept = select(
                block,
                prev,
                gate,
                cut,
                hist.as_deref_mut(),
                &mut mask,
                stride,
                finder.as_mut().map(|f| (start, strong, f)),
            );
            add_block(&mut sums, block, norm, &mask, kept);
        }
        if let Some(f) = finder {
            f.finish(samples.len());
        }
        Self { sums }
    }

    /// Adds the sums of `other` (moments of more rows: power sums add).
    pub(crate) fn add(&mut self, other: &Self) {
        for (t, v) in self.sums.iter_mut().zip(other.sums) {
            *t += v;
        }
    }

    /// No rows.
    pub(crate) fn zero() -> Self {
        Self {
            sums: [T::zero(); COUNT],
        }
    }

    /// Number of samples summed (the moment of degree 0).
    pub fn count(&self) -> usize {
        self.sums[0].to_count()
    }

    /// `sum x^p y^q z^r`.
    #[inline]
    pub fn get(&self, p: u8, q: u8, r: u8) -> T {
        let k = INDEX[usize::from(p) % 5][usize::from(q) % 5][usize::from(r) % 5];
        self.sums[usize::from(k) % COUNT]
    }

    /// The 10x10 scatter matrix `S = sum phi phi^T`, assembled from the
    /// moments.
    pub fn scatter(&self) -> SMatrix<T, 10, 10> {
        // From a table of (moment, factor) per entry, computed at compile
        // time: the index arithmetic per entry cost about 60 instructions
        // a call on a Cortex-M4F, and the robust path assembles a scatter
        // for every refit.
        let mut s = SMatrix::<T, 10, 10>::zeros();
        for (i, row) in SCATTER.iter().enumerate() {
            for (j, &(k, factor)) in row.iter().enumerate() {
                let m = self.sums.get(usize::from(k)).copied().unwrap_or(T::zero());
                s[(i, j)] = m * T::from_count(usize::from(factor));
            }
        }
        s
    }
}

/// Entry `(i, j)` of the scatter: the index of its moment and its factor.
const SCATTER: [[(u8, u8); 10]; 10] = scatter_table();

const fn scatter_table() -> [[(u8, u8); 10]; 10] {
    let mut out = [[(0u8, 0u8); 10]; 10];
    let mut i = 0;
    while i < 10 {
        let mut j = 0;
        while j < 10 {
            let (ei, ki) = PHI[i];
            let (ej, kj) = PHI[j];
            let (p, q, r) = (ei[0] + ej[0], ei[1] + ej[1], ei[2] + ej[2]);
            out[i][j] = (INDEX[p as usize][q as usize][r as usize], ki * kj);
            j += 1;
        }
        i += 1;
    }
    out
}

/// Moments of degrees 0-3: positions `0..LOW` of [`EXPONENTS`].
const LOW: usize = 20;

/// Words of a block's mask of kept rows.
const MASK_WORDS: usize = BLOCK / 32;

/// A 0/1 weight for a weighted LS refit: a row is kept when its algebraic
/// residual `e = (|u|^2 - 1) / 2` under the previous fit (`u` its
/// calibrated vector) is at most `limit` in magnitude. Near the ellipsoid
/// `e` is the radial error `|u| - 1` to first order, and for the LS9 quadric
/// `phi9 . v9 - 1 = k (|u|^2 - 1)`: the cut is on the LS's own residual.
#[derive(Clone, Copy)]
pub(crate) struct Cut<T: Real> {
    pub map: Projector<T>,
    pub limit: T,
}

/// A moments pass as a value, fed the rows in slices
/// ([`MomentsPass::feed`], the background calibrator,
/// [`crate::device::background`]); the batch fit runs the same pass over
/// all of them at once ([`Moments::accumulate_with`]). The moments of the
/// slices add up (power sums), in blocks of [`BLOCK`] rows from each
/// slice's start: slices of one block give the whole pass's sums bit for
/// bit, others the same to rounding.
#[derive(Clone, Copy)]
pub(crate) struct MomentsPass<T: Real> {
    norm: Normalization<T>,
    cut: Option<Cut<T>>,
    moments: Moments<T>,
}

impl<T: Real> MomentsPass<T> {
    /// No rows yet: the moments of the rows normalised by `norm` (within
    /// `cut`, when given).
    pub(crate) fn new(norm: Normalization<T>, cut: Option<Cut<T>>) -> Self {
        Self {
            norm,
            cut,
            moments: Moments::zero(),
        }
    }

    /// Adds the rows of `rows` the gate passes (a slice of the samples; the
    /// rows after it come with the next call).
    pub(crate) fn feed<S: Sample>(&mut self, rows: &[S], gate: &Gate<T>) {
        let cut = self.cut.as_ref();
        let slice = Moments::accumulate_with(rows, &self.norm, gate, cut, None);
        self.moments.add(&slice);
    }

    /// The moments of every row fed.
    pub(crate) fn moments(&self) -> &Moments<T> {
        &self.moments
    }
}

// The two block sums are separate functions, not inlined into `accumulate`,
// so that each loop gets the floating-point registers to itself: inlined,
// the normalisation constants of one loop spill during the other.

/// Marks in `mask` the rows of `block` (every `stride`-th, from the first)
/// that the gate passes and the cut keeps, and returns their count;
/// `hist`, when given, counts the cut's residual of every row the gate
/// passes; `finder`, when given, gets the index of each row whose
/// residual exceeds the threshold given with it (the block's first row is
/// at the index given). A loop of its own: with the
/// gate's and the cut's constants beside the 19 sums, one loop spilled
/// (about 230 instructions a sample on a Cortex-M4F for this and
/// [`sum_low`] together, against about 150 apart).
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn select<T: Real, S: Sample>(
    block: &[S],
    prev: Option<&S>,
    gate: &Gate<T>,
    cut: Option<&Cut<T>>,
    mut hist: Option<&mut LogHistogram>,
    mask: &mut [u32; MASK_WORDS],
    stride: usize,
    mut finder: Option<(usize, T, &mut RunFinder<'_>)>,
) -> usize {
    let half = T::lit(0.5);
    // The cut by value: its constants then stay in registers rather than
    // being read again after each histogram write.
    let cut = cut.copied();
    let mut count = 0;
    for (i, s, last) in every(block, prev, stride) {
        let Some(y) = gate.pass(s, last) else {
            continue;
        };
        if let Some(cut) = &cut {
            let [ux, uy, uz] = cut.map.project(y);
            let e = (ux * ux + uy * uy + uz * uz - T::one()) * half;
            if let Some(h) = hist.as_deref_mut() {
                h.add(e);
            }
            if !(e.abs() <= cut.limit) {
                // Only rows well beyond the cut count towards a run.
                if let Some((start, _, f)) = finder.as_mut().filter(|f| e.abs() > f.1) {
                    f.reject(start.saturating_add(i));
                }
                continue;
            }
        }
        if let Some(w) = mask.get_mut(i / 32) {
            *w |= 1 << (i % 32);
            count += 1;
        }
    }
    count
}

/// Calls `add` with each normalised row of `block` marked in `mask`. (A
/// loop over the mask's words, not an iterator that looks up each row's
/// word: that cost 6 instructions a row more on a Cortex-M4F.)
#[inline(always)]
fn for_marked<T: Real, S: Sample>(
    block: &[S],
    norm: &Normalization<T>,
    mask: &[u32; MASK_WORDS],
    mut add: impl FnMut(T, T, T),
) {
    let (c, is) = (&norm.centre, norm.inv_scale);
    for (&word, chunk) in mask.iter().zip(block.chunks(32)) {
        // Only the set bits, lowest first: a subsample's rows cost
        // nothing between them.
        let mut bits = word;
        while bits != 0 {
            let i = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            if let Some(s) = chunk.get(i) {
                let [x, y, z] = s.xyz::<T>();
                add((x - c.x) * is, (y - c.y) * is, (z - c.z) * is);
            }
        }
    }
}

/// Adds the sums of the rows of `block` marked in `mask` (`kept` of them)
/// to `sums`: the block sums of the plain and the gated pass, one copy
/// (one copy each took 136 bytes of flash more, LS9 + ADC2).
#[inline(never)]
fn add_block<T: Real, S: Sample>(
    sums: &mut [T; COUNT],
    block: &[S],
    norm: &Normalization<T>,
    mask: &[u32; MASK_WORDS],
    kept: usize,
) {
    let (low, high) = sums.split_at_mut(LOW);
    let mut a = sum_low(block, norm, mask);
    a[0] = T::from_count(kept);
    for (t, v) in low.iter_mut().zip(a) {
        *t += v;
    }
    for (t, v) in high.iter_mut().zip(sum_high(block, norm, mask)) {
        *t += v;
    }
}

/// The sums of the monomials of degrees 1-3 over the rows of `block`
/// marked in `mask`, in [`EXPONENTS`] order (`a[0]`, the count, is the
/// caller's).
#[inline(never)]
fn sum_low<T: Real, S: Sample>(
    block: &[S],
    norm: &Normalization<T>,
    mask: &[u32; MASK_WORDS],
) -> [T; LOW] {
    let mut a = [T::zero(); LOW];
    for_marked(block, norm, mask, |x, y, z| add_low(&mut a, x, y, z));
    a
}

/// The sums of the monomials of degree 4 over the rows of `block` marked
/// in `mask`, in [`EXPONENTS`] order.
#[inline(never)]
fn sum_high<T: Real, S: Sample>(
    block: &[S],
    norm: &Normalization<T>,
    mask: &[u32; MASK_WORDS],
) -> [T; COUNT - LOW] {
    let mut a = [T::zero(); COUNT - LOW];
    for_marked(block, norm, mask, |x, y, z| add_high(&mut a, x, y, z));
    a
}

/// Adds the monomials of degrees 1-3 of one normalised sample to
/// `a[1..LOW]`, in [`EXPONENTS`] order (`a[0]`, the count, is the caller's).
#[inline(always)]
fn add_low<T: Real>(a: &mut [T; LOW], x: T, y: T, z: T) {
    let (xx, xy, xz, yy, yz, zz) = (x * x, x * y, x * z, y * y, y * z, z * z);
    a[1] += x;
    a[2] += y;
    a[3] += z;
    a[4] += xx;
    a[5] += xy;
    a[6] += xz;
    a[7] += yy;
    a[8] += yz;
    a[9] += zz;
    a[10] += xx * x;
    a[11] += xx * y;
    a[12] += xx * z;
    a[13] += xy * y;
    a[14] += xy * z;
    a[15] += xz * z;
    a[16] += yy * y;
    a[17] += yy * z;
    a[18] += yz * z;
    a[19] += zz * z;
}

/// Adds the monomials of degree 4 of one normalised sample, in
/// [`EXPONENTS`] order (positions `LOW..COUNT`).
#[inline(always)]
fn add_high<T: Real>(a: &mut [T; COUNT - LOW], x: T, y: T, z: T) {
    let (xx, xy, xz, yy, yz, zz) = (x * x, x * y, x * z, y * y, y * z, z * z);
    a[0] += xx * xx;
    a[1] += xx * xy;
    a[2] += xx * xz;
    a[3] += xx * yy;
    a[4] += xx * yz;
    a[5] += xx * zz;
    a[6] += xy * yy;
    a[7] += xy * yz;
    a[8] += xy * zz;
    a[9] += xz * zz;
    a[10] += yy * yy;
    a[11] += yy * yz;
    a[12] += yy * zz;
    a[13] += yz * zz;
    a[14] += zz * zz;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exponents_cover_every_monomial_once() {
        let mut seen = [[[false; 5]; 5]; 5];
        for [p, q, r] in EXPONENTS {
            assert!(p + q + r <= 4);
            assert!(!seen[p as usize][q as usize][r as usize]);
            seen[p as usize][q as usize][r as usize] = true;
        }
        for (k, [p, q, r]) in EXPONENTS.iter().enumerate() {
            assert_eq!(INDEX[*p as usize][*q as usize][*r as usize] as usize, k);
        }
    }

    /// The moments pass fed in slices of one block is the pass run over
    /// every row at once, bit for bit, with the same rows cut; in other
    /// slices, to rounding.
    #[test]
    fn the_moments_in_slices_are_the_moments_of_the_whole() {
        let mut rng = crate::test_support::Rng(5);
        let norm: Normalization<f64> = Normalization {
            centre: nalgebra::Vector3::new(3.0, -2.0, 1.0),
            scale: 10.0,
            inv_scale: 0.1,
        };
        let mut samples = [[0.0f64; 3]; 700];
        for (i, s) in samples.iter_mut().enumerate() {
            // Every 10th row off the unit sphere about the centre: cut.
            let r = if i % 10 == 0 { 13.0 } else { 10.0 };
            let d = rng.direction() * r;
            *s = [3.0 + d.x, -2.0 + d.y, 1.0 + d.z];
        }
        let w = nalgebra::Matrix3::identity();
        let cut = Cut {
            map: Projector::new(&norm, &nalgebra::Vector3::zeros(), &w),
            limit: 0.1,
        };
        let gate = Gate::PLAIN;
        let whole = Moments::accumulate_with(&samples, &norm, &gate, Some(&cut), None);
        assert_eq!(whole.count(), 630);
        for slice in [BLOCK, 2 * BLOCK, 37] {
            let mut fed = MomentsPass::new(norm, Some(cut));
            for rows in samples.chunks(slice) {
                fed.feed(rows, &gate);
            }
            if slice == BLOCK {
                assert_eq!(fed.moments(), &whole);
            } else {
                // Block sums added in another grouping: equal to rounding.
                for (got, want) in fed.moments().sums.iter().zip(whole.sums) {
                    assert!((got - want).abs() <= 1e-12 * want.abs().max(1.0), "{slice}");
                }
            }
        }
    }

    /// The written-out monomials are exactly the exponent table's.
    #[test]
    fn written_out_monomials_follow_the_exponent_table() {
        let v = [1.3f64, -0.7, 2.1];
        let (mut low, mut high) = ([0.0; LOW], [0.0; COUNT - LOW]);
        low[0] = 1.0; // the count, `x^0 y^0 z^0`
        add_low(&mut low, v[0], v[1], v[2]);
        add_high(&mut high, v[0], v[1], v[2]);
        let mut acc = [0.0; COUNT];
        for (a, v) in acc.iter_mut().zip(low.into_iter().chain(high)) {
            *a = v;
        }
        for (k, [p, q, r]) in EXPONENTS.iter().enumerate() {
            let want =
                v[0].powi(i32::from(*p)) * v[1].powi(i32::from(*q)) * v[2].powi(i32::from(*r));
            assert!(
                (acc[k] - want).abs() <= 1e-12 * want.abs().max(1.0),
                "{k}: {} vs {want}",
                acc[k]
            );
        }
    }
}
