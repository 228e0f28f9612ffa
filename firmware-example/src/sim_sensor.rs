//! QEMU wiring: a register-level LSM303AGR on a simulated I2C bus.
//!
//! [`SimI2c`] implements `embedded_hal::i2c::I2c`, so the unmodified
//! `lsm303agr` driver talks to [`SimLsm303agr`] exactly as it talks to the
//! chip on the micro:bit's internal bus. The physics comes from
//! [`crate::sim`].
//!
//! # Registers modelled
//!
//! Accelerometer, address 0x19 (multi-byte access auto-increments when bit 7
//! of the sub-address is set, as on the chip):
//!
//! | reg | name | model |
//! |---|---|---|
//! | 0x0F | WHO_AM_I_A | reads 0x33 |
//! | 0x1F | TEMP_CFG_REG_A | stored (`init()` writes TEMP_EN) |
//! | 0x20-0x25 | CTRL_REG1_A..CTRL_REG6_A | stored (`init()` writes BDU in CTRL_REG4_A) |
//! | 0x27 | STATUS_REG_A | reads 0: no acceleration is simulated |
//! | 0x2E | FIFO_CTRL_REG_A | stored |
//!
//! Magnetometer, address 0x1E (the sub-address always auto-increments, bit 7
//! ignored, as on the chip):
//!
//! | reg | name | model |
//! |---|---|---|
//! | 0x4F | WHO_AM_I_M | reads 0x40 |
//! | 0x60 | CFG_REG_A_M | stored; MD (bits 1:0) and ODR (bits 3:2) honoured, SOFT_RST resets |
//! | 0x61 | CFG_REG_B_M | stored |
//! | 0x62 | CFG_REG_C_M | stored (`init()` writes BDU) |
//! | 0x67 | STATUS_REG_M | Zyxda/xda/yda/zda when a new sample is latched, Zyxor/.. on overrun |
//! | 0x68-0x6D | OUTX_L_REG_M..OUTZ_H_REG_M | latched sample, little-endian i16 |
//!
//! Any other register, or a write to a read-only one, is answered with a
//! NACK error, so a driver change that touches something unmodelled fails
//! loudly instead of reading zeros.
//!
//! # Time
//!
//! QEMU time means nothing here, so the simulated clock is the status poll:
//! each read of STATUS_REG_M advances it by 10 ms. In continuous mode
//! (MD = 00) a new sample is latched every `100 Hz / ODR` polls (10 Hz: 10,
//! 20 Hz: 5, 50 Hz: 2, 100 Hz: 1); in single mode (MD = 01) one sample is
//! latched and the mode returns to idle (MD = 11); idle produces nothing, and
//! a firmware that never starts the magnetometer would poll forever (QEMU's
//! timeout then fails the run). Reading an axis' high byte clears its data
//! ready and overrun bits, and Zyxda/Zyxor once all three are read.
//!
//! # Faults (`--features faults`)
//!
//! With [`Faults::RUN`] in the scenario the bus and the registers misbehave
//! on the simulator's schedule ([`crate::sim`]):
//!
//! - NACK bursts: after every `nack_every` transactions answered, the next
//!   1, 2, .., `nack_burst_max` transactions (in turn) are refused with an
//!   address NACK, before any register is touched (no side effect, so a
//!   refused STATUS_REG_M read does not advance the clock);
//! - stuck output: a sample marked stuck is not written to the output
//!   registers, yet STATUS_REG_M reports new data as usual, so the driver
//!   reads the previous sample again.
//!
//! Saturation, the passing magnet and the glitches (wild and displaced
//! readings) are in the physics; [`Bench`] reports each latched sample's
//! faults and glitch, and the counts injected, for the run's self-check.
//!
//! # Flash stand-in
//!
//! QEMU's mps2-an386 has no nRF52 NVMC (its "flash" is plain SRAM and there
//! is no flash controller), so the calibration record goes to [`SimFlash`]:
//! one 4 KiB page in RAM with NOR-flash semantics (erase sets every byte to
//! 0xFF, a write can only clear bits, words of 4 bytes), implementing the
//! same `embedded-storage` traits as the board's `Nvmc`. It lives in
//! [`Hardware`] for the whole run, so it survives the simulated reboots of
//! the application (see `src/main.rs`).

use core::cell::RefCell;

