//! Memory footprint of the calibration on the Cortex-M4F: flash of the
//! code path, stack high-water mark, RAM per stored sample.
//!
//! One source, several builds, chosen at compile time by the environment
//! variable `MAG_CAL_FOOTPRINT` (cargo rebuilds when it changes):
//!
//! - unset or `stack`: the measurement run (on QEMU). Prints
//!   `STACK <method> n=1000 bytes=<b>` for each method on clean samples,
//!   `STACK <method>-contaminated ...` on the same samples with every tenth
//!   row displaced (the robust path, deeper), `STACK <method>-doubtful ...`
//!   with a third of the rows displaced as one stretch (the window starts
//!   of a result in doubt), and
//!   `RAM sample_bytes=<b> store_bytes=<b> store_capacity=<n>`. `bench.sh`
//!   reports the largest for each method.
//! - `baseline`, `ls`, `ls9+adc2`, `all`: minimal programs for the flash
//!   figure. Each reads the same 342 static samples and prints one line;
//!   `baseline` calls nothing, `ls` and `ls9+adc2` call
//!   `calibrate::<f32, [i16; 3]>` with a constant `Config` (so the other
//!   methods are dead code and the linker drops them), `all` with a method
//!   and LS variant chosen at run time (every one the core's cargo
//!   features enable is linked). `bench.sh footprint` builds
//!   each (release profile: opt-level "s", fat LTO) and reports the
//!   difference of `.text + .rodata` against `baseline`: the calibration
//!   code path, including what it pulls in from nalgebra, libm and
//!   compiler-builtins (soft-float `f64` helpers, if any), and excluding
//!   the samples.
//!
//! # Stack high-water mark
//!
//! Painting: all RAM between the end of `.bss`/`.uninit` (`_stack_end`) and
//! the current stack pointer (less 16 bytes) is filled with a pattern, the
//! calibration runs, and the lowest word that no longer holds the pattern
//! marks the deepest stack write; the figure is the main function's stack
//! pointer just before the call minus that address. Limits: a frame that
//! reserves stack it never writes is not seen (an underestimate by at most
//! that unwritten part); a write of the pattern value itself would be missed
//! (the pattern is not a plausible float, pointer or count); interrupt
//! handlers are not included (none runs during the call here); and the
//! figure holds for this build's inlining (release, opt-level "s", fat LTO;
//! a debug build uses far more). QEMU executes the same instructions as the
//! chip, so the stack use is the chip's.
//!
//! # The Cortex-M0+ build
//!
//! `bench.sh footprint` also builds `baseline`, `ls9+adc2` and the stack run
//! for `thumbv6m-none-eabi` (ARMv6-M, no FPU: `f32` arithmetic in software,
//! compiler-builtins' routines counted in the flash). The stack run of that
//! build executes on the same QEMU machine: ARMv6-M's Thumb instructions are
//! a subset of ARMv7-M's, so the Cortex-M4 executes the M0+ build's own
//! instructions and the painted stack is that build's.
//!
//! Run: `./bench.sh footprint` in `firmware-example/`.

#![no_std]
#![no_main]

use core::hint::black_box;

use cortex_m_rt::entry;
use defmt::println;
use firmware_example::platform;
use mag_cal_core::{calibrate, Config, LsVariant, Method, SampleStore};

/// The generated parity vectors: static samples for the flash builds.
#[allow(dead_code)]
mod vectors {
    include!("../../testdata/vectors.rs");
}

/// Which build this is.
const VARIANT: &str = match option_env!("MAG_CAL_FOOTPRINT") {
    Some(v) => v,
    None => "stack",
};

const fn str_eq(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.len() != b.len() {
        return false;
    }
    let mut i = 0;
    while i < a.len() {
        if a[i] != b[i] {
            return false;
        }
        i += 1;
    }
    true
}

