//! Instruction counts of the calibration on the emulated Cortex-M4F (QEMU
//! mps2-an386), `f32`, `[i16; 3]` samples.
//!
//! Prints one line per figure,
//!
//! ```text
//! BENCH <name> n=<n> instructions=<count>
//! ```
//!
//! and comment lines starting with `#`. Run it with `./bench.sh` (or
//! `cargo xtask bench`), never with the plain runner: the counts are only
//! instruction counts when QEMU runs with `-icount shift=0`.
//!
//! # How the counting works
//!
//! With `-icount shift=0` QEMU advances its virtual clock by exactly 1 ns
//! per guest instruction executed. The SysTick of mps2-an386, clocked from
//! the processor clock (`CLKSOURCE = 1`), runs at the board's 25 MHz SYSCLK,
//! so one tick is 40 ns = 40 instructions. The firmware checks that factor
//! at start-up against a loop of known length (`subs`/`bne`, 2 instructions
//! per pass; the run fails if the factor is off by more than 0.1 %), and the
//! figures agree with a count of QEMU's per-instruction exec log to 0.1 %
//! (`bench.sh --verify`, see `docs/benchmarks.md`). QEMU does not emulate
//! the DWT cycle counter, and these are instructions, not cycles: on a real
//! Cortex-M4F loads, divides and square roots take several cycles, so
//! expect somewhat more cycles than instructions.
//!
//! The SysTick counter is 24 bits wide (671 M instructions per wrap); its
//! exception counts wraps, so any length can be timed. Each figure is
//! `(ticks - empty) * 40`, where `empty` is the tick count of an empty
//! measurement; the resolution is one tick (40 instructions). Small stages
//! are repeated and averaged to beat that resolution. QEMU is deterministic,
//! so a figure repeats exactly from run to run.
//!
//! # What is measured
//!
//! The input is `n` samples of the firmware's simulated sensor
//! ([`Scenario::DEFAULT`]: 320-count field, +-25 % tilted soft iron, a hard
//! iron of a few hundred counts, 2.5 counts of noise) on one pole-to-pole
//! spiral of `n` samples: a deterministic, evenly covered full sphere.
//!
//! - `ls`, `adc1`, `adc2`, `adc2-iter`, `submle`: one whole
//!   `calibrate::<f32, [i16; 3]>` call with that method (LS9 start), from
//!   the raw samples to the validated result: every pass over the samples
//!   (normalisation, moments, the method's passes, the final quality pass),
//!   the small solves and the degenerate-geometry checks. `adc2` is the
//!   figure of the "LS9 + ADC2" budget.
//! - Stages, from the core's public pieces, on the same data:
//!   `moments` (the LS moment pass), `scatter` (the 10x10 scatter from the
//!   moments), `ls9-solve` (9x9 Cholesky and the quadric to ellipsoid step,
//!   which includes a 3x3 symmetric eigen decomposition), `adc2-stats` (the
//!   artificial-data pass), `adc2-solve` (the closed-form solve on the
//!   statistics, with the 4x4 Gram check), `adc2-run` (`adc2-stats` + `adc2-solve` + the canonical square root),
//!   and proxies for private pieces: `calibration-new` (`Calibration::new`:
//!   one 3x3 symmetric eigen decomposition, as the checks and the canonical
//!   forms do several, plus a determinant and a cube root), `rsqrt` (1000 calls of the core's
//!   `Real::rsqrt` for `f32`, the inverse square root of the per-sample
//!   passes) and `sqrtf` (1000 calls of `libm::sqrtf`, the software square
//!   root behind `f32` `sqrt` in `no_std`). `adc2-other` is `adc2` minus
//!   `moments`, `scatter`, `ls9-solve` and `adc2-run`: the normalisation
//!   pass, the final quality pass and the checks.
//! - Linearity: `adc2` and `ls` at other `n`.
//!
//! Run: `./bench.sh bench` in `firmware-example/`.

#![no_std]
#![no_main]

