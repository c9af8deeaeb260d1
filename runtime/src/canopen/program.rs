//! Program download (CiA 302-3) onto the A/B policy slots: the objects 0x1F50 (program data),
//! 0x1F51 (program control), 0x1F56 (program software identification) and 0x1F57 (flash status),
//! sub-index 1 each (sub-index 0 holds 1, the number of programs).
//!
//! - **0x1F50:1 program data** (DOMAIN, write only): an SDO download (block transfer, or
//!   segmented) of a policy file streams into the *inactive* slot; the size must be given and fit
//!   a slot. At the end the file is decoded (its own CRC-32 included) and checked by the
//!   controller (layout, period, capacity); a file that fails is dropped with abort 0x0800_0020
//!   and 0x1F57 says why. Refused with 0x0800_0022 while the controller is operational. The
//!   active policy runs on, untouched, whatever happens to a download (a cut transfer, a bad file,
//!   a power cut: [`crate::slots`]).
//! - **0x1F51:1 program control** (u8): write `1` *start*: the verified file staged by a download
//!   becomes the active policy (refused with 0x0800_0022 while operational, 0x0800_0024 when
//!   nothing is staged); `3` *clear*: the staged file is discarded; `0x80` *roll back*
//!   (manufacturer-specific): the previous policy is active again (0x0800_0024 when none is kept);
//!   `0` *stop*: the controller leaves operational for pre-operational at its next cycle (sends the
//!   safe action). `2` (*reset*) and any other value: 0x0609_0030. Read: `1` while the controller
//!   is operational, else `0`. A staged file is activated by an explicit start only: no other
//!   request or state change activates it.
//! - **0x1F56:1 program software identification** (u32, read only): the CRC-32 of the active policy
//!   file (0 when none).
//! - **0x1F57:1 flash status** (u32, read only): bit 0 a download is in progress; bits 1-7 the last
//!   download's or control's result ([`FlashResult`]); bit 8 a verified file is staged.

use dex_policy::PolicyView;

use super::abort::SdoAbort;
use super::od::{
    Access, DataType, Entry, Object, ObjectDictionary, ObjectKind, SubObject, Value, basic_entry,
    find, read_value,
};
use crate::error::LoadError;
use crate::slots::{PolicySlots, SlotError};

/// Program data.
pub const PROGRAM_DATA: u16 = 0x1F50;
/// Program control.
pub const PROGRAM_CONTROL: u16 = 0x1F51;
/// Program software identification.
pub const PROGRAM_ID: u16 = 0x1F56;
/// Flash status identification.
pub const FLASH_STATUS: u16 = 0x1F57;

/// Sub-index 0 of every program-download object: one program.
const PROGRAMS: SubObject = SubObject {
    sub: 0,
    name: "Highest sub-index supported",
    data_type: DataType::Unsigned8,
    access: Access::ReadOnly,
    value: Value::Const(1),
};

/// The program-download objects (the module's list): access and size of every request come from
/// here ([`ObjectDictionary::entry`]; program data's size is the slot capacity), and
/// `can/jaco.eds` is generated from it (with [`super::device::OBJECTS`]).
pub const OBJECTS: [Object; 4] = [
    Object {
        index: PROGRAM_DATA,
        name: "Program data",
        kind: ObjectKind::Array,
        subs: &[
            PROGRAMS,
            SubObject {
                sub: 1,
                name: "Program number 1",
                data_type: DataType::Domain,
                access: Access::WriteOnly,
                value: Value::Live,
            },
        ],
    },
    Object {
        index: PROGRAM_CONTROL,
        name: "Program control",
        kind: ObjectKind::Array,
        subs: &[
            PROGRAMS,
            SubObject {
                sub: 1,
                name: "Program number 1",
                data_type: DataType::Unsigned8,
                access: Access::ReadWrite,
                value: Value::Live,
            },
        ],
    },
    Object {
        index: PROGRAM_ID,
        name: "Program software identification",
        kind: ObjectKind::Array,
        subs: &[
            PROGRAMS,
            SubObject {
                sub: 1,
                name: "Program number 1",
                data_type: DataType::Unsigned32,
                access: Access::ReadOnly,
                value: Value::Live,
            },
        ],
    },
    Object {
        index: FLASH_STATUS,
        name: "Flash status identification",
        kind: ObjectKind::Array,
        subs: &[
            PROGRAMS,
            SubObject {
                sub: 1,
                name: "Program number 1",
                data_type: DataType::Unsigned32,
                access: Access::ReadOnly,
                value: Value::Live,
            },
        ],
    },
];