const IS_STACK: bool = str_eq(VARIANT, "stack");
const IS_BASELINE: bool = str_eq(VARIANT, "baseline");
const IS_LS: bool = str_eq(VARIANT, "ls");
const IS_ADC2: bool = str_eq(VARIANT, "ls9+adc2");
const IS_ALL: bool = str_eq(VARIANT, "all");
const _: () = assert!(
    IS_STACK || IS_BASELINE || IS_LS || IS_ADC2 || IS_ALL,
    "MAG_CAL_FOOTPRINT must be unset or one of stack, baseline, ls, ls9+adc2, all"
);

/// Samples of the stack measurement (as in the bench).
const N: usize = 1000;
/// Fill pattern of the painted stack.
const PATTERN: u32 = 0xA5C3_5A3C;

#[entry]
fn main() -> ! {
    if IS_STACK {
        stack_run()
    } else {
        flash_build()
    }
}

/// The flash builds: the same input and output, with or without the call.
fn flash_build() -> ! {
    let samples: &[[i16; 3]] = black_box(vectors::CASES[0].samples);
    let ok = if IS_BASELINE {
        !black_box(samples).is_empty()
    } else {
        let method = if IS_LS {
            Method::Ls
        } else if IS_ADC2 {
            Method::Adc2
        } else {
            // Every method reachable: chosen at run time.
            black_box(Method::Adc2)
        };
        // With the method, the LS variant is chosen at run time too.
        let ls = if IS_ALL {
            black_box(LsVariant::Ls9)
        } else {
            LsVariant::Ls9
        };
        let config = Config {
            method,
            ls,
            ..Config::default()
        };
        let result = calibrate::<f32, [i16; 3]>(samples, &config);
        black_box(&result).is_ok()
    };
    println!("flash build {=str}: {=bool}", VARIANT, ok);
    platform::exit(ok)
}

extern "C" {
    /// Lowest address of the stack region (cortex-m-rt's `link.x`): the end
    /// of `.bss` and `.uninit`.
    static _stack_end: u32;
}

/// Fills the free stack below the caller's frame with [`PATTERN`].
#[inline(never)]
fn paint() {
    let sp = cortex_m::register::msp::read() as usize;
    let bottom = core::ptr::addr_of!(_stack_end) as usize;
    let mut a = bottom;
    while a + 4 <= sp - 16 {
        // SAFETY: word-aligned RAM between the end of the statics and this
        // function's own frame: free stack that nothing references.
        unsafe { core::ptr::write_volatile(a as *mut u32, PATTERN) };
        a += 4;
    }
}

/// The lowest address whose word no longer holds [`PATTERN`].
#[inline(never)]
fn lowest_written() -> usize {
    let sp = cortex_m::register::msp::read() as usize;
    let mut a = core::ptr::addr_of!(_stack_end) as usize;
    while a + 4 <= sp {
        // SAFETY: word-aligned RAM between the end of the statics and this
        // function's frame.
        if unsafe { core::ptr::read_volatile(a as *const u32) } != PATTERN {
            return a;
        }
        a += 4;
    }
    sp
}

/// The calibration under measurement, kept out of line: inlined into its
/// caller, its frame would be reserved before the caller reads the stack
/// pointer, and the figure would miss it (8 KB were missed that way).
#[inline(never)]
fn measured_call(
    samples: &[[i16; 3]],
    config: &Config,
) -> Result<mag_cal_core::Fit<f32>, mag_cal_core::Error> {
    calibrate::<f32, [i16; 3]>(samples, config)
}

/// Stack bytes of one calibration with `method` (f32, LS9 start); `None`
/// when it was refused, unless `refusal_ok`.
fn stack_of(samples: &[[i16; 3]], method: Method, refusal_ok: bool) -> Option<usize> {
    let config = Config {
        method,
        ls: LsVariant::Ls9,
        ..Config::default()
    };
    let sp0 = cortex_m::register::msp::read() as usize;
    paint();
    // The inputs pass through `black_box` after painting and the result
    // before reading: the calibration has no side effect the optimiser can
    // see, so without both fences it could move the call across `paint` or
    // `lowest_written` (a measured 640 bytes for ADC2 was such a move).
    let result = measured_call(black_box(samples), black_box(&config));
    black_box(&result);
    let low = lowest_written();
    match result {
        Ok(_) => Some(sp0 - low),
        Err(_) if refusal_ok => Some(sp0 - low),
        Err(e) => {
            defmt::error!("{=str}: calibration failed: {}", method.name(), e);
            None
        }
    }
}

