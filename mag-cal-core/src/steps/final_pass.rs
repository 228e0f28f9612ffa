//! Step 5, the final pass: with the method's calibration, the radial
//! residuals of every row the weights keep (fit error, RMS, tails, the
//! lack of fit over direction cells) and the calibrated directions'
//! coverage.

use crate::tuning::{LOF_CELLS, LOF_MIN_ROWS, LOF_SIGNIFICANCE};
use nalgebra::{Matrix3, Vector3};

use crate::numerics::histogram::LogHistogram;
use crate::numerics::linalg::{eigen_range, larger};
use crate::robust::runs::Runs;
use crate::steps::artificial::Stats;
use crate::steps::moments::BLOCK;
use crate::steps::normalize::{Normalization, Projector};
use crate::steps::rules::Gate;
use crate::{Error, Real, Sample};

/// What the last pass over the samples measures with the final calibration.
pub(crate) struct FinalPass<T: Real> {
    /// RMS of `|u| - 1` over the rows used.
    pub radial_rms: T,
    pub coverage: T,
    pub gram_condition: T,
    /// Rows the gate passed (kept by the rules, inside the screening ball).
    pub passed: usize,
    /// Of those, rows within the residual limit: the rows used.
    pub used: usize,
    /// `1.4826 median||u| - 1|` over the rows the gate passed.
    pub fit_error: T,
    /// See [`crate::Quality::lack_of_fit`].
    pub lack_of_fit: T,
    /// Whether the cell means are off zero beyond the noise.
    pub misfit_significant: bool,
    /// The lack of fit about the mean radial residual (`lack_of_fit` with
    /// `centred`), 0 when not significant. (Only the robust pipeline's
    /// cleanness reads it.)
    #[cfg(feature = "robust")]
    pub lack_of_shape: T,
    /// The mean radial residual `|u| - 1` of the rows used.
    pub mean_residual: T,
    /// The largest `||u| - 1|` over the rows the gate passed. (Only the
    /// robust pipeline's cleanness reads it.)
    #[cfg(feature = "robust")]
    pub max_residual: T,
    /// Skewness of `|u| - 1` over the rows used (reported only by the
    /// robust path, [`crate::judge::quality::Quality::skewness`]).
    #[cfg(feature = "robust")]
    pub skewness: T,
}

/// The sums of the directions `h` that coverage and Gram condition need,
/// as a method's artificial-data pass leaves them (see
/// [`crate::steps::methods::Estimate::directions`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct DirectionSums<T: Real> {
    /// Samples with a direction.
    pub count: usize,
    /// `sum h`.
    pub s_h: Vector3<T>,
    /// `sum h h^T`.
    pub s_hh: Matrix3<T>,
}

impl<T: Real> From<&Stats<T>> for DirectionSums<T> {
    fn from(s: &Stats<T>) -> Self {
        Self {
            count: s.count,
            s_h: s.s_h,
            s_hh: s.s_hh,
        }
    }
}

/// Per-cell sums of the radial residual of the rows used.
type Cells<T> = [(T, u32); LOF_CELLS];

/// The lack-of-fit cell of a calibrated vector.
#[inline(always)]
fn cell<T: Real>([x, y, z]: [T; 3]) -> usize {
    let (ax, ay, az) = (x.abs(), y.abs(), z.abs());
    let neg = |v: T| usize::from(v < T::zero());
    let (face, a, b) = if ax >= ay && ax >= az {
        (neg(x), y, z)
    } else if ay >= az {
        (2 + neg(y), x, z)
    } else {
        (4 + neg(z), x, y)
    };
    face * 4 + neg(a) * 2 + neg(b)
}