use embedded_hal::delay::DelayNs;
use embedded_hal::i2c::{self, ErrorKind, NoAcknowledgeSource, Operation};
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use nalgebra::{Matrix3, Vector3};

use crate::sim::{Faults, Glitch, InjectedCounts, Motion, Reading, Scenario, Simulator};
use crate::storage::FlashStorage;
use crate::{BootOutcome, GlitchKind, Truth};

/// What this build runs on, for the log.
pub const NAME: &str = "QEMU mps2-an386, simulated LSM303AGR";

/// Found in the ELF by `runner.sh`, which then runs QEMU instead of probe-rs.
static QEMU_MARKER: [u8; 29] = *b"mag-cal-firmware-example:qemu";

/// I2C address of the accelerometer.
const ACCEL_ADDR: u8 = 0x19;
/// I2C address of the magnetometer.
const MAG_ADDR: u8 = 0x1E;

const WHO_AM_I_A: u8 = 0x0F;
const TEMP_CFG_REG_A: u8 = 0x1F;
const CTRL_REG1_A: u8 = 0x20;
const CTRL_REG6_A: u8 = 0x25;
const STATUS_REG_A: u8 = 0x27;
const FIFO_CTRL_REG_A: u8 = 0x2E;

const WHO_AM_I_M: u8 = 0x4F;
const CFG_REG_A_M: u8 = 0x60;
const CFG_REG_B_M: u8 = 0x61;
const CFG_REG_C_M: u8 = 0x62;
const STATUS_REG_M: u8 = 0x67;
const OUTX_L_REG_M: u8 = 0x68;
const OUTZ_H_REG_M: u8 = 0x6D;

/// CFG_REG_A_M reset value: idle mode (MD = 11).
const CFG_REG_A_M_RESET: u8 = 0b0000_0011;
const CFG_A_SOFT_RST: u8 = 0b0010_0000;
const CFG_A_REBOOT: u8 = 0b0100_0000;
const CFG_A_MD: u8 = 0b0000_0011;
const MD_CONTINUOUS: u8 = 0b00;
const MD_SINGLE: u8 = 0b01;
const MD_IDLE: u8 = 0b11;

/// STATUS_REG_M bits.
const ZYXOR: u8 = 0b1000_0000;
const ZYXDA: u8 = 0b0000_1000;
/// Per-axis data-ready bits (x, y, z); the overrun bits are these `<< 4`.
const AXIS_DA: [u8; 3] = [0b001, 0b010, 0b100];

/// An I2C error of the simulated bus.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum SimI2cError {
    /// No device at this address.
    NoDevice(u8),
    /// The device did not acknowledge its address: a NACK burst of the
    /// fault schedule (a busy or glitching bus).
    Busy(u8),
    /// The device NACKed: unmodelled register, write to a read-only
    /// register, or a transfer that does not start with the sub-address.
    Nack {
        /// Device address.
        device: u8,
        /// Register.
        register: u8,
    },
}

impl i2c::Error for SimI2cError {
    fn kind(&self) -> ErrorKind {
        match self {
            SimI2cError::NoDevice(_) | SimI2cError::Busy(_) => {
                ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address)
            }
            SimI2cError::Nack { .. } => ErrorKind::NoAcknowledge(NoAcknowledgeSource::Data),
        }
    }
}

/// The register file and sampling state of a simulated LSM303AGR.
pub struct SimLsm303agr {
    sim: Simulator,
    /// TEMP_CFG_REG_A, CTRL_REG1_A..CTRL_REG6_A, FIFO_CTRL_REG_A, indexed by
    /// `register - TEMP_CFG_REG_A`.
    accel_cfg: [u8; (FIFO_CTRL_REG_A - TEMP_CFG_REG_A + 1) as usize],
    /// CFG_REG_A_M..CFG_REG_C_M.
    mag_cfg: [u8; 3],
    status_m: u8,
    out_m: [u8; 6],
    /// Status polls since the last latched sample.
    ticks: u32,
    /// Truth of the latched sample.
    latched: Option<Reading>,
    /// Bus transactions answered since the last NACK burst.
    answered: u32,
    /// Transactions still to NACK in the current burst.
    nack_left: u32,
    /// NACK bursts injected.
    nack_bursts: u32,
}