/// Program control values (0x1F51:1).
pub mod control {
    /// Stop the program (the controller leaves operational).
    pub const STOP: u8 = 0;
    /// Start: activate the staged file.
    pub const START: u8 = 1;
    /// Reset (not supported: abort 0x0609_0030).
    pub const RESET: u8 = 2;
    /// Clear: discard the staged file.
    pub const CLEAR: u8 = 3;
    /// Roll back to the previous policy (manufacturer-specific value).
    pub const ROLL_BACK: u8 = 0x80;
}

/// The last download's or program control's result, bits 1-7 of 0x1F57:1.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum FlashResult {
    /// Nothing failed.
    Ok = 0,
    /// Start or roll-back with no file to activate.
    NoProgram = 1,
    /// The downloaded bytes are not a valid policy file.
    Format = 2,
    /// The controller refused the file (layout, control period, capacity).
    Refused = 3,
    /// The file is larger than a slot, or more bytes came than announced.
    TooLarge = 4,
    /// The download was aborted or timed out before its end.
    Aborted = 5,
    /// Refused because the controller is operational.
    Operational = 6,
}

/// What program download needs from the application: the controller.
pub trait ProgramHost {
    /// Whether the program may change now (not while the policy runs).
    fn may_change_program(&self) -> bool;
    /// The controller's checks of a received file.
    fn accept(&self, view: &PolicyView<'_>, file: &[u8]) -> Result<(), LoadError>;
    /// Makes the verified file in the inactive slot the active policy.
    fn activate(&mut self, slots: &mut PolicySlots<'_>) -> Result<(), SlotError>;
    /// Makes the previous policy active again.
    fn roll_back(&mut self, slots: &mut PolicySlots<'_>) -> Result<(), SlotError>;
    /// Leaves operational at the next control cycle.
    fn stop(&mut self);
    /// Whether the policy runs (operational).
    fn running(&self) -> bool;
}

/// What 0x1F57 reports between requests.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ProgramState {
    downloading: bool,
    result: FlashResult,
    /// The byte of a program-control write, applied when the write ends.
    control: Option<u8>,
}

impl Default for ProgramState {
    fn default() -> Self {
        ProgramState {
            downloading: false,
            result: FlashResult::Ok,
            control: None,
        }
    }
}

impl ProgramState {
    /// The flash status word (0x1F57:1) given whether a verified file is staged.
    pub fn status_word(&self, staged: bool) -> u32 {
        u32::from(self.downloading) | (u32::from(self.result as u8) << 1) | (u32::from(staged) << 8)
    }

    /// The last result.
    pub fn result(&self) -> FlashResult {
        self.result
    }
}

/// The program-download objects over `slots`, for one SDO request.
pub struct ProgramObjects<'a, 'r, H: ProgramHost> {
    /// The policy slots.
    pub slots: &'a mut PolicySlots<'r>,
    /// The controller.
    pub host: &'a mut H,
    /// What 0x1F57 reports.
    pub state: &'a mut ProgramState,
}

/// Whether `index` is one of the program-download objects.
pub const fn is_program_object(index: u16) -> bool {
    matches!(
        index,
        PROGRAM_DATA | PROGRAM_CONTROL | PROGRAM_ID | FLASH_STATUS
    )
}

impl FlashResult {
    /// The result a slot error leaves in 0x1F57.
    pub const fn of(e: &SlotError) -> FlashResult {
        match e {
            SlotError::Format(_) | SlotError::Misaligned => FlashResult::Format,
            SlotError::Refused(_) => FlashResult::Refused,
            SlotError::TooLarge | SlotError::RegionTooSmall => FlashResult::TooLarge,
            SlotError::Operational => FlashResult::Operational,
            SlotError::NoImage | SlotError::NoPrevious | SlotError::NoActive => {
                FlashResult::NoProgram
            }
            SlotError::NoTransfer | SlotError::OutOfOrder | SlotError::Incomplete => {
                FlashResult::Aborted
            }
        }
    }
}

impl<H: ProgramHost> ProgramObjects<'_, '_, H> {
    fn fail(&mut self, result: FlashResult, abort: SdoAbort) -> SdoAbort {
        self.state.result = result;
        self.state.downloading = false;
        abort
    }

    fn slot_error(&mut self, e: SlotError) -> SdoAbort {
        let abort = match e {
            SlotError::Operational => SdoAbort::DeviceState,
            SlotError::NoImage | SlotError::NoPrevious | SlotError::NoActive => SdoAbort::NoData,
            _ => SdoAbort::CannotStore,
        };
        self.fail(FlashResult::of(&e), abort)
    }

    fn control(&mut self, value: u8) -> Result<(), SdoAbort> {
        match value {
            control::START => {
                if !self.host.may_change_program() {
                    return Err(self.fail(FlashResult::Operational, SdoAbort::DeviceState));
                }
                if self.slots.transfer_state() != 2 {
                    return Err(self.fail(FlashResult::NoProgram, SdoAbort::NoData));
                }
                self.host
                    .activate(self.slots)
                    .map_err(|e| self.slot_error(e))?;
            }
            control::CLEAR => {
                if !self.host.may_change_program() {
                    return Err(self.fail(FlashResult::Operational, SdoAbort::DeviceState));
                }
                self.slots.discard();
                self.state.downloading = false;
            }
            control::ROLL_BACK => {
                self.host
                    .roll_back(self.slots)
                    .map_err(|e| self.slot_error(e))?;
            }
            control::STOP => self.host.stop(),
            _ => return Err(SdoAbort::InvalidValue),
        }
        self.state.result = FlashResult::Ok;
        Ok(())
    }
}

impl<H: ProgramHost> ObjectDictionary for ProgramObjects<'_, '_, H> {
    fn entry(&self, index: u16, sub: u8) -> Result<Entry, SdoAbort> {
        let desc = find(&OBJECTS, index, sub)?;
        Ok(match desc.data_type {
            // A domain takes at most a slot.
            DataType::Domain => Entry {
                access: desc.access,
                size: Some(self.slots.capacity() as u32),
                exact: false,
            },
            _ => basic_entry(desc),
        })
    }

    fn read(
        &mut self,
        index: u16,
        sub: u8,
        offset: u32,
        buf: &mut [u8],
    ) -> Result<usize, SdoAbort> {
        let value: u32 = match (index, sub) {
            (_, 0) => match find(&OBJECTS, index, sub)?.value {
                Value::Const(v) => v,
                _ => return Err(SdoAbort::NoData),
            },
            (PROGRAM_CONTROL, 1) => u32::from(self.host.running()),
            (PROGRAM_ID, 1) => self.slots.active_crc(),
            (FLASH_STATUS, 1) => self.state.status_word(self.slots.transfer_state() == 2),
            _ => return Err(SdoAbort::WriteOnly),
        };
        let size = self.entry(index, sub)?.size.unwrap_or(0) as usize;
        let bytes = value.to_le_bytes();
        Ok(read_value(bytes.get(..size).unwrap_or(&[]), offset, buf))
    }

    fn begin_write(&mut self, index: u16, sub: u8, size: Option<u32>) -> Result<(), SdoAbort> {
        if (index, sub) != (PROGRAM_DATA, 1) {
            return Ok(());
        }
        if !self.host.may_change_program() {
            return Err(self.fail(FlashResult::Operational, SdoAbort::DeviceState));
        }
        let Some(size) = size else {
            return Err(self.fail(FlashResult::Aborted, SdoAbort::LengthMismatch));
        };
        self.slots
            .begin(size as usize)
            .map_err(|e| self.slot_error(e))?;
        self.state.downloading = true;
        self.state.result = FlashResult::Ok;
        Ok(())
    }

    fn write(&mut self, index: u16, sub: u8, offset: u32, data: &[u8]) -> Result<(), SdoAbort> {
        if (index, sub) != (PROGRAM_DATA, 1) {
            // Program control: one byte, applied at the end of the write.
            self.state.control = data.first().copied();
            return Ok(());
        }
        self.slots.write_at(offset as usize, data).map_err(|e| {
            let abort = match e {
                SlotError::TooLarge => SdoAbort::TooLong,
                _ => SdoAbort::General,
            };
            self.fail(FlashResult::of(&e), abort)
        })
    }

    fn end_write(&mut self, index: u16, sub: u8, total: u32) -> Result<(), SdoAbort> {
        match (index, sub) {
            (PROGRAM_DATA, 1) => {
                let host = &*self.host;
                let result = self.slots.finish(|view, file| host.accept(view, file));
                self.state.downloading = false;
                match result {
                    Ok(()) => {
                        self.state.result = FlashResult::Ok;
                        Ok(())
                    }
                    Err(e) => Err(self.fail(FlashResult::of(&e), SdoAbort::CannotStore)),
                }
            }
            (PROGRAM_CONTROL, 1) => match (self.state.control.take(), total) {
                (Some(value), 1) => self.control(value),
                _ => Err(SdoAbort::LengthMismatch),
            },
            _ => Err(SdoAbort::ReadOnly),
        }
    }

    fn abort_write(&mut self, index: u16, sub: u8) {
        if (index, sub) == (PROGRAM_DATA, 1) && self.state.downloading {
            self.slots.abort();
            self.state.downloading = false;
            self.state.result = FlashResult::Aborted;
        }
    }
}