use core::hint::black_box;
use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use cortex_m_rt::{entry, exception};
use defmt::println;
use firmware_example::platform;
use firmware_example::sim::{Scenario, Simulator, SplitMix64};
// The stages are timed through the core's unstable benchmark path.
use mag_cal_core::__unstable::{adc2, fit_scatter, Moments, Normalization, Stats};
use mag_cal_core::{calibrate, Calibration, Config, LsVariant, Method, Real};
use nalgebra::{Matrix3, Vector3};

/// The sample count of the headline figures.
const N: usize = 1000;
/// Sample counts of the linearity check (the largest sets the buffer size).
const LINEARITY: [usize; 4] = [250, 500, 2000, 4000];
/// Capacity of the sample buffer.
const CAPACITY: usize = 4000;
/// Instructions per SysTick tick: 25 MHz SysTick, 1 ns per instruction.
const INSTRUCTIONS_PER_TICK: u64 = 40;
/// Passes of the calibration loop (2 instructions each).
const CHECK_LOOP_PASSES: u32 = 1_000_000;
/// Repetitions of the small stages.
const SMALL_REPEATS: u32 = 20;

/// SysTick wraps (each 2^24 ticks).
static WRAPS: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    WRAPS.fetch_add(1, Ordering::Relaxed);
}

/// Ticks since the counter started (monotonic, wraps accounted for).
#[inline(always)]
fn now() -> u64 {
    loop {
        let w = WRAPS.load(Ordering::SeqCst);
        let v = SYST::get_current();
        // A wrap between the two reads would pair the old count with the
        // new value: read again.
        if WRAPS.load(Ordering::SeqCst) == w {
            return u64::from(w) * (1 << 24) + u64::from(0x00FF_FFFF - v);
        }
    }
}

/// Ticks of `reps` calls of `f`, minus the cost of an empty measurement.
struct Timer {
    empty: u64,
}

impl Timer {
    fn ticks<R>(&self, reps: u32, mut f: impl FnMut() -> R) -> u64 {
        bench_mark();
        let t0 = now();
        for _ in 0..reps {
            black_box(f());
        }
        let t1 = now();
        bench_mark();
        (t1 - t0).saturating_sub(self.empty)
    }

    /// Instructions of one call of `f` (averaged over `reps` calls).
    fn instructions<R>(&self, reps: u32, f: impl FnMut() -> R) -> u64 {
        let total = self.ticks(reps, f) * INSTRUCTIONS_PER_TICK;
        (total + u64::from(reps) / 2) / u64::from(reps)
    }
}

/// Brackets every timed region, outside the SysTick reads: `bench.sh
/// --verify` counts the instructions QEMU executes between consecutive calls
/// of this function in its exec log (an exact count, independent of the
/// SysTick).
#[no_mangle]
#[inline(never)]
pub extern "C" fn bench_mark() {
    cortex_m::asm::nop();
}

fn report(name: &str, n: usize, instructions: u64) {
    println!(
        "BENCH {=str} n={=usize} instructions={=u64}",
        name, n, instructions
    );
}

/// `passes` passes of a two-instruction loop: exactly `2 * passes`
/// instructions (plus the `mov` that loads the count).
#[inline(never)]
fn known_loop(passes: u32) {
    // SAFETY: a register-only countdown loop; no memory, no stack.
    unsafe {
        core::arch::asm!(
            "2:",
            "subs {0}, {0}, #1",
            "bne 2b",
            inout(reg) passes => _,
            options(nomem, nostack),
        );
    }
}

/// `n` samples of one pole-to-pole spiral of the simulated sensor.
fn fill(buf: &mut [[i16; 3]], n: usize) -> &[[i16; 3]] {
    let mut sim = Simulator::new(Scenario {
        sweep_samples: n as u32,
        ..Scenario::DEFAULT
    });
    for s in buf[..n].iter_mut() {
        *s = sim.next_reading().counts;
    }
    &buf[..n]
}

