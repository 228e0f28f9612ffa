//! Link-time proof that `mag-cal-core`'s public API has no reachable panic.
//!
//! The panic handler calls `mag_cal_core_has_a_reachable_panic`, an
//! external function that nothing defines. After optimisation (the
//! firmware's `opt-level = "s"`, fat LTO, one codegen unit) the handler is
//! only kept when some panic call survives in the code reachable from
//! `main`; then the link fails with
//! `undefined symbol: mag_cal_core_has_a_reachable_panic`. A successful
//! link therefore shows that no panic (bounds check, `unwrap`, `expect`,
//! `assert!`, division by zero, ...; integer overflow checks only when
//! built with `CARGO_PROFILE_RELEASE_OVERFLOW_CHECKS=true`) is reachable
//! from the calls below, for any input.
//!
//! Every input comes through [`opaque`] (`read_volatile`), and every slice
//! is rebuilt from a volatile pointer and length, so the optimiser knows
//! nothing about the values, lengths, configuration or the method chosen:
//! no branch can be folded away on the grounds of a known input. Every
//! result goes into [`black_box`], so nothing is dropped as unused.
//!
//! The feature `canary` adds one deliberate panic path: the check must then
//! fail, which `check.sh` verifies first. See `check.sh` and
//! `docs/robustness.md`.

#![no_std]
#![no_main]
// A build with only some entry point groups leaves the others' helpers
// unused.
#![cfg_attr(
    not(all(
        feature = "calibrate",
        feature = "calibration",
        feature = "align",
        feature = "heading",
        feature = "store",
        feature = "collector",
        feature = "persist"
    )),
    allow(unused_imports, dead_code)
)]

use core::hint::black_box;
use core::panic::PanicInfo;
use core::ptr::{addr_of, addr_of_mut, read_volatile};

use cortex_m_rt::entry;
use mag_cal_core::align::{procrustes, AlignedCalibration};
use mag_cal_core::collector::Collector;
use mag_cal_core::heading::{
    heading_deg, tilt_compensated_heading_deg, wrap_deg, HeadingSmoother, DEFAULT_WINDOW,
};
use mag_cal_core::{calibrate, persist, Calibration, Config, Method, Real, Sample, SampleStore};

extern "C" {
    /// Defined nowhere: a reference to it that survives optimisation fails
    /// the link. (When it does, `check.sh` links the same code again with
    /// `--defsym` pointing it at cortex-m-rt's `DefaultHandler_`, so that
    /// the panic call sites can be listed from the ELF.)
    fn mag_cal_core_has_a_reachable_panic() -> !;
}

#[panic_handler]
fn panic(_info: &PanicInfo) -> ! {
    // SAFETY: a build in which this call survives does not link (or, with
    // `--defsym`, is only inspected, never run).
    unsafe { mag_cal_core_has_a_reachable_panic() }
}

/// Keeps a result alive: the optimiser must assume it is used.
#[inline(always)]
fn keep<T>(value: T) {
    let _ = black_box(value);
}

/// A value the optimiser cannot know: a volatile read.
#[inline(always)]
fn opaque<T: Copy>(place: &T) -> T {
    // SAFETY: `place` is a valid, aligned reference to an initialised `T`.
    unsafe { read_volatile(place) }
}

/// [`opaque`] for a value that is not `Copy` (a sample store): a bitwise
/// copy through a volatile read.
#[inline(always)]
fn opaque_store<S: Sample, const N: usize>(place: &SampleStore<S, N>) -> SampleStore<S, N> {
    // SAFETY: `place` is valid and aligned; the store's elements are `Copy`
    // (samples), so the bitwise copy owns nothing the original also owns.
    unsafe { read_volatile(place) }
}

/// An opaque configuration: the default one, through a volatile read, so
/// that every field (the method and LS variant included) is unknown to the
/// optimiser and every method and variant stays reachable. Built from
/// `Config::default()` rather than a literal so that fields added to
/// `Config` are covered without a change here.
#[inline(always)]
fn opaque_config() -> Config {
    opaque(&Config::default())
}

/// A slice given by address and length, both read through [`opaque`].
///
/// The statics below point at real buffers, so the slices are valid should
/// the binary ever run; to the optimiser the address and the length are
/// arbitrary (lengths up to `usize::MAX / size_of::<T>()`).
#[repr(C)]
struct RawSlice<T: 'static> {
    ptr: *const T,
    len: usize,
}