impl SimLsm303agr {
    /// A sensor in its power-on state, simulating `scenario`.
    pub fn new(scenario: Scenario) -> Self {
        let mut dev = Self {
            sim: Simulator::new(scenario),
            accel_cfg: [0; (FIFO_CTRL_REG_A - TEMP_CFG_REG_A + 1) as usize],
            mag_cfg: [0; 3],
            status_m: 0,
            out_m: [0; 6],
            ticks: 0,
            latched: None,
            answered: 0,
            nack_left: 0,
            nack_bursts: 0,
        };
        dev.reset_accel();
        dev.reset_mag();
        dev
    }

    fn reset_accel(&mut self) {
        self.accel_cfg = [0; (FIFO_CTRL_REG_A - TEMP_CFG_REG_A + 1) as usize];
        // CTRL_REG1_A resets to 0x07: x, y, z enabled, power down.
        self.accel_cfg[(CTRL_REG1_A - TEMP_CFG_REG_A) as usize] = 0x07;
    }

    fn reset_mag(&mut self) {
        self.mag_cfg = [CFG_REG_A_M_RESET, 0, 0];
        self.status_m = 0;
        self.out_m = [0; 6];
        self.ticks = 0;
        self.latched = None;
    }

    /// The simulator, for truth and motion.
    pub fn simulator(&mut self) -> &mut Simulator {
        &mut self.sim
    }

    /// Truth of the sample currently in the output registers.
    pub fn latched(&self) -> Option<&Reading> {
        self.latched.as_ref()
    }

    /// Whether the bus NACKs this transaction (a NACK burst of the fault
    /// schedule); counts the transaction.
    fn nack_now(&mut self) -> bool {
        let f = self.sim.scenario().faults;
        if self.nack_left > 0 {
            self.nack_left -= 1;
            return true;
        }
        if f.nack_every == 0 || f.nack_burst_max == 0 {
            return false;
        }
        self.answered += 1;
        if self.answered <= f.nack_every {
            return false;
        }
        // This transaction starts a burst of 1, 2, .., max in turn.
        self.answered = 0;
        self.nack_left = self.nack_bursts % f.nack_burst_max;
        self.nack_bursts += 1;
        true
    }

    /// Fault episodes injected so far.
    pub fn injected(&self) -> InjectedCounts {
        InjectedCounts {
            nack: self.nack_bursts,
            ..self.sim.injected()
        }
    }

    /// Polls per sample at the configured output data rate (100 Hz / ODR).
    fn ticks_per_sample(&self) -> u32 {
        match (self.mag_cfg[0] >> 2) & 0b11 {
            0b00 => 10, // 10 Hz
            0b01 => 5,  // 20 Hz
            0b10 => 2,  // 50 Hz
            _ => 1,     // 100 Hz
        }
    }

    /// One tick of the simulated clock (a STATUS_REG_M read).
    fn tick(&mut self) {
        let md = self.mag_cfg[0] & CFG_A_MD;
        if md != MD_CONTINUOUS && md != MD_SINGLE {
            self.ticks = 0;
            return;
        }
        self.ticks += 1;
        if self.ticks < self.ticks_per_sample() {
            return;
        }
        self.ticks = 0;
        let reading = self.sim.next_reading();
        // A stuck output keeps the previous sample; STATUS still says new.
        if !reading.injected.stuck {
            for (i, c) in reading.counts.iter().enumerate() {
                self.out_m[2 * i..2 * i + 2].copy_from_slice(&c.to_le_bytes());
            }
        }
        // A sample replacing an unread one is an overrun.
        let unread = self.status_m & 0b111;
        self.status_m |= (unread << 4) | if unread != 0 { ZYXOR } else { 0 };
        self.status_m |= 0b111 | ZYXDA;
        self.latched = Some(reading);
        if md == MD_SINGLE {
            self.mag_cfg[0] = (self.mag_cfg[0] & !CFG_A_MD) | MD_IDLE;
        }
    }

    fn read_accel(&mut self, reg: u8) -> Result<u8, u8> {
        match reg {
            WHO_AM_I_A => Ok(0x33),
            TEMP_CFG_REG_A | CTRL_REG1_A..=CTRL_REG6_A | FIFO_CTRL_REG_A => {
                Ok(self.accel_cfg[(reg - TEMP_CFG_REG_A) as usize])
            }
            STATUS_REG_A => Ok(0),
            _ => Err(reg),
        }
    }