/// Mean and RMS spread, as the core's normalisation pass computes them
/// (computed here outside the timed regions, to drive the stage timings).
fn normalization(samples: &[[i16; 3]]) -> Normalization<f32> {
    let n = samples.len() as f32;
    let mut c = [0.0f32; 3];
    for s in samples {
        for k in 0..3 {
            c[k] += f32::from(s[k]);
        }
    }
    let c = c.map(|v| v / n);
    let mut ss = 0.0f32;
    for s in samples {
        for k in 0..3 {
            let d = f32::from(s[k]) - c[k];
            ss += d * d;
        }
    }
    let scale = libm::sqrtf(ss / n);
    Normalization {
        centre: Vector3::new(c[0], c[1], c[2]),
        scale,
        inv_scale: 1.0 / scale,
    }
}

/// Contamination kinds for the robust benchmarks (design document,
/// section 14), applied in place to `i16` samples of a 320-count field.
#[derive(Clone, Copy)]
enum Kind {
    /// Wild values anywhere in the i16 range (an I2C glitch).
    Spike,
    /// One axis on the rail.
    Rail,
    /// Exact zero rows.
    Zero,
    /// Runs of 10 repeated rows.
    Stuck,
    /// Isolated rows displaced by 0.3 of the field.
    Displace03,
    /// Isolated rows displaced by one field.
    Displace1,
    /// A contiguous stretch of the spiral displaced by 0.3 of the field.
    Patch,
}

impl Kind {
    const ALL: [Kind; 7] = [
        Kind::Spike,
        Kind::Rail,
        Kind::Zero,
        Kind::Stuck,
        Kind::Displace03,
        Kind::Displace1,
        Kind::Patch,
    ];

    fn bench_name(self) -> &'static str {
        match self {
            Kind::Spike => "robust-spike",
            Kind::Rail => "robust-rail",
            Kind::Zero => "robust-zero",
            Kind::Stuck => "robust-stuck",
            Kind::Displace03 => "robust-displace-0.3",
            Kind::Displace1 => "robust-displace-1",
            Kind::Patch => "robust-patch",
        }
    }

    fn bench_name_iterated(self) -> &'static str {
        match self {
            Kind::Spike => "robust-iter-spike",
            Kind::Rail => "robust-iter-rail",
            Kind::Zero => "robust-iter-zero",
            Kind::Stuck => "robust-iter-stuck",
            Kind::Displace03 => "robust-iter-displace-0.3",
            Kind::Displace1 => "robust-iter-displace-1",
            Kind::Patch => "robust-iter-patch",
        }
    }

    /// Contaminates `fraction` of the rows of `rows`.
    fn apply(self, rows: &mut [[i16; 3]], fraction: f64, seed: u64) {
        let mut rng = SplitMix64::new(seed);
        let n = rows.len();
        let k = (n as f64 * fraction) as usize;
        let field = 320.0;
        let unit = |rng: &mut SplitMix64| {
            // A direction from three uniforms (not uniform on the sphere; a
            // displacement direction needs no more).
            let v = [
                rng.uniform() - 0.5,
                rng.uniform() - 0.5,
                rng.uniform() - 0.5,
            ];
            let norm = libm::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).max(1e-9);
            v.map(|c| c / norm)
        };
        let displaced = |row: [i16; 3], d: [f64; 3], size: f64| {
            let mut out = row;
            for (o, (r, c)) in out.iter_mut().zip(row.iter().zip(d)) {
                *o = (f64::from(*r) + size * field * c).clamp(-32000.0, 32000.0) as i16;
            }
            out
        };
        match self {
            Kind::Patch => {
                let d = unit(&mut rng);
                let start = (rng.next_u64() % (n - k) as u64) as usize;
                for row in rows[start..start + k].iter_mut() {
                    *row = displaced(*row, d, 0.3);
                }
            }
            Kind::Stuck => {
                let mut i = 0;
                let mut done = 0;
                while done < k && i + 11 < n {
                    i += 11 + (rng.next_u64() % 80) as usize;
                    let source = rows[(i - 11).min(n - 1)];
                    for row in rows[(i - 10).min(n)..i.min(n)].iter_mut() {
                        *row = source;
                        done += 1;
                    }
                }
            }
            _ => {
                for _ in 0..k {
                    let i = (rng.next_u64() % n as u64) as usize;
                    let row = rows[i];
                    rows[i] = match self {
                        Kind::Spike => [0, 1, 2].map(|_| (rng.next_u64() % 60000) as i16 - 30000),
                        Kind::Rail => {
                            let mut r = row;
                            r[(rng.next_u64() % 3) as usize] = i16::MAX;
                            r
                        }
                        Kind::Zero => [0; 3],
                        Kind::Displace03 => displaced(row, unit(&mut rng), 0.3),
                        _ => displaced(row, unit(&mut rng), 1.0),
                    };
                }
            }
        }
    }
}