impl<T> Clone for RawSlice<T> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<T> Copy for RawSlice<T> {}

// SAFETY: the descriptors are never written; the buffers they point to are
// immutable statics.
unsafe impl<T> Sync for RawSlice<T> {}

impl<T> RawSlice<T> {
    const fn of<const N: usize>(buffer: &'static [T; N]) -> Self {
        Self {
            ptr: buffer.as_ptr(),
            len: N,
        }
    }

    /// The slice, from an opaque copy of the descriptor.
    #[inline(always)]
    fn get(&'static self) -> &'static [T] {
        let raw = opaque(self);
        // SAFETY: the descriptor statics hold a pointer to and the length
        // of a `'static` buffer, and are never modified; the volatile read
        // only hides that from the optimiser.
        unsafe { core::slice::from_raw_parts(raw.ptr, raw.len) }
    }
}

// --- Input buffers and their descriptors -----------------------------------

static BUF_I16: [[i16; 3]; 4] = [[1, 2, 3], [-4, 5, 6], [7, -8, 9], [i16::MAX, i16::MIN, 0]];
static BUF_I32: [[i32; 3]; 2] = [[1, 2, 3], [i32::MAX, i32::MIN, 0]];
static BUF_F32: [[f32; 3]; 3] = [[1.0, 2.0, 3.0], [f32::NAN, 0.0, -1.0], [1e38, -1e-40, 0.5]];
static BUF_F64: [[f64; 3]; 3] = [
    [1.0, 2.0, 3.0],
    [f64::NAN, 0.0, -1.0],
    [1e300, -1e-320, 0.5],
];

static SAMPLES_I16: RawSlice<[i16; 3]> = RawSlice::of(&BUF_I16);
static SAMPLES_I32: RawSlice<[i32; 3]> = RawSlice::of(&BUF_I32);
static SAMPLES_F32: RawSlice<[f32; 3]> = RawSlice::of(&BUF_F32);
static SAMPLES_F64: RawSlice<[f64; 3]> = RawSlice::of(&BUF_F64);
// Second slices for the pairs of `procrustes` (lengths may differ).
static REFERENCE_F32: RawSlice<[f32; 3]> = RawSlice::of(&BUF_F32);
static REFERENCE_F64: RawSlice<[f64; 3]> = RawSlice::of(&BUF_F64);

/// Scalars and small arrays, per precision.
struct Scalars<T: 'static> {
    hard_iron: [T; 3],
    soft_iron: [[T; 3]; 3],
    rotation: [[T; 3]; 3],
    raw: [T; 3],
    accel: [T; 3],
    heading: T,
    pushes: u32,
    window: usize,
}

static SCALARS_F32: Scalars<f32> = Scalars {
    hard_iron: [1.0, 2.0, 3.0],
    soft_iron: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    raw: [4.0, 5.0, 6.0],
    accel: [0.0, 0.0, -9.81],
    heading: 10.0,
    pushes: 20,
    window: DEFAULT_WINDOW,
};

static SCALARS_F64: Scalars<f64> = Scalars {
    hard_iron: [1.0, 2.0, 3.0],
    soft_iron: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    raw: [4.0, 5.0, 6.0],
    accel: [0.0, 0.0, -9.81],
    heading: 10.0,
    pushes: 20,
    window: DEFAULT_WINDOW,
};

/// Spans for `Runs::from_spans` (a selection read back from storage).
static BUF_SPANS: [(usize, usize); 2] = [(3, 9), (usize::MAX - 1, usize::MAX)];
static SPANS: RawSlice<(usize, usize)> = RawSlice::of(&BUF_SPANS);

/// Bytes for `persist::from_bytes` and `crc32`.
static BUF_BYTES: [u8; 8] = *b"MCAL\x01\x04\0\0";
static BYTES: RawSlice<u8> = RawSlice::of(&BUF_BYTES);
/// The collector's minimum angle.
static ANGLE: f32 = 4.0;

/// Stores in an arbitrary state (their length included): copied with a
/// volatile read before each use.
static STORE_I16: SampleStore<[i16; 3], 64> = SampleStore::new();
static STORE_F32: SampleStore<[f32; 3], 64> = SampleStore::new();