    fn write_accel(&mut self, reg: u8, value: u8) -> Result<(), u8> {
        match reg {
            TEMP_CFG_REG_A | CTRL_REG1_A..=CTRL_REG6_A | FIFO_CTRL_REG_A => {
                self.accel_cfg[(reg - TEMP_CFG_REG_A) as usize] = value;
                Ok(())
            }
            _ => Err(reg),
        }
    }

    fn read_mag(&mut self, reg: u8) -> Result<u8, u8> {
        match reg {
            WHO_AM_I_M => Ok(0x40),
            CFG_REG_A_M..=CFG_REG_C_M => Ok(self.mag_cfg[(reg - CFG_REG_A_M) as usize]),
            STATUS_REG_M => {
                self.tick();
                Ok(self.status_m)
            }
            OUTX_L_REG_M..=OUTZ_H_REG_M => {
                let i = reg - OUTX_L_REG_M;
                if i % 2 == 1 {
                    // High byte read: this axis is consumed.
                    let axis = AXIS_DA[(i / 2) as usize];
                    self.status_m &= !(axis | axis << 4);
                    if self.status_m & 0b111 == 0 {
                        self.status_m &= !(ZYXDA | ZYXOR);
                    }
                }
                Ok(self.out_m[i as usize])
            }
            _ => Err(reg),
        }
    }

    fn write_mag(&mut self, reg: u8, value: u8) -> Result<(), u8> {
        match reg {
            CFG_REG_A_M => {
                if value & CFG_A_SOFT_RST != 0 {
                    self.reset_mag();
                } else {
                    // REBOOT only reloads trimming: nothing to model.
                    self.mag_cfg[0] = value & !CFG_A_REBOOT;
                }
                Ok(())
            }
            CFG_REG_B_M | CFG_REG_C_M => {
                self.mag_cfg[(reg - CFG_REG_A_M) as usize] = value;
                Ok(())
            }
            _ => Err(reg),
        }
    }
}

/// The simulated I2C bus with the LSM303AGR on it.
pub struct SimI2c<'a> {
    dev: &'a RefCell<SimLsm303agr>,
}

impl SimI2c<'_> {
    /// One register access: `Ok(value)` or the NACKed register.
    fn access(&self, device: u8, reg: u8, write: Option<u8>) -> Result<u8, SimI2cError> {
        let mut dev = self.dev.borrow_mut();
        let r = match (device, write) {
            (ACCEL_ADDR, None) => dev.read_accel(reg),
            (ACCEL_ADDR, Some(v)) => dev.write_accel(reg, v).map(|()| v),
            (MAG_ADDR, None) => dev.read_mag(reg),
            (MAG_ADDR, Some(v)) => dev.write_mag(reg, v).map(|()| v),
            _ => return Err(SimI2cError::NoDevice(device)),
        };
        r.map_err(|register| SimI2cError::Nack { device, register })
    }
}

impl i2c::ErrorType for SimI2c<'_> {
    type Error = SimI2cError;
}

impl i2c::I2c for SimI2c<'_> {
    /// The LSM303AGR protocol: the first byte written is the sub-address;
    /// further bytes written, and bytes read, go to consecutive registers.
    fn transaction(
        &mut self,
        address: u8,
        operations: &mut [Operation<'_>],
    ) -> Result<(), Self::Error> {
        if address != ACCEL_ADDR && address != MAG_ADDR {
            return Err(SimI2cError::NoDevice(address));
        }
        if self.dev.borrow_mut().nack_now() {
            return Err(SimI2cError::Busy(address));
        }
        // Register pointer and auto-increment, set by the sub-address.
        let mut pointer: Option<(u8, bool)> = None;
        for op in operations {
            match op {
                Operation::Write(bytes) => {
                    for &byte in bytes.iter() {
                        match pointer {
                            None => {
                                let reg = byte & 0x7F;
                                // The magnetometer always auto-increments;
                                // the accelerometer only with bit 7 set.
                                let inc = address == MAG_ADDR || byte & 0x80 != 0;
                                pointer = Some((reg, inc));
                            }
                            Some((reg, inc)) => {
                                self.access(address, reg, Some(byte))?;
                                pointer = Some((if inc { reg + 1 } else { reg }, inc));
                            }
                        }
                    }
                }
                Operation::Read(buf) => {
                    let Some((mut reg, inc)) = pointer else {
                        return Err(SimI2cError::Nack {
                            device: address,
                            register: 0xFF,
                        });
                    };
                    for b in buf.iter_mut() {
                        *b = self.access(address, reg, None)?;
                        if inc {
                            reg += 1;
                        }
                    }
                    pointer = Some((reg, inc));
                }
            }
        }
        Ok(())
    }
}