fn config(method: Method) -> Config {
    Config {
        method,
        ls: LsVariant::Ls9,
        ..Config::default()
    }
}

/// Times one stage (`reps` calls, averaged) and reports it.
fn stage<R>(timer: &Timer, name: &str, reps: u32, f: impl FnMut() -> R) -> u64 {
    let count = timer.instructions(reps, f);
    report(name, N, count);
    if reps > 1 {
        println!("# {=str}: mean of {=u32} calls", name, reps);
    }
    count
}

/// One whole calibration; `None` (and an error line) when it fails.
fn calibration(timer: &Timer, name: &str, samples: &[[i16; 3]], method: Method) -> Option<u64> {
    calibration_with(timer, name, samples, &config(method))
}

/// [`calibration`] with a given configuration.
fn calibration_with(timer: &Timer, name: &str, samples: &[[i16; 3]], cfg: &Config) -> Option<u64> {
    let cfg = *cfg;
    let mut result = None;
    let count = timer.instructions(1, || {
        result = Some(calibrate::<f32, [i16; 3]>(
            black_box(samples),
            black_box(&cfg),
        ));
    });
    match result {
        Some(Ok(fit)) => {
            report(name, samples.len(), count);
            let r = &fit.report;
            println!(
                "# {=str} n={=usize}: iterations={=u32} passes={=u32} robust_passes={=u32} dropped={=usize} dwell={=usize} screened={=usize} rejected={=usize} radial_rms={=f32} fit_error={=f32} lack_of_fit={=f32}",
                name,
                samples.len(),
                r.iterations,
                r.passes,
                r.robust_passes,
                r.samples_dropped,
                r.dwell,
                r.screened,
                r.rejected,
                r.radial_rms,
                r.quality.fit_error,
                r.quality.lack_of_fit
            );
            Some(count)
        }
        Some(Err(e)) => {
            defmt::error!("{=str}: calibration failed: {}", name, e);
            None
        }
        None => None,
    }
}

/// Like [`calibration_with`] for samples the calibration must refuse:
/// reports the instructions of the refusal and its reason; `false` when it
/// was accepted.
fn refusal_with(timer: &Timer, name: &str, samples: &[[i16; 3]], cfg: &Config) -> bool {
    let cfg = *cfg;
    let mut result = None;
    let count = timer.instructions(1, || {
        result = Some(calibrate::<f32, [i16; 3]>(
            black_box(samples),
            black_box(&cfg),
        ));
    });
    match result {
        Some(Err(e)) => {
            report(name, samples.len(), count);
            println!("# {=str} n={=usize}: refused: {}", name, samples.len(), e);
            true
        }
        _ => {
            defmt::error!("{=str}: expected a refusal", name);
            false
        }
    }
}