/// `calibrate` for one sample type and precision, every method and LS
/// variant (the configuration is opaque), then the fit's accessors.
#[cfg(feature = "calibrate")]
#[inline(never)]
fn fit<T: Real, S: Sample>(samples: &'static RawSlice<S>, raw: [T; 3]) {
    let config = opaque_config();
    let result = calibrate::<T, S>(samples.get(), &config);
    if let Ok(fit) = &result {
        let cal = &fit.calibration;
        keep(cal.apply(raw));
        keep(cal.apply_scaled(raw));
        keep(cal.shape());
        for warning in fit.report.warnings.iter() {
            keep(warning);
        }
        // Classifying rows afterwards, with the fit's selection and with an
        // arbitrary one (a selection read back from storage).
        for class in fit.report.selection.classify(cal, samples.get()) {
            keep(class);
        }
        let selection = opaque(&fit.report.selection);
        for class in selection.classify(cal, samples.get()) {
            keep(class);
        }
        if let Some(runs) = mag_cal_core::Runs::from_spans(SPANS.get()) {
            let selection = mag_cal_core::Selection { runs, ..selection };
            for class in selection.classify(cal, samples.get()) {
                keep(class);
            }
            keep(runs.contains(opaque(&7usize)));
            keep(runs.missed());
        }
    }
    keep(result);
}

/// `Calibration::new` and its methods, `AlignedCalibration`.
#[cfg(feature = "calibration")]
#[inline(never)]
fn calibration<T: Real>(scalars: &'static Scalars<T>) {
    let b = opaque(&scalars.hard_iron);
    let w = opaque(&scalars.soft_iron);
    let r = opaque(&scalars.rotation);
    let raw = opaque(&scalars.raw);
    let cal = Calibration::new(b, w);
    if let Ok(cal) = &cal {
        keep(cal.apply(raw));
        keep(cal.apply_scaled(raw));
        // Readings as a driver returns them.
        keep(cal.apply(opaque(&(1_i16, -2_i16, 3_i16))));
        keep(cal.shape());
        keep(cal.soft_iron());
        keep(cal.hard_iron());
        keep(cal.field_strength());
        let aligned = AlignedCalibration::new(*cal, r);
        if let Ok(aligned) = &aligned {
            keep(aligned.apply(raw));
            keep(aligned.rotation());
            keep(aligned.calibration());
        }
        keep(aligned);
    }
    // Offsets-only refits of that calibration on the samples.
    if let Ok(cal) = &cal {
        for strength in [
            mag_cal_core::offsets::Strength::Unchanged,
            mag_cal_core::offsets::Strength::Unknown,
        ] {
            let strength = opaque(&strength);
            keep(mag_cal_core::offsets::refit_offsets(
                SAMPLES_I16.get(),
                cal,
                strength,
            ));
            keep(mag_cal_core::offsets::refit_offsets(
                SAMPLES_F32.get(),
                cal,
                strength,
            ));
        }
    }
    keep(cal);
    // Planar fits of the samples, and every accessor of a planar
    // calibration built from opaque parts.
    let config = mag_cal_core::planar::PlanarConfig::with_up(opaque(&[0.0, 0.0, -1.0]));
    let config = opaque(&config);
    keep(mag_cal_core::planar::calibrate_planar::<f32, _>(
        SAMPLES_I16.get(),
        &config,
    ));
    keep(mag_cal_core::planar::calibrate_planar::<f32, _>(
        SAMPLES_F32.get(),
        &config,
    ));
    let parts = opaque(&scalars.rotation);
    if let Ok(planar) = mag_cal_core::planar::PlanarCalibration::new(
        parts[0],
        raw,
        [parts[1], parts[2]],
        opaque(&raw[0]),
    ) {
        keep(planar.apply(raw));
        keep(planar.turn_angle_deg(raw));
        keep(planar.heading_deg(opaque(&(1_i16, -2_i16, 3_i16))));
        keep(planar.plane_strength());
        keep(planar.aligned(raw, opaque(&raw[1])));
    }
}