/// The lack of fit and whether it is significant, from the cells with at
/// least `LOF_MIN_ROWS` rows: with `m_c` a cell's mean radial residual and
/// `n_c` its rows, the systematic misfit
/// `sqrt(max(0, mean_c(m_c^2 - sigma^2 / n_c)))` (the noise's share of each
/// squared mean removed), in units of the field; significant when
/// `mean_c(n_c m_c^2) / sigma^2` exceeds `LOF_SIGNIFICANCE` (noise alone
/// gives about 1).
///
/// With `centred`, `m_c` is taken about the mean radial residual of those
/// cells' rows: the misfit of the shape alone, without a common offset of
/// the radius (which is the LS fit's own shrinkage under noise).
fn lack_of_fit<T: Real>(cells: &Cells<T>, sigma: T, centred: bool) -> (T, bool) {
    let (mut misfit, mut chi) = (T::zero(), T::zero());
    let mut used = 0usize;
    let noise = sigma * sigma;
    let offset = if centred {
        let (mut sum, mut rows) = (T::zero(), 0usize);
        for &(s, n) in cells.iter().filter(|c| c.1 >= LOF_MIN_ROWS) {
            sum += s;
            rows += n as usize;
        }
        if rows == 0 {
            return (T::zero(), false);
        }
        sum / T::from_count(rows)
    } else {
        T::zero()
    };
    for &(s, n) in cells {
        if n >= LOF_MIN_ROWS {
            let nf = T::from_count(n as usize);
            let mean = s / nf - offset;
            misfit += mean * mean - noise / nf;
            chi += nf * mean * mean;
            used += 1;
        }
    }
    if used == 0 || !(sigma > T::zero()) {
        return (T::zero(), false);
    }
    let cells = T::from_count(used);
    let significant = chi / (noise * cells) > T::lit(LOF_SIGNIFICANCE);
    (larger(misfit / cells, T::zero()).square_root(), significant)
}

/// One pass with the final calibration (normalised coordinates) over the
/// rows `gate` passes outside the spans of `runs`: the robust sigma and the largest of the radial
/// residuals `r = |u| - 1` with `u = W' (x - b')`; the rows within `limit`
/// (all when `None`) are the rows used, and give the RMS of `r`, the
/// lack-of-fit figure, and the coverage and Gram condition of their
/// directions `h = u / |u|`, or of `directions` when given (then the pass
/// need not sum the directions). Out of line: its histogram and cells
/// take stack only while it runs.
#[allow(clippy::too_many_arguments)]
#[inline(never)]
pub(crate) fn final_pass<T: Real, S: Sample>(
    samples: &[S],
    norm: &Normalization<T>,
    centre: &Vector3<T>,
    w: &Matrix3<T>,
    directions: Option<DirectionSums<T>>,
    gate: &Gate<T>,
    runs: &Runs,
    limit: Option<T>,
) -> Result<FinalPass<T>, Error> {
    let map = Projector::new(norm, centre, w);
    let mut sums = FinalSums::new();
    sums.add(samples, &map, gate, runs, limit, directions.is_none());
    sums.finish(directions)
}

/// The running sums of a final pass, which may be taken over several
/// pieces of the samples in turn (a pass in slices; [`crate::background`]).
pub(crate) struct FinalSums<T: Real> {
    hist: LogHistogram,
    cells: Cells<T>,
    acc: Accumulated<T>,
}

impl<T: Real> FinalSums<T> {
    /// No rows yet.
    pub(crate) fn new() -> Self {
        Self {
            hist: LogHistogram::new(),
            cells: [(T::zero(), 0); LOF_CELLS],
            acc: Accumulated {
                passed: 0,
                used: 0,
                #[cfg(feature = "robust")]
                max: T::zero(),
                sums: [T::zero(); 10],
                #[cfg(feature = "robust")]
                cubes: T::zero(),
            },
        }
    }

    /// Adds the rows of `samples` the gate passes outside the spans of
    /// `runs`, under `map`, with the residual `limit`; sums their
    /// directions when `directions` is set.
    pub(crate) fn add<S: Sample>(
        &mut self,
        samples: &[S],
        map: &Projector<T>,
        gate: &Gate<T>,
        runs: &Runs,
        limit: Option<T>,
        directions: bool,
    ) {
        let spec = BlockSpec {
            map,
            limit: limit.unwrap_or(T::MAX),
            directions,
        };
        let (hist, cells, acc) = (&mut self.hist, &mut self.cells, &mut self.acc);
        for (_, prev, block) in runs.pieces(samples, BLOCK) {
            final_block(block, prev, gate, &spec, hist, cells, acc);
        }
    }