/// Delay for the driver's turn-on waits: QEMU time does not matter.
pub struct NoDelay;

impl DelayNs for NoDelay {
    fn delay_ns(&mut self, _ns: u32) {}
}

/// Size of the flash stand-in: one nRF52833 page.
pub const FLASH_PAGE: usize = 4096;

/// An error of the flash stand-in (the same cases as the NVMC's).
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum SimFlashError {
    /// Outside the page.
    OutOfBounds,
    /// Not aligned to the erase or write size.
    Unaligned,
}

impl NorFlashError for SimFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            SimFlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            SimFlashError::Unaligned => NorFlashErrorKind::NotAligned,
        }
    }
}

/// One page of NOR flash in RAM: QEMU's stand-in for the board's NVMC page
/// (see the module documentation). Starts erased (all 0xFF).
pub struct SimFlash {
    bytes: [u8; FLASH_PAGE],
    erases: u32,
}

impl SimFlash {
    /// An erased page.
    pub const fn new() -> Self {
        Self {
            bytes: [0xFF; FLASH_PAGE],
            erases: 0,
        }
    }

    /// Flips bit `bit` of byte `offset`, as a retention error or a torn
    /// write would (test hook; not reachable through the flash traits).
    pub fn corrupt(&mut self, offset: usize, bit: u8) {
        if let Some(b) = self.bytes.get_mut(offset) {
            *b ^= 1 << (bit % 8);
        }
    }

    /// Page erases so far.
    pub fn erases(&self) -> u32 {
        self.erases
    }

    fn range(&self, offset: u32, len: usize) -> Result<core::ops::Range<usize>, SimFlashError> {
        let start = offset as usize;
        let end = start.checked_add(len).ok_or(SimFlashError::OutOfBounds)?;
        if end > FLASH_PAGE {
            return Err(SimFlashError::OutOfBounds);
        }
        Ok(start..end)
    }
}

impl Default for SimFlash {
    fn default() -> Self {
        Self::new()
    }
}

impl ErrorType for SimFlash {
    type Error = SimFlashError;
}

impl ReadNorFlash for SimFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let r = self.range(offset, bytes.len())?;
        bytes.copy_from_slice(&self.bytes[r]);
        Ok(())
    }

    fn capacity(&self) -> usize {
        FLASH_PAGE
    }
}

impl NorFlash for SimFlash {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = FLASH_PAGE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        if from > to {
            return Err(SimFlashError::OutOfBounds);
        }
        let r = self.range(from, (to - from) as usize)?;
        if r.start % Self::ERASE_SIZE != 0 || r.end % Self::ERASE_SIZE != 0 {
            return Err(SimFlashError::Unaligned);
        }
        self.bytes[r].fill(0xFF);
        self.erases += 1;
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let r = self.range(offset, bytes.len())?;
        if r.start % Self::WRITE_SIZE != 0 || r.len() % Self::WRITE_SIZE != 0 {
            return Err(SimFlashError::Unaligned);
        }
        // NOR flash: programming only clears bits.
        for (cell, b) in self.bytes[r].iter_mut().zip(bytes) {
            *cell &= *b;
        }
        Ok(())
    }
}

/// The calibration storage of this build: the record at the start of the
/// flash stand-in.
pub type CalibrationStorage = FlashStorage<SimFlash>;

/// Where the calibration is stored, for the log.
pub const STORAGE_NAME: &str = "flash stand-in (4 KiB of RAM; QEMU has no NVMC)";

/// Samples the simulated device lies still at the start of each collection
/// before it turns: 20 s at the firmware's 20 Hz. The collector keeps one
/// sample of it (`mag_cal_core::collector::NOISE_SPACING`) and fills once
/// the device turns; the run checks that the collection then calibrates.
pub const STILL_START: u32 = 400;

/// The simulated hardware.
pub struct Hardware {
    sensor: RefCell<SimLsm303agr>,
    delay: NoDelay,
    storage: CalibrationStorage,
}