#[entry]
fn main() -> ! {
    let mut cp = cortex_m::Peripherals::take().expect("taken once");
    let syst = &mut cp.SYST;
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(0x00FF_FFFF);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
    // The counter reads 0 until its first reload.
    while SYST::get_current() == 0 {}

    let mut ok = true;

    // The cost of an empty measurement, then the tick factor against a loop
    // of known length.
    let mut timer = Timer { empty: 0 };
    timer.empty = timer.ticks(1, || ());
    let expected = 2 * u64::from(CHECK_LOOP_PASSES);
    let measured =
        timer.ticks(1, || known_loop(black_box(CHECK_LOOP_PASSES))) * INSTRUCTIONS_PER_TICK;
    let error_ppm = (measured as i64 - expected as i64).unsigned_abs() * 1_000_000 / expected;
    println!(
        "# check: {=u64} instructions of a known {=u64}-instruction loop ({=u64} ppm off; empty measurement {=u64} ticks)",
        measured,
        expected,
        error_ppm,
        timer.empty
    );
    if error_ppm > 1000 {
        defmt::error!(
            "SysTick is not {=u64} instructions per tick: is QEMU running with -icount shift=0? (use bench.sh)",
            INSTRUCTIONS_PER_TICK
        );
        platform::exit(false);
    }

    let buf =
        cortex_m::singleton!(: [[i16; 3]; CAPACITY] = [[0; 3]; CAPACITY]).expect("taken once");

    // Whole calibrations at the headline n.
    let samples = fill(buf, N);
    let mut adc2_total = None;
    for method in Method::ALL {
        let r = calibration(&timer, method.name(), samples, method);
        ok &= r.is_some();
        if method == Method::Adc2 {
            adc2_total = r;
        }
    }

    // The plain pipeline (outlier handling off): the estimates of the paper's
    // methods, as before outlier handling existed.
    let plain = Config {
        robust: false,
        ..config(Method::Adc2)
    };
    ok &= calibration_with(&timer, "adc2-plain", samples, &plain).is_some();

    // Contaminated copies of the same samples: 10 % of the rows of each kind
    // (design document, section 14), robust LS9 + ADC2 (the default).
    let dirty = cortex_m::singleton!(: [[i16; 3]; N] = [[0; 3]; N]).expect("taken once");
    for kind in Kind::ALL {
        dirty.copy_from_slice(samples);
        kind.apply(dirty, 0.10, 7);
        let name = kind.bench_name();
        ok &= calibration_with(&timer, name, dirty, &config(Method::Adc2)).is_some();
        let iterated = config(Method::Adc2Iterated);
        ok &= calibration_with(&timer, kind.bench_name_iterated(), dirty, &iterated).is_some();
    }
    // 30 % of the rows as one patch: refused for too many outliers, which
    // puts the first result in doubt, so the window starts are scored and
    // the robust path runs again (the cost of such a refusal).
    dirty.copy_from_slice(samples);
    Kind::Patch.apply(dirty, 0.30, 7);
    ok &= refusal_with(&timer, "robust-patch-0.3", dirty, &config(Method::Adc2));

    // Stages of LS9 + ADC2.
    let norm = normalization(samples);
    let moments = Moments::<f32>::accumulate(samples, &norm);
    let mut stages = 0;
    stages += stage(&timer, "moments", 1, || {
        Moments::<f32>::accumulate(black_box(samples), &norm)
    });
    stages += stage(&timer, "scatter", SMALL_REPEATS, || {
        black_box(&moments).scatter()
    });
    let scatter = moments.scatter();
    stages += stage(&timer, "ls9-solve", SMALL_REPEATS, || {
        fit_scatter(black_box(&scatter), LsVariant::Ls9)
    });
    let Ok(ls) = fit_scatter(&scatter, LsVariant::Ls9) else {
        defmt::error!("ls9 fit failed");
        platform::exit(false)
    };
    stage(&timer, "adc2-stats", 1, || {
        Stats::<f32>::accumulate(black_box(samples), &norm, &ls.centre, &ls.w)
    });
    let Ok(stats) = Stats::<f32>::accumulate(samples, &norm, &ls.centre, &ls.w) else {
        defmt::error!("adc2 statistics failed");
        platform::exit(false)
    };
    stage(&timer, "adc2-solve", SMALL_REPEATS, || {
        adc2::solve(black_box(&stats), &ls.t, &ls.centre)
    });
    let cfg = config(Method::Adc2);
    stages += stage(&timer, "adc2-run", 1, || {
        adc2::run(black_box(samples), &norm, &ls, &cfg)
    });
    if let Some(total) = adc2_total {
        report("adc2-other", N, total.saturating_sub(stages));
    }

    // Proxies for private pieces: `Calibration::new` is one 3x3 symmetric
    // eigen decomposition (the core's own Jacobi, as in the checks and the
    // canonical forms) plus a determinant and a cube root; then the inverse
    // square root of the per-sample passes (and libm's software square
    // root, for comparison).
    let spd = Matrix3::from_fn(|i, j| scatter[(i, j)] + if i == j { 1.0 } else { 0.0 });
    stage(&timer, "calibration-new", SMALL_REPEATS, || {
        Calibration::new([0.0; 3], black_box(spd).into())
    });
    stage(&timer, "rsqrt", 1, || {
        let mut acc = 0.0f32;
        for k in 0..N {
            acc += Real::rsqrt(black_box(0.5 + k as f32 * 1e-3));
        }
        acc
    });
    stage(&timer, "sqrtf", 1, || {
        let mut acc = 0.0f32;
        for k in 0..N {
            acc += libm::sqrtf(black_box(0.5 + k as f32 * 1e-3));
        }
        acc
    });

    // Linearity in n.
    for n in LINEARITY {
        let samples = fill(buf, n);
        ok &= calibration(&timer, "ls", samples, Method::Ls).is_some();
        ok &= calibration(&timer, "adc2", samples, Method::Adc2).is_some();
    }

    ok &= background(&timer);
    platform::exit(ok)
}