    /// The figures of every row added; `directions` replaces the summed
    /// directions when given.
    pub(crate) fn finish(
        &self,
        directions: Option<DirectionSums<T>>,
    ) -> Result<FinalPass<T>, Error> {
        let acc = &self.acc;
        let t = acc.sums;
        let dirs = directions.unwrap_or(DirectionSums {
            count: acc.used,
            s_h: Vector3::new(t[1], t[2], t[3]),
            s_hh: Matrix3::new(t[4], t[5], t[6], t[5], t[7], t[8], t[6], t[8], t[9]),
        });
        if acc.used < crate::MIN_SAMPLES || dirs.count == 0 {
            return Err(Error::TooFewSamples {
                found: acc.used,
                required: crate::MIN_SAMPLES,
            });
        }
        let (coverage, gram_condition) = direction_figures(&dirs)?;
        let fit_error = crate::steps::methods::robust_sigma(&self.hist).unwrap_or(T::zero());
        #[cfg(feature = "robust")]
        let lack_of_shape = match lack_of_fit(&self.cells, fit_error, true) {
            (lack, true) => lack,
            (_, false) => T::zero(),
        };
        let (lack_of_fit, misfit_significant) = lack_of_fit(&self.cells, fit_error, false);
        let (sum, rows) = self
            .cells
            .iter()
            .fold((T::zero(), 0usize), |(s, n), c| (s + c.0, n + c.1 as usize));
        let mean_residual = if rows == 0 {
            T::zero()
        } else {
            sum / T::from_count(rows)
        };
        // The moments about zero of the rows used, then about their mean
        // (the residuals are small: no cancellation to fear).
        #[cfg(feature = "robust")]
        let n = T::from_count(acc.used);
        #[cfg(feature = "robust")]
        let (m1, m2, m3) = (sum / n, t[0] / n, acc.cubes / n);
        #[cfg(feature = "robust")]
        let var = m2 - m1 * m1;
        #[cfg(feature = "robust")]
        let skewness = if var > T::zero() {
            (m3 - T::lit(3.0) * m1 * m2 + T::lit(2.0) * m1 * m1 * m1) / (var * var.square_root())
        } else {
            T::zero()
        };
        Ok(FinalPass {
            radial_rms: (t[0] / T::from_count(acc.used)).square_root(),
            coverage,
            gram_condition,
            passed: acc.passed,
            used: acc.used,
            fit_error,
            lack_of_fit,
            misfit_significant,
            #[cfg(feature = "robust")]
            lack_of_shape,
            mean_residual,
            #[cfg(feature = "robust")]
            max_residual: acc.max,
            #[cfg(feature = "robust")]
            skewness,
        })
    }
}

/// Coverage (`lambda_min` of the covariance of the directions) and the
/// condition number of their Gram matrix `G / n`.
fn direction_figures<T: Real>(d: &DirectionSums<T>) -> Result<(T, T), Error> {
    let n = T::from_count(d.count);
    let mean = [d.s_h.x / n, d.s_h.y / n, d.s_h.z / n];
    // The covariance `G3 / n - mean mean^T` (symmetric: by columns or by
    // rows alike) and `G / n`, by rows, straight from the sums: through
    // nalgebra's temporaries they took 208 bytes of flash more (LS9 +
    // ADC2 without `robust`; 196 with it; `bash bench.sh flash`).
    let mut cov = [[T::zero(); 3]; 3];
    let mut g = [[T::zero(); 4]; 4];
    for (i, (ci, gi)) in cov.iter_mut().zip(g.iter_mut()).enumerate() {
        for (j, (c, x)) in ci.iter_mut().zip(gi.iter_mut()).enumerate() {
            let second = d.s_hh[(i, j)] / n;
            *c = second - mean[i] * mean[j];
            *x = second;
        }
        gi[3] = mean[i];
    }
    g[3] = [mean[0], mean[1], mean[2], T::one()];
    let (coverage, _) = eigen_range(&cov)?;
    let (gmin, gmax) = eigen_range(&g)?;
    let gram_condition = if gmin > T::zero() {
        gmax / gmin
    } else {
        // Singular to rounding: as ill-conditioned as the figure can say.
        T::lit(f64::from(f32::MAX))
    };
    Ok((coverage, gram_condition))
}

