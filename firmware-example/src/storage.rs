//! Keeping the calibration across resets.
//!
//! The record is the core's [`persist`] encoding: [`RECORD_LEN`] = 92 bytes
//! (magic `"MCAL"`, version, the values as `f64`, CRC-32). A [`Storage`]
//! holds one record; [`FlashStorage`] puts it at the start of a NOR flash
//! page through the `embedded-storage` traits:
//!
//! - on the micro:bit v2, the nRF52833's last 4 KiB page (0x7F000..0x80000),
//!   through the HAL's `Nvmc` (`src/board.rs`; `build.rs` takes the page
//!   out of the linker's FLASH region, so the program can never overlap
//!   it);
//! - under QEMU, which emulates no NVMC, a page of RAM with NOR semantics
//!   (`SimFlash` in `src/sim_sensor.rs`) that lives through the simulated
//!   reboots of one run.
//!
//! Storing erases the page, programs the record and reads it back; loading
//! reads it and decodes it with [`persist::from_bytes`] in `f32`, which
//! refuses an erased page (`BadMagic`), another format version
//! (`UnsupportedVersion`) and any corruption (`ChecksumMismatch`), and then
//! checks that the values are physically plausible ([`plausible`]). A
//! calibration that fails any of this is not used: the application
//! calibrates again and overwrites the record.

use core::fmt::Debug;

use embedded_storage::nor_flash::NorFlash;
use mag_cal_core::persist::{self, ENCODED_LEN};
use mag_cal_core::Calibration;

/// Length of a stored record, bytes.
pub const RECORD_LEN: usize = ENCODED_LEN;

/// Smallest plausible field strength `rho`, counts: half the weakest
/// geomagnetic field on the Earth's surface (about 22 uT = 147 counts of
/// 150 nT), leaving room for a soft iron that shrinks the field.
pub const RHO_MIN: f32 = 70.0;

/// Largest plausible field strength, counts: twice the strongest surface
/// field (about 67 uT = 447 counts).
pub const RHO_MAX: f32 = 900.0;

/// Where one calibration record is kept.
pub trait Storage {
    /// Why the medium failed.
    type Error: Debug;

    /// Reads the record area (whatever it holds: the caller validates).
    fn read_record(&mut self, record: &mut [u8; RECORD_LEN]) -> Result<(), Self::Error>;

    /// Erases the record area and writes `record`.
    fn write_record(&mut self, record: &[u8; RECORD_LEN]) -> Result<(), Self::Error>;
}

/// Why a write to a [`FlashStorage`] failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlashStorageError<E> {
    /// The flash driver refused the operation.
    Flash(E),
    /// The record read back differs from the one written.
    Verify,
}

/// A record at `offset` (a page boundary) of a NOR flash.
pub struct FlashStorage<F> {
    flash: F,
    offset: u32,
}

impl<F: NorFlash> FlashStorage<F> {
    /// The record at `offset` of `flash`, which must be a multiple of the
    /// erase size (the record owns that whole erase unit).
    pub fn new(flash: F, offset: u32) -> Self {
        Self { flash, offset }
    }

    /// The flash (tests and the simulator's corruption hook).
    pub fn flash_mut(&mut self) -> &mut F {
        &mut self.flash
    }
}

impl<F: NorFlash> Storage for FlashStorage<F> {
    type Error = FlashStorageError<F::Error>;

    fn read_record(&mut self, record: &mut [u8; RECORD_LEN]) -> Result<(), Self::Error> {
        self.flash
            .read(self.offset, record)
            .map_err(FlashStorageError::Flash)
    }

    fn write_record(&mut self, record: &[u8; RECORD_LEN]) -> Result<(), Self::Error> {
        // Programming works in words of WRITE_SIZE bytes (4 on the nRF52).
        const { assert!(RECORD_LEN.is_multiple_of(F::WRITE_SIZE)) };
        let end = self.offset + F::ERASE_SIZE as u32;
        self.flash
            .erase(self.offset, end)
            .map_err(FlashStorageError::Flash)?;
        self.flash
            .write(self.offset, record)
            .map_err(FlashStorageError::Flash)?;
        let mut back = [0u8; RECORD_LEN];
        self.read_record(&mut back)?;
        if back == *record {
            Ok(())
        } else {
            Err(FlashStorageError::Verify)
        }
    }
}

/// Why no calibration was loaded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum LoadError {
    /// The medium could not be read.
    Storage,
    /// The record was refused by [`persist::from_bytes`] (erased page:
    /// `BadMagic`; corruption: `ChecksumMismatch`; ...).
    Record(persist::Error),
    /// The record is intact but its values are not a plausible calibration
    /// of this sensor ([`plausible`]).
    Implausible,
}

/// Loads the stored calibration.
pub fn load<S: Storage>(storage: &mut S) -> Result<Calibration<f32>, LoadError> {
    let mut record = [0u8; RECORD_LEN];
    if let Err(e) = storage.read_record(&mut record) {
        defmt::error!("reading the stored record: {}", defmt::Debug2Format(&e));
        return Err(LoadError::Storage);
    }
    let cal = persist::from_bytes::<f32>(&record).map_err(LoadError::Record)?;
    if plausible(&cal) {
        Ok(cal)
    } else {
        Err(LoadError::Implausible)
    }
}

/// Stores `cal` (erase, program, read back and compare).
pub fn store<S: Storage>(storage: &mut S, cal: &Calibration<f32>) -> Result<(), S::Error> {
    storage.write_record(&persist::to_bytes(cal))
}

/// Whether a decoded calibration is physically plausible for the LSM303AGR
/// (150 nT a count, +-32767 counts): its field strength within
/// [`RHO_MIN`]..[`RHO_MAX`] and its hard iron inside the sensor's range.
/// The decoder has already checked that the values are finite, that `W` is
/// symmetric positive definite and that `rho` matches it.
pub fn plausible(cal: &Calibration<f32>) -> bool {
    let rho = cal.field_strength();
    (RHO_MIN..=RHO_MAX).contains(&rho) && cal.hard_iron().iter().all(|b| b.abs() < 32767.0)
}