impl Hardware {
    /// The sensor in its power-on state, simulating [`Scenario::DEFAULT`]
    /// lying still for [`STILL_START`] samples at the start of each
    /// collection (with [`Faults::RUN`] in the fault run), and an erased
    /// flash page.
    pub fn take() -> Self {
        // Keep the marker in the ELF for `runner.sh`.
        core::hint::black_box(&QEMU_MARKER);
        let faults = if cfg!(feature = "faults") {
            Faults::RUN
        } else {
            Faults::NONE
        };
        Self {
            sensor: RefCell::new(SimLsm303agr::new(Scenario {
                faults,
                still_samples: STILL_START,
                ..Scenario::DEFAULT
            })),
            delay: NoDelay,
            storage: FlashStorage::new(SimFlash::new(), 0),
        }
    }

    /// The I2C bus for the driver, its delay, the test bench, and the
    /// calibration storage.
    pub fn split(&mut self) -> (SimI2c<'_>, &mut NoDelay, Bench<'_>, &mut CalibrationStorage) {
        (
            SimI2c { dev: &self.sensor },
            &mut self.delay,
            Bench { dev: &self.sensor },
            &mut self.storage,
        )
    }
}

/// Byte of the stored record flipped before the third boot: inside `W`.
const CORRUPTED_BYTE: usize = 40;

/// The simulator's side of the experiment: it moves the sensor and knows
/// the truth.
pub struct Bench<'a> {
    dev: &'a RefCell<SimLsm303agr>,
}

