//! micro:bit v2 wiring: the LSM303AGR on the internal I2C bus (TWIM0), the
//! HAL timer as delay, defmt over RTT, panics through panic-probe.

use crate::Truth;
use defmt_rtt as _;
use microbit::hal::{twim, Timer, Twim};
use microbit::pac::{TIMER0, TWIM0};
use panic_probe as _;

/// What this build runs on, for the log.
pub const NAME: &str = "micro:bit v2, LSM303AGR on the internal I2C bus";

/// The board's peripherals used here.
pub struct Hardware {
    i2c: Twim<TWIM0>,
    timer: Timer<TIMER0>,
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
        }
    }

    /// The I2C bus for the driver, its delay, and the (human) bench.
    pub fn split(&mut self) -> (&mut Twim<TWIM0>, &mut Timer<TIMER0>, Bench) {
        (&mut self.i2c, &mut self.timer, Bench)
    }
}

/// On hardware the "bench" is the person holding the board: it is told what
/// to do, and there is no truth to compare with.
pub struct Bench;

impl Bench {
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