/// A known stack user for the self-check: a 2000-byte local array, every
/// word written (through `black_box`, so none is optimised away).
#[inline(never)]
fn known_stack_user(seed: u32) -> u32 {
    let mut buf = [0u32; 500];
    for (i, w) in buf.iter_mut().enumerate() {
        *w = seed.wrapping_add(i as u32);
    }
    black_box(&mut buf);
    buf.iter().fold(0, |a, &w| a ^ w)
}

/// The painter's self-check: the known user must measure its 2000 bytes
/// plus at most a small frame overhead, else the stack figures are void.
fn stack_self_check() -> bool {
    let sp0 = cortex_m::register::msp::read() as usize;
    paint();
    black_box(known_stack_user(black_box(7)));
    let bytes = sp0 - lowest_written();
    let ok = (2000..=2200).contains(&bytes);
    println!(
        "stack self-check: a 2000-byte local array measures {=usize} bytes ({=str})",
        bytes,
        if ok { "ok" } else { "FAIL" }
    );
    ok
}

/// Prints `STACK <method><suffix> n=<n> bytes=<b>` for every method on
/// `samples`; false when a calibration failed (a refusal only unless
/// `refusal_ok`).
fn stack_lines(samples: &[[i16; 3]], suffix: &str, refusal_ok: bool) -> bool {
    let mut ok = true;
    for method in Method::ALL {
        match stack_of(samples, method, refusal_ok) {
            Some(bytes) => println!(
                "STACK {=str}{=str} n={=usize} bytes={=usize}",
                method.name(),
                suffix,
                samples.len(),
                bytes
            ),
            None => ok = false,
        }
    }
    ok
}

fn stack_run() -> ! {
    use firmware_example::sim::{Scenario, Simulator};

    if !stack_self_check() {
        platform::exit(false)
    }

    let store =
        cortex_m::singleton!(: SampleStore<[i16; 3], N> = SampleStore::new()).expect("taken once");
    let mut sim = Simulator::new(Scenario {
        sweep_samples: N as u32,
        ..Scenario::DEFAULT
    });
    while !store.is_full() {
        if store.push(sim.next_reading().counts).is_err() {
            break;
        }
    }
    let samples = store.as_slice();

    let mut ok = stack_lines(samples, "", false);
    // The same samples with every tenth row displaced by about 0.3 of the
    // field (55 counts on each axis: 95 of 320) and every 50th row zero:
    // the plain attempt with the glitch rules, then the robust path
    // (screening, robust LS, weighted passes), whose stack the clean run
    // does not reach.
    let dirty = cortex_m::singleton!(: [[i16; 3]; N] = [[0; 3]; N]).expect("taken once");
    for (i, (d, s)) in dirty.iter_mut().zip(samples).enumerate() {
        *d = match i % 50 {
            7 => [0; 3],
            k if k % 10 == 3 => s.map(|v| v.saturating_add(55)),
            _ => *s,
        };
    }
    ok &= stack_lines(&dirty[..samples.len()], "-contaminated", false);
    // A third of the rows, one stretch, displaced by about 0.3 of the
    // field: the first result is in doubt (refused for too many outliers),
    // so the window starts are scored and the robust path runs again; a
    // refusal is an answer here.
    let third = samples.len() / 3;
    for (i, (d, s)) in dirty.iter_mut().zip(samples).enumerate() {
        *d = if (third..2 * third).contains(&i) {
            s.map(|v| v.saturating_add(55))
        } else {
            *s
        };
    }
    ok &= stack_lines(&dirty[..samples.len()], "-doubtful", true);
    println!(
        "RAM sample_bytes={=usize} store_bytes={=usize} store_capacity={=usize}",
        core::mem::size_of::<[i16; 3]>(),
        core::mem::size_of::<SampleStore<[i16; 3], N>>(),
        N
    );
    platform::exit(ok)
}