/// What the final pass does with each row.
struct BlockSpec<'a, T: Real> {
    map: &'a Projector<T>,
    limit: T,
    /// Sum the directions of the rows used.
    directions: bool,
}

/// The final pass's running counts and sums: `(|u| - 1)^2`, `h` and the
/// upper triangle of `h h^T` of the rows used.
struct Accumulated<T: Real> {
    passed: usize,
    used: usize,
    /// The largest residual (only the robust pipeline reads it).
    #[cfg(feature = "robust")]
    max: T,
    sums: [T; 10],
    /// `sum (|u| - 1)^3` of the rows used (only the robust pipeline's
    /// skewness reads it: without it, not summed: LS9 + ADC2 without
    /// `robust` 21 416 -> 21 360 bytes of flash,
    /// `bash bench.sh flash`).
    #[cfg(feature = "robust")]
    cubes: T,
}

/// The final pass over one block (not inlined: the floating-point
/// registers are then the loop's alone).
///
/// One loop for the plain gate and the others (the plain one converts
/// each row inline, the others call [`Gate::pass`]): a copy of the loop
/// for each took 1 096 bytes of flash more (LS9 + ADC2), for 26 920
/// instructions less on clean data and 25 000 more on contaminated data
/// (n = 1000; the call in the loop leaves no room for the map's constants
/// in the floating-point registers, which are loaded again for each row).
#[inline(never)]
fn final_block<T: Real, S: Sample>(
    block: &[S],
    prev: Option<&S>,
    gate: &Gate<T>,
    spec: &BlockSpec<'_, T>,
    hist: &mut LogHistogram,
    cells: &mut Cells<T>,
    acc: &mut Accumulated<T>,
) {
    let one = T::one();
    let mut a = [T::zero(); 10];
    #[cfg(feature = "robust")]
    let mut cubes = T::zero();
    #[cfg(feature = "robust")]
    let mut max = acc.max;
    let (mut passed, mut used) = (0, 0);
    let mut last = prev;
    for s in block {
        let row = gate.pass(s, last);
        last = Some(s);
        let Some(y) = row else {
            continue;
        };
        let u = spec.map.project(y);
        let [ux, uy, uz] = u;
        passed += 1;
        let q = ux * ux + uy * uy + uz * uz;
        if !(q >= T::MIN_POSITIVE) {
            // At the centre: |u| - 1 = -1, no direction.
            hist.add(one);
            #[cfg(feature = "robust")]
            {
                max = larger(max, one);
            }
            if one <= spec.limit {
                used += 1;
                a[0] += one;
                #[cfg(feature = "robust")]
                {
                    cubes -= one;
                }
            }
            continue;
        }
        let inv = q.rsqrt();
        // |u| - 1 = (|u|^2 - 1) / (|u| + 1): no extra cancellation.
        let e = (q - one) / (q * inv + one);
        let r = e.abs();
        hist.add(r);
        #[cfg(feature = "robust")]
        {
            max = larger(max, r);
        }
        if !(r <= spec.limit) {
            continue;
        }
        used += 1;
        let e2 = e * e;
        a[0] += e2;
        #[cfg(feature = "robust")]
        {
            cubes += e2 * e;
        }
        if let Some(c) = cells.get_mut(cell(u)) {
            c.0 += e;
            c.1 += 1;
        }
        if spec.directions {
            let (hx, hy, hz) = (ux * inv, uy * inv, uz * inv);
            a[1] += hx;
            a[2] += hy;
            a[3] += hz;
            a[4] += hx * hx;
            a[5] += hx * hy;
            a[6] += hx * hz;
            a[7] += hy * hy;
            a[8] += hy * hz;
            a[9] += hz * hz;
        }
    }
    for (t, v) in acc.sums.iter_mut().zip(a) {
        *t += v;
    }
    #[cfg(feature = "robust")]
    {
        acc.cubes += cubes;
        acc.max = max;
    }
    acc.passed += passed;
    acc.used += used;
}