/// `align::procrustes` on two opaque slices.
#[cfg(feature = "align")]
#[inline(never)]
fn align<T: Real>(pairs: [&'static RawSlice<[T; 3]>; 2]) {
    keep(procrustes::<T>(pairs[0].get(), pairs[1].get()));
}

/// The heading functions and the smoother (any window, any number of
/// pushes, so that its ring position and fill are unknown at every push).
#[cfg(feature = "heading")]
#[inline(never)]
fn heading<T: Real>(scalars: &'static Scalars<T>) {
    let field = opaque(&scalars.raw);
    let accel = opaque(&scalars.accel);
    keep(heading_deg(field));
    keep(tilt_compensated_heading_deg(field, accel));
    keep(wrap_deg(opaque(&scalars.heading)));

    let mut default: HeadingSmoother<T, DEFAULT_WINDOW> = HeadingSmoother::new();
    let smoother = HeadingSmoother::<T, 128>::with_window(opaque(&scalars.window));
    if let Ok(mut smoother) = smoother {
        for _ in 0..opaque(&scalars.pushes) {
            let h = opaque(&scalars.heading);
            keep(smoother.push(h));
            keep(default.push(h));
            if opaque(&scalars.pushes) == 7 {
                smoother.clear();
            }
        }
        keep(smoother.mean());
        keep(smoother.len());
        keep(smoother);
    }
    keep(default.mean());
    keep(default);
}

/// `SampleStore::push` on a store in an arbitrary state.
#[cfg(feature = "store")]
#[inline(never)]
fn stores() {
    let mut store = opaque_store(&STORE_I16);
    keep(store.push(opaque(&BUF_I16[0])));
    keep(store.as_slice());
    keep(store);

    let mut store = opaque_store(&STORE_F32);
    keep(store.push(opaque(&BUF_F32[0])));
    keep(store.is_full());
    keep(store.len());
    keep(store);
}

/// `collector::Collector`: any spacing, any number of offers, so that its
/// state is arbitrary at every call.
#[cfg(feature = "collector")]
#[inline(never)]
fn collector<S: Sample, T: Real>(samples: &'static RawSlice<S>, scalars: &'static Scalars<T>) {
    let mut collector: Collector<S, 300> = Collector::new(opaque(&ANGLE));
    let offered = samples.get();
    for _ in 0..opaque(&scalars.pushes) {
        for sample in offered {
            keep(collector.offer(*sample));
        }
        keep(collector.progress());
        if opaque(&scalars.pushes) == 3 {
            collector.clear();
        }
    }
    keep(collector.is_ready());
    keep(collector.centre());
    keep(collector.len());
    keep(collector.samples());
    keep(collector);
    let mut default: Collector<S, 8> = Collector::default();
    if let Some(first) = offered.first() {
        keep(default.offer(*first));
    }
    keep(default);
}

/// `background::Background`: any readings, any number of pushes and
/// steps, every accessor.
#[cfg(feature = "collector")]
#[inline(never)]
fn background<S: Sample, T: Real>(samples: &'static RawSlice<S>, scalars: &'static Scalars<T>) {
    let config = opaque(&mag_cal_core::background::BackgroundConfig::DEFAULT);
    let made: Result<mag_cal_core::background::Background<T, S, 96, 2>, _> =
        mag_cal_core::background::Background::new(config);
    let Ok(mut bg) = made else {
        return;
    };
    for _ in 0..opaque(&scalars.pushes) {
        for sample in samples.get() {
            keep(bg.push(*sample));
            keep(bg.step());
        }
        if let Some(first) = samples.get().first() {
            keep(bg.update(*first));
        }
    }
    keep(bg.calibration());
    keep(bg.current());
    keep(bg.age());
    keep(bg.is_stale());
    keep(bg.progress());
    keep(bg.cells_filled());
    keep(bg.samples());
    keep(bg.counters());
    keep(bg.is_working());
}

/// `persist`: `from_bytes` and `crc32` on any bytes, `to_bytes` on what
/// `from_bytes` accepts.
#[cfg(feature = "persist")]
#[inline(never)]
fn persist<T: Real>(bytes: &'static RawSlice<u8>) {
    let data = bytes.get();
    keep(persist::crc32(data));
    let restored = persist::from_bytes::<T>(data);
    if let Ok(cal) = &restored {
        keep(persist::to_bytes(cal));
    }
    keep(restored);
}

/// Pointers from C: valid or null, the optimiser cannot tell which.
#[cfg(feature = "ffi")]
#[inline(always)]
fn maybe_null<T>(p: *const T) -> *const T {
    if opaque(&SCALARS_F32.window) == 0 {
        core::ptr::null()
    } else {
        p
    }
}

/// The C API: every function, on opaque arguments (a configuration read
/// back from memory may hold any method number, a length any value).
#[cfg(feature = "ffi")]
#[inline(never)]
fn ffi() {
    use mag_cal_ffi::*;
    static CONFIG: MagcalConfig = MagcalConfig {
        method: MAGCAL_METHOD_ADC2,
        ls: MAGCAL_LS_LS9,
        robust: true,
        max_iterations: 50,
        max_passes: 50,
        expected_field_strength: 0.0,
        noise_sigma: 0.0,
        thresholds: MagcalThresholds {
            warn_samples: 50,
            refuse_flatness: 0.03,
            warn_flatness: 0.1,
            refuse_quadric_gap: 3.0,
            gap_noise_limit: 0.05,
            warn_quadric_gap: 10.0,
            refuse_distortion: 16.0,
            refuse_coverage: 0.05,
            warn_gram_condition: 20.0,
            refuse_field_deviation: 0.25,
            warn_spread_over_noise: 10.0,
            refuse_fit_error: 0.2,
            warn_fit_error: 0.05,
            refuse_outlier_share: 0.25,
            refuse_lack_of_fit: 0.01,
            refuse_skewness: -0.6,
        },
    };
    static mut RESULT: MaybeResult = MaybeResult([0; 64]);
    static mut COLLECTOR: MagcalCollector = MagcalCollector {
        storage: [0; MAGCAL_COLLECTOR_WORDS],
    };
    static mut SMOOTHER: MagcalSmoother = MagcalSmoother {
        storage: [0; MAGCAL_SMOOTHER_WORDS],
    };
    static mut OUT3: [f32; 3] = [0.0; 3];
    static mut RECORD: [u8; MAGCAL_RECORD_BYTES] = [0; MAGCAL_RECORD_BYTES];
    /// Room for a `MagcalResult`, 8-aligned.
    #[repr(C, align(8))]
    struct MaybeResult([u64; 64]);
    const _: () = assert!(core::mem::size_of::<MagcalResult>() <= 512);

    let config = opaque(&CONFIG);
    let samples_i16 = SAMPLES_I16.get();
    let samples_f32 = SAMPLES_F32.get();
    let count = opaque(&SCALARS_F32.window);
    let result = addr_of_mut!(RESULT).cast::<MagcalResult>();
    let out3 = addr_of_mut!(OUT3).cast::<f32>();
    let raw = maybe_null(SCALARS_F32.raw.as_ptr());
    // SAFETY: every pointer is null or points to a valid static of the
    // documented size (the counts do not exceed the buffers' lengths when
    // the samples are read: `count` is clamped below).
    unsafe {
        let mut config_out = config;
        keep(magcal_config_default(&mut config_out));
        let n_i16 = count.min(samples_i16.len());
        let n_f32 = count.min(samples_f32.len());
        keep(magcal_calibrate_i16(
            maybe_null(samples_i16.as_ptr()),
            n_i16,
            &config,
            result,
        ));
        keep(magcal_calibrate_f32(
            maybe_null(samples_f32.as_ptr()),
            n_f32,
            &config,
            result,
        ));
        keep(magcal_calibrate_i16_f64(
            maybe_null(samples_i16.as_ptr()),
            n_i16,
            &config,
            result,
        ));
        keep(magcal_calibrate_f32_f64(
            maybe_null(samples_f32.as_ptr()),
            n_f32,
            &config,
            result,
        ));
        let cal = maybe_null(addr_of!((*result).calibration));
        keep(magcal_apply(cal, raw, out3));
        keep(magcal_apply_i16(cal, maybe_null(BUF_I16[3].as_ptr()), out3));
        keep(magcal_heading_deg(raw));
        keep(magcal_tilt_heading_deg(
            raw,
            maybe_null(SCALARS_F32.accel.as_ptr()),
            out3,
        ));
        keep(magcal_smoother_init(addr_of_mut!(SMOOTHER), count as u32));
        keep(magcal_smoother_push(
            addr_of_mut!(SMOOTHER),
            opaque(&SCALARS_F32.raw[0]),
            out3,
        ));
        keep(magcal_collector_init(
            addr_of_mut!(COLLECTOR),
            opaque(&ANGLE),
        ));
        keep(magcal_collector_offer(
            addr_of_mut!(COLLECTOR),
            maybe_null(BUF_I16[0].as_ptr()),
        ));
        let mut progress = MagcalProgress {
            samples: 0,
            cells_visited: 0,
            cells: 0,
            percent: 0,
            ready: false,
            visited: 0,
        };
        keep(magcal_collector_progress(
            addr_of!(COLLECTOR),
            &mut progress,
        ));
        let mut n = 0usize;
        keep(magcal_collector_samples(addr_of!(COLLECTOR), &mut n));
        let record = addr_of_mut!(RECORD).cast::<u8>();
        keep(magcal_to_bytes(cal, record, count));
        let bytes = BYTES.get();
        keep(magcal_from_bytes(
            maybe_null(bytes.as_ptr()),
            bytes.len(),
            addr_of_mut!((*result).calibration),
        ));
        keep(magcal_error_str(opaque(&SCALARS_F32.window) as i32));
        // The refusal the calls above left (any status and figures), into
        // a buffer of any size up to its length, or none.
        static mut MESSAGE: [u8; 256] = [0; 256];
        keep(magcal_refusal_message(
            maybe_null(addr_of!((*result).refusal)),
            maybe_null(addr_of!(MESSAGE).cast::<core::ffi::c_char>()).cast_mut(),
            count.min(256),
        ));
        keep(magcal_refusal_name(maybe_null(addr_of!((*result).refusal))));
    }
}

/// A deliberate panic path the optimiser cannot remove: the check must
/// fail with this feature.
#[cfg(feature = "canary")]
#[inline(never)]
fn canary() {
    let index = opaque(&SCALARS_F32.window);
    keep(BUF_I16[index]);
}

#[entry]
fn main() -> ! {
    loop {
        for (m, name) in Method::ALL.iter().map(|m| (m, m.name())) {
            keep((m, name, Method::from_name(opaque(&name))));
        }
        #[cfg(feature = "calibrate")]
        {
            fit::<f32, [i16; 3]>(&SAMPLES_I16, opaque(&SCALARS_F32.raw));
            fit::<f64, [i16; 3]>(&SAMPLES_I16, opaque(&SCALARS_F64.raw));
            fit::<f32, [i32; 3]>(&SAMPLES_I32, opaque(&SCALARS_F32.raw));
            fit::<f64, [i32; 3]>(&SAMPLES_I32, opaque(&SCALARS_F64.raw));
            fit::<f32, [f32; 3]>(&SAMPLES_F32, opaque(&SCALARS_F32.raw));
            fit::<f64, [f32; 3]>(&SAMPLES_F32, opaque(&SCALARS_F64.raw));
            fit::<f32, [f64; 3]>(&SAMPLES_F64, opaque(&SCALARS_F32.raw));
            fit::<f64, [f64; 3]>(&SAMPLES_F64, opaque(&SCALARS_F64.raw));
        }
        #[cfg(feature = "calibration")]
        {
            calibration::<f32>(&SCALARS_F32);
            calibration::<f64>(&SCALARS_F64);
        }
        #[cfg(feature = "align")]
        {
            align::<f32>([&SAMPLES_F32, &REFERENCE_F32]);
            align::<f64>([&SAMPLES_F64, &REFERENCE_F64]);
        }
        #[cfg(feature = "heading")]
        {
            heading::<f32>(&SCALARS_F32);
            heading::<f64>(&SCALARS_F64);
        }
        #[cfg(feature = "store")]
        stores();
        #[cfg(feature = "collector")]
        {
            collector::<[i16; 3], f32>(&SAMPLES_I16, &SCALARS_F32);
            collector::<[f32; 3], f32>(&SAMPLES_F32, &SCALARS_F32);
            collector::<[f64; 3], f64>(&SAMPLES_F64, &SCALARS_F64);
            background::<[i16; 3], f32>(&SAMPLES_I16, &SCALARS_F32);
            background::<[f32; 3], f32>(&SAMPLES_F32, &SCALARS_F32);
        }
        #[cfg(feature = "persist")]
        {
            persist::<f32>(&BYTES);
            persist::<f64>(&BYTES);
        }
        #[cfg(feature = "ffi")]
        ffi();
        #[cfg(feature = "canary")]
        canary();
        // The buffers stay in the image whatever is enabled.
        keep(addr_of!(BUF_I32));
        keep(addr_of!(BUF_BYTES));
        keep(addr_of!(ANGLE));
    }
}