impl Bench<'_> {
    /// Start tumbling the sensor over the sphere (after it lies still for
    /// the scenario's `still_samples`).
    pub fn begin_sweep(&mut self) {
        let mut dev = self.dev.borrow_mut();
        let sim = dev.simulator();
        let s = sim.scenario();
        defmt::info!(
            "simulator: field {=f64} uT, dip {=f64} deg, noise {=f64} counts; the sensor lies still for {=u32} samples, then tumbles over the sphere",
            s.field_nt / 1000.0,
            s.dip_deg,
            s.noise,
            s.still_samples
        );
        sim.set_motion(Motion::Sweep);
    }

    /// Start a level compass swing: `stops` headings, `dwell` samples each.
    pub fn begin_level_turn(&mut self, stops: u32, dwell: u32) {
        defmt::info!(
            "simulator: level compass swing, {} headings, {} samples each",
            stops,
            dwell
        );
        self.dev
            .borrow_mut()
            .simulator()
            .set_motion(Motion::LevelTurn {
                stops,
                dwell,
                offset_deg: 5,
            });
    }

    /// Start ordinary use (no calibration dance).
    pub fn begin_ordinary_use(&mut self) {
        defmt::info!("simulator: ordinary use: heading changes, tilts now and then, no tumbling");
        self.dev
            .borrow_mut()
            .simulator()
            .set_motion(Motion::OrdinaryUse);
    }

    /// Moves the hard iron by `delta` counts (a part got magnetised).
    pub fn move_hard_iron(&mut self, delta: [f64; 3]) {
        let mut dev = self.dev.borrow_mut();
        let sim = dev.simulator();
        let b = sim.hard_iron();
        sim.set_hard_iron([b[0] + delta[0], b[1] + delta[1], b[2] + delta[2]]);
        defmt::info!(
            "simulator: the hard iron moved by ({=f64}, {=f64}, {=f64}) counts",
            delta[0],
            delta[1],
            delta[2]
        );
    }

    /// The noise of the simulated sensor over its field strength.
    pub fn relative_noise(&self) -> f32 {
        let mut dev = self.dev.borrow_mut();
        let sim = dev.simulator();
        (sim.scenario().noise / sim.field_strength()) as f32
    }

    /// Application boots in one run: 1, erased flash, nothing stored:
    /// calibrate and store; 2, load the stored calibration and skip the
    /// calibration; 3, after a bit of the record was flipped, the load
    /// fails its checksum: calibrate and store again.
    pub fn boots(&self) -> u32 {
        3
    }

    /// Prepares boot `boot` (a simulated reset: the sensor, the bus and the
    /// flash keep their state; the application starts from scratch).
    pub fn before_boot(&mut self, boot: u32, storage: &mut CalibrationStorage) {
        defmt::info!("--- boot {=u32} (simulated reset) ---", boot);
        if boot == 3 {
            defmt::info!(
                "simulator: flipping bit 4 of byte {=usize} of the stored record",
                CORRUPTED_BYTE
            );
            storage.flash_mut().corrupt(CORRUPTED_BYTE, 4);
        }
    }

    /// Whether boot `boot` did what the flow requires: boot 1 finds the
    /// page erased (`BadMagic`), boot 2 loads exactly what boot 1 stored,
    /// boot 3 finds the corrupted record (`ChecksumMismatch`).
    pub fn check_boot(
        &self,
        boot: u32,
        outcome: BootOutcome,
        calibration: &mag_cal_core::Calibration<f32>,
        previous: Option<&mag_cal_core::Calibration<f32>>,
    ) -> bool {
        use crate::storage::LoadError::Record;
        use mag_cal_core::persist::Error;
        let ok = match boot {
            1 => outcome == BootOutcome::Calibrated(Record(Error::BadMagic)),
            2 => outcome == BootOutcome::Loaded && previous == Some(calibration),
            _ => outcome == BootOutcome::Calibrated(Record(Error::ChecksumMismatch)),
        };
        if !ok {
            defmt::error!("boot {=u32}: unexpected outcome {}", boot, outcome);
        }
        ok
    }

    /// Whether the sample in the output registers carries an injected fault
    /// (the truth the firmware must not let into a calibration).
    pub fn latched_faulty(&self) -> bool {
        self.dev
            .borrow()
            .latched()
            .is_some_and(|r| r.injected.any())
    }

    /// Fault episodes injected so far, in the order of the summary line:
    /// NACK bursts, stuck, saturated, disturbance (all 0 in the clean run).
    pub fn injected(&self) -> Option<[u32; 4]> {
        let c = self.dev.borrow().injected();
        Some([c.nack, c.stuck, c.saturated, c.disturbance])
    }

    /// The glitch of the sample in the output registers, if it has one
    /// (the truth; glitches are no faults for [`Bench::latched_faulty`]).
    /// A stuck output shows the sample before, whose glitch was reported
    /// when it was read.
    pub fn latched_glitch(&self) -> Option<GlitchKind> {
        let dev = self.dev.borrow();
        let r = dev.latched()?;
        if r.injected.stuck {
            return None;
        }
        r.injected.glitch.map(|g| match g {
            Glitch::Wild => GlitchKind::Wild,
            Glitch::Displaced => GlitchKind::Displaced,
        })
    }

    /// Glitches injected so far: wild, displaced (both 0 in the clean run).
    pub fn injected_glitches(&self) -> Option<[u32; 2]> {
        let c = self.dev.borrow().injected();
        Some([c.wild, c.displaced])
    }

    /// The raw counts in the output registers (the last sample latched,
    /// or the one before it when the output is stuck).
    pub fn latched_counts(&self) -> Option<[i16; 3]> {
        let dev = self.dev.borrow();
        dev.latched()?;
        let o = &dev.out_m;
        Some([0, 1, 2].map(|i| i16::from_le_bytes([o[2 * i], o[2 * i + 1]])))
    }

    /// The true level heading (degrees) of the last sample read.
    pub fn true_heading_deg(&self) -> Option<f32> {
        self.dev.borrow().latched().map(|r| r.heading_deg as f32)
    }

    /// The true calibration.
    pub fn truth(&self) -> Option<Truth> {
        let mut dev = self.dev.borrow_mut();
        let sim = dev.simulator();
        let t = sim.soft_iron();
        let b = sim.hard_iron();
        Some(Truth {
            hard_iron: Vector3::new(b[0] as f32, b[1] as f32, b[2] as f32),
            soft_iron: Matrix3::from_fn(|i, j| t[i][j] as f32),
            field_strength: sim.field_strength() as f32,
        })
    }
}

/// Ends the program through semihosting; QEMU exits with status 0 or 1.
pub fn exit(success: bool) -> ! {
    use cortex_m_semihosting::debug;
    debug::exit(if success {
        debug::EXIT_SUCCESS
    } else {
        debug::EXIT_FAILURE
    });
    // Not reached under QEMU; on a debugger that ignores the request, stop.
    loop {
        cortex_m::asm::bkpt();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    defmt::error!("panic: {}", defmt::Display2Format(info));
    exit(false)
}

#[cortex_m_rt::exception]
unsafe fn HardFault(frame: &cortex_m_rt::ExceptionFrame) -> ! {
    defmt::error!("hard fault at pc {=u32:#010x}", frame.pc());
    exit(false)
}
