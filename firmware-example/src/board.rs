//! micro:bit v2 wiring: the LSM303AGR on the internal I2C bus (TWIM0), the
//! HAL timer as delay, the calibration record in the nRF52833's last flash
//! page through the NVMC, defmt over RTT, panics through panic-probe.
//!
//! # The calibration page
//!
//! | address | size | what |
//! |---|---|---|
//! | 0x00000..0x7F000 | 508 KiB | the program (the linker's FLASH region, `build.rs`) |
//! | 0x7F000..0x7F05C | 92 bytes | the calibration record (`mag_cal_core::persist`) |
//! | 0x7F05C..0x80000 | rest of the page | erased (0xFF) |
//!
//! The nRF52833 erases flash in 4 KiB pages and programs 32-bit words; the
//! NVMC is the HAL's `Nvmc`, given exactly this page, so it cannot touch
//! anything else. Each store erases the page once (the nRF52833's flash
//! endures 10 000 erase cycles per page; a calibration is stored once per
//! recalibration, not per boot).

use core::marker::PhantomData;

use crate::storage::FlashStorage;
use crate::{BootOutcome, GlitchKind, Truth};
use defmt_rtt as _;
use microbit::hal::nvmc::Nvmc;
use microbit::hal::{twim, Timer, Twim};
use microbit::pac::{NVMC, TIMER0, TWIM0};
use panic_probe as _;

/// What this build runs on, for the log.
pub const NAME: &str = "micro:bit v2, LSM303AGR on the internal I2C bus";

/// Size of an nRF52833 flash page (the NVMC's erase unit).
const PAGE: usize = 4096;

extern "C" {
    /// First byte of the calibration page (linker symbol from `build.rs`).
    static __mag_cal_page_start: u8;
    /// One past its last byte.
    static __mag_cal_page_end: u8;
}

/// The calibration storage of this build: the record at the start of the
/// last flash page, through the NVMC.
pub type CalibrationStorage = FlashStorage<Nvmc<NVMC>>;

/// Where the calibration is stored, for the log.
pub const STORAGE_NAME: &str = "the last flash page (0x7F000, NVMC)";

/// The board's peripherals used here.
pub struct Hardware {
    i2c: Twim<TWIM0>,
    timer: Timer<TIMER0>,
    storage: CalibrationStorage,
}

impl Hardware {
    /// Takes the board's peripherals; call once.
    pub fn take() -> Self {
        let Some(board) = microbit::Board::take() else {
            defmt::error!("board peripherals already taken");
            exit(false)
        };
        Self {
            i2c: Twim::new(
                board.TWIM0,
                board.i2c_internal.into(),
                twim::Frequency::K100,
            ),
            timer: Timer::new(board.TIMER0),
            storage: FlashStorage::new(Nvmc::new(board.NVMC, calibration_page()), 0),
        }
    }

    /// The I2C bus for the driver, its delay, the (human) bench, and the
    /// calibration storage.
    pub fn split(
        &mut self,
    ) -> (
        &mut Twim<TWIM0>,
        &mut Timer<TIMER0>,
        Bench<'_>,
        &mut CalibrationStorage,
    ) {
        (
            &mut self.i2c,
            &mut self.timer,
            Bench(PhantomData),
            &mut self.storage,
        )
    }
}

/// The calibration page, for the NVMC.
fn calibration_page() -> &'static mut [u8] {
    let start = core::ptr::addr_of!(__mag_cal_page_start) as usize;
    let end = core::ptr::addr_of!(__mag_cal_page_end) as usize;
    if end.wrapping_sub(start) != PAGE || !start.is_multiple_of(PAGE) {
        defmt::error!(
            "calibration page {=usize:#x}..{=usize:#x} is not one aligned page",
            start,
            end
        );
        exit(false)
    }
    // SAFETY: `build.rs` takes this page out of the linker's FLASH region,
    // so no code or data of the program lies in it, and nothing else in the
    // program refers to it; this runs once (`Hardware::take` succeeds only
    // once, with the board's peripherals), so the slice is the page's only
    // reference. Reads and NVMC-driven writes go through it alone.
    unsafe { core::slice::from_raw_parts_mut(start as *mut u8, PAGE) }
}

/// On hardware the "bench" is the person holding the board: it is told what
/// to do, and there is no truth to compare with. (The lifetime matches the
/// simulator's bench, so that code for both can name `Bench<'_>`.)
pub struct Bench<'a>(PhantomData<&'a ()>);

impl Bench<'_> {
    /// Ask for the calibration motion.
    pub fn begin_sweep(&mut self) {
        defmt::info!("turn the board slowly in all directions (every face up, every face down)");
    }

    /// Ask for a level turn.
    pub fn begin_level_turn(&mut self, stops: u32, dwell: u32) {
        defmt::info!(
            "hold the board level and turn it slowly: {} headings of {} samples",
            stops,
            dwell
        );
    }

    /// The true heading: unknown on hardware.
    pub fn true_heading_deg(&self) -> Option<f32> {
        None
    }

    /// The true calibration: unknown on hardware.
    pub fn truth(&self) -> Option<Truth> {
        None
    }

    /// One boot per run: a reset is a real reset.
    pub fn boots(&self) -> u32 {
        1
    }

    /// Nothing to prepare on hardware.
    pub fn before_boot(&mut self, _boot: u32, _storage: &mut CalibrationStorage) {}

    /// Any outcome is fine on hardware (the simulator checks the flow).
    pub fn check_boot(
        &self,
        _boot: u32,
        _outcome: BootOutcome,
        _calibration: &mag_cal_core::Calibration<f32>,
        _previous: Option<&mag_cal_core::Calibration<f32>>,
    ) -> bool {
        true
    }

    /// Unknown on hardware.
    pub fn latched_faulty(&self) -> bool {
        false
    }

    /// Unknown on hardware.
    pub fn injected(&self) -> Option<[u32; 4]> {
        None
    }

    /// Unknown on hardware.
    pub fn latched_glitch(&self) -> Option<GlitchKind> {
        None
    }

    /// Unknown on hardware.
    pub fn injected_glitches(&self) -> Option<[u32; 2]> {
        None
    }
}

/// Ends the program: `probe-rs run` stops at the breakpoint and exits.
pub fn exit(success: bool) -> ! {
    if !success {
        defmt::error!("firmware failed");
    }
    loop {
        cortex_m::asm::bkpt();
    }
}