/// The background calibrator (`Background<f32, [i16; 3], 288, 6>`, default
/// configuration: 32 buffered samples a step) fed [`BACKGROUND_READINGS`]
/// readings of the simulator's ordinary use, one `push` and one `step` a
/// reading, each call timed on its own: the worst `push`, the worst
/// `step`, a refit's whole cost (the steps from its start to its end;
/// worst and mean) and the mean per reading. Single calls are timed to a
/// SysTick tick (40 instructions), after subtracting the empty measurement.
/// (No `bench_mark`: `bench.sh --verify` checks the other figures.)
fn background(timer: &Timer) -> bool {
    use firmware_example::sim::Motion;
    use mag_cal_core::background::{Background, BackgroundConfig, Stepped};
    type Calibrator = Background<f32, [i16; 3], 288, 6>;
    let Some(Ok(bg)) = cortex_m::singleton!(: Result<Calibrator, mag_cal_core::Error> = Background::new(BackgroundConfig::DEFAULT))
    else {
        return false;
    };
    let mut sim = Simulator::new(Scenario::DEFAULT);
    sim.set_motion(Motion::OrdinaryUse);
    let ticks = |t0: u64, t1: u64| (t1 - t0).saturating_sub(timer.empty) * INSTRUCTIONS_PER_TICK;
    let (mut worst_push, mut worst_step, mut total) = (0u64, 0u64, 0u64);
    let (mut refit, mut worst_refit, mut refit_sum, mut refits) = (0u64, 0u64, 0u64, 0u64);
    let mut adopted = 0u32;
    for _ in 0..BACKGROUND_READINGS {
        let s = sim.next_reading().counts;
        let t0 = now();
        black_box(bg.push(black_box(s)));
        let t1 = now();
        let step = black_box(bg.step());
        let t2 = now();
        let (p, q) = (ticks(t0, t1), ticks(t1, t2));
        worst_push = worst_push.max(p);
        worst_step = worst_step.max(q);
        total += p + q;
        match step {
            Stepped::Working => refit += q,
            Stepped::Adopted | Stepped::Kept | Stepped::Refused(_) => {
                refit += q;
                worst_refit = worst_refit.max(refit);
                refit_sum += refit;
                refits += 1;
                refit = 0;
                adopted += u32::from(step == Stepped::Adopted);
            }
            _ => refit = 0,
        }
    }
    let n = BACKGROUND_READINGS as usize;
    println!(
        "# background: {=u64} refits ({=u32} adopted), {=usize} buffered at the end",
        refits,
        adopted,
        bg.samples().len()
    );
    report("background-push-worst", n, worst_push);
    report("background-step-worst", n, worst_step);
    report("background-refit-worst", n, worst_refit);
    report("background-refit-mean", n, refit_sum / refits.max(1));
    report(
        "background-per-reading-mean",
        n,
        total / BACKGROUND_READINGS,
    );
    bg.calibration().is_some() && refits > 0
}

/// Readings of the background benchmark.
const BACKGROUND_READINGS: u64 = 20_000;
