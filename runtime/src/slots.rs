//! A/B policy slots: two caller-provided byte regions (two flash sectors, two static buffers), one
//! active, one inactive, and the segmented transfer over CAN that writes the inactive one.
//!
//! - A transfer writes only the inactive slot, so a power cut at any byte of it leaves the active
//!   slot's bytes, and the active policy, untouched.
//! - A transferred file is verified before it can be activated: length and transfer CRC, then the
//!   policy file's own checks ([`PolicyView::decode`]: magic, version, file CRC, layout hash, full
//!   decode) and the controller's (layout against [`crate::interface`], capacity, control period).
//! - Activation ([`crate::Controller::activate_slot`]) is refused in operational and runs between
//!   two calls into the controller, so no control cycle sees two policies. Its commit point is one
//!   small write: the new slot's header, with a generation one above the active slot's. The slot
//!   left behind keeps its file and header: [`crate::Controller::roll_back_slot`] makes it active
//!   again (a new transfer discards it).
//! - A policy whose first evaluation after activation fails (a non-finite output) is rolled back
//!   by the controller on the spot, with emergency 0xFF07 (fault code 7, `PolicyRolledBack`); its
//!   slot header is invalidated so that it is neither rolled back to nor mounted again.
//!
//! Region layout: a [`SLOT_HEADER_BYTES`]-byte header, then the policy file. Header (little
//! endian): magic `DXSL`, generation u32, file length u32, file CRC-32 u32, CRC-32 of the first 16
//! header bytes u32 (written last), zero padding. [`PolicySlots::mount`] makes the slot whose header,
//! file CRC and file decode are valid and whose generation is highest the active one, so what a
//! device finds after a reset is what was running, or the last committed activation. A partially
//! written header fails its CRC, and the slot is then empty. On NOR flash the header would live in
//! its own, separately erased record; here both regions are byte-writable.
//!
//! No heap, no unbounded loops: a segment is at most 6 bytes; verification and mounting read each
//! file once or twice (CRC and decode), bounded by the region's length.
//!
//! # Flash protocol (CAN)
//!
//! Requests on `0x600 + node` (tool to controller), responses on `0x580 + node`; byte 0 is the
//! command, a response sets bit 7 (`0x80 | command`) and carries a [`FlashStatus`] in byte 1.
//!
//! | request | bytes | response |
//! |---|---|---|
//! | `0x01` init | size u32 LE | `0x81 status` |
//! | `0x02` data | sequence u8, 1..6 data bytes | every [`BLOCK_SEGMENTS`] segments and at the last: `0x82 status seq` |
//! | `0x03` end | CRC-32/ISO-HDLC of the whole file u32 LE | `0x83 status` (after verification) |
//! | `0x04` activate | - | `0x84 status` (after the controller loaded the file, or refused it) |
//! | `0x05` abort | - | `0x85 status` |
//! | `0x06` status | - | `0x86 transfer-state active-crc u32 LE flags` |
//! | `0x07` roll back | - | `0x87 status` (the previous slot active again) |
//!
//! Transfer state: 0 none (or the inactive slot holds the previous policy), 1 receiving, 2
//! verified. Flags: bit 0 a previous policy is kept for a roll-back, bit 1 the active policy has
//! not been evaluated since its activation (a fault in its first evaluation rolls it back).

use core::fmt;

use crc::{Crc, Digest};
use dex_policy::{FormatError, PolicyView};

use crate::error::LoadError;

/// CRC-32/ISO-HDLC (zlib's), of the transfer and of slot headers: the workspace's one checksum
/// ([`dex_policy::CRC32`]), as a `static` so that a transfer's running digest can borrow it.
pub static CRC32: Crc<u32> = dex_policy::CRC32;

/// Alignment each region must have (the policy file's values are read in place).
pub const SLOT_ALIGN: usize = 8;
/// Bytes of slot header before the policy file in each region.
pub const SLOT_HEADER_BYTES: usize = 32;
/// Data bytes per transfer segment.
pub const SEGMENT_BYTES: usize = 6;
/// Segments per acknowledged block.
pub const BLOCK_SEGMENTS: u32 = 32;
/// Request identifier base (`+ node`).
pub const FLASH_REQUEST_BASE: u16 = 0x600;
/// Response identifier base (`+ node`).
pub const FLASH_RESPONSE_BASE: u16 = 0x580;

/// The header's magic.
const MAGIC: [u8; 4] = *b"DXSL";
/// Header bytes covered by the header CRC.
const HEADER_CHECKED: usize = 16;
/// Header bytes written (the rest is padding).
const HEADER_WRITTEN: usize = HEADER_CHECKED + 4;

/// Result codes of flash responses (byte 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum FlashStatus {
    /// Accepted.
    Ok = 0,
    /// A data segment arrived out of sequence (or empty): the transfer is aborted.
    Sequence = 1,
    /// The announced size exceeds the slot or more data came than announced.
    TooLarge = 2,
    /// Length or transfer CRC did not match.
    Crc = 3,
    /// The file is not a valid policy file.
    Format = 4,
    /// The controller refuses the file (layout, capacity, period).
    Refused = 5,
    /// Activation or roll-back refused: the controller is operational.
    Operational = 6,
    /// Nothing verified to activate.
    NoImage = 7,
    /// Data or end without an init.
    NoTransfer = 8,
    /// Unknown command.
    Unknown = 9,
    /// Roll-back refused: no previous policy is kept.
    NoPrevious = 10,
}

/// Why a slot operation failed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SlotError {
    /// A region does not start at a multiple of [`SLOT_ALIGN`].
    Misaligned,
    /// A region cannot hold a header and a file.
    RegionTooSmall,
    /// Refused while the controller is operational.
    Operational,
    /// No verified file waits in the inactive slot.
    NoImage,
    /// No previous policy is kept for a roll-back.
    NoPrevious,
    /// No policy is active.
    NoActive,
    /// The file is larger than a slot.
    TooLarge,
    /// The file is not a valid policy file.
    Format(FormatError),
    /// The controller refuses the file.
    Refused(LoadError),
}

impl fmt::Display for SlotError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SlotError::Misaligned => write!(f, "slot region not {SLOT_ALIGN}-byte aligned"),
            SlotError::RegionTooSmall => f.write_str("slot region too small for a policy file"),
            SlotError::Operational => f.write_str("refused while operational"),
            SlotError::NoImage => f.write_str("no verified policy file in the inactive slot"),
            SlotError::NoPrevious => f.write_str("no previous policy to roll back to"),
            SlotError::NoActive => f.write_str("no active policy"),
            SlotError::TooLarge => f.write_str("policy file larger than a slot"),
            SlotError::Format(e) => write!(f, "invalid policy file: {e}"),
            SlotError::Refused(e) => write!(f, "{e}"),
        }
    }
}

impl core::error::Error for SlotError {}

impl SlotError {
    /// The flash response status for this error.
    pub const fn status(&self) -> FlashStatus {
        match self {
            SlotError::Operational => FlashStatus::Operational,
            SlotError::NoImage | SlotError::NoActive => FlashStatus::NoImage,
            SlotError::NoPrevious => FlashStatus::NoPrevious,
            SlotError::TooLarge | SlotError::RegionTooSmall => FlashStatus::TooLarge,
            SlotError::Format(_) | SlotError::Misaligned => FlashStatus::Format,
            SlotError::Refused(_) => FlashStatus::Refused,
        }
    }
}

/// A committed file in a slot (its header is valid).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SlotFile {
    /// File length in bytes.
    pub len: usize,
    /// CRC-32/ISO-HDLC of the file.
    pub crc: u32,
    /// Generation: the active slot has the highest.
    pub generation: u32,
}

/// The state of the transfer into the inactive slot.
#[derive(Clone)]
enum Transfer {
    /// No transfer.
    Idle,
    /// Receiving: `written` of `size` bytes so far.
    Receiving {
        size: usize,
        written: usize,
        next_seq: u8,
        segments: u32,
        digest: Digest<'static, u32>,
    },
    /// A verified file of `size` bytes, CRC `crc`, waits for activation.
    Verified { size: usize, crc: u32 },
}

/// What a flash request asks of the controller, beyond the slots themselves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SlotCommand {
    /// Verify the received file against the controller (`0x03` end, the CRC matched).
    Verify,
    /// Activate the verified file (`0x04`).
    Activate,
    /// Roll back to the previous policy (`0x07`).
    RollBack,
}

/// The outcome of [`PolicySlots::request`]: a response now, or a command for the controller (which
/// answers it with [`PolicySlots::response`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Request {
    /// Nothing to send (a data segment inside a block).
    Silent,
    /// Send these response bytes.
    Respond(ResponseBytes),
    /// The controller must carry out this command, then respond.
    Command(SlotCommand),
}

/// Response bytes (at most 7).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ResponseBytes {
    bytes: [u8; 8],
    len: u8,
}

impl ResponseBytes {
    fn new(data: &[u8]) -> Self {
        let mut bytes = [0u8; 8];
        let len = data.len().min(8);
        bytes[..len].copy_from_slice(&data[..len]);
        ResponseBytes {
            bytes,
            len: len as u8,
        }
    }

    /// The bytes to send.
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes[..usize::from(self.len)]
    }
}

/// Two policy slots over caller-provided regions; see the module documentation.
pub struct PolicySlots<'r> {
    regions: [&'r mut [u8]; 2],
    files: [Option<SlotFile>; 2],
    active: Option<usize>,
    transfer: Transfer,
    trial: bool,
}

impl fmt::Debug for PolicySlots<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("PolicySlots")
            .field("capacity", &self.capacity())
            .field("files", &self.files)
            .field("active", &self.active)
            .field("transfer_state", &self.transfer_state())
            .field("trial", &self.trial)
            .finish()
    }
}

impl<'r> PolicySlots<'r> {
    /// Mounts two regions: checks each slot's header, file CRC and file decode, and makes the valid
    /// slot with the highest generation active (none when neither is valid: new, erased storage).
    /// Both regions must be [`SLOT_ALIGN`]-aligned and longer than [`SLOT_HEADER_BYTES`]; the
    /// smaller one bounds the file size ([`PolicySlots::capacity`]).
    pub fn mount(a: &'r mut [u8], b: &'r mut [u8]) -> Result<Self, SlotError> {
        for r in [&*a, &*b] {
            if !(r.as_ptr() as usize).is_multiple_of(SLOT_ALIGN) {
                return Err(SlotError::Misaligned);
            }
            if r.len() <= SLOT_HEADER_BYTES {
                return Err(SlotError::RegionTooSmall);
            }
        }
        let files = [read_slot(a), read_slot(b)];
        let active = match files {
            [Some(x), Some(y)] => Some(if y.generation > x.generation { 1 } else { 0 }),
            [Some(_), None] => Some(0),
            [None, Some(_)] => Some(1),
            [None, None] => None,
        };
        Ok(PolicySlots {
            regions: [a, b],
            files,
            active,
            transfer: Transfer::Idle,
            trial: false,
        })
    }

    /// Gives the regions back, as a reset would leave them (the transfer state and the trial are
    /// RAM state and gone); [`PolicySlots::mount`] them again to continue.
    pub fn into_regions(self) -> (&'r mut [u8], &'r mut [u8]) {
        let [a, b] = self.regions;
        (a, b)
    }

    /// Largest policy file a slot takes.
    pub fn capacity(&self) -> usize {
        self.regions[0].len().min(self.regions[1].len()) - SLOT_HEADER_BYTES
    }

    /// Index (0 or 1) of the active slot.
    pub fn active_index(&self) -> Option<usize> {
        self.active
    }

    /// The active slot's committed file.
    pub fn active(&self) -> Option<SlotFile> {
        self.active.and_then(|i| self.files[i])
    }

    /// The active policy file's bytes (empty when none is active).
    pub fn active_file(&self) -> &[u8] {
        match self.active.and_then(|i| self.files[i].map(|f| (i, f))) {
            Some((i, f)) => file_bytes(self.regions[i], f.len),
            None => &[],
        }
    }

    /// CRC-32 of the active policy file (0 when none), as the status response reports it.
    pub fn active_crc(&self) -> u32 {
        self.active().map_or(0, |f| f.crc)
    }

    /// The previous policy kept in the inactive slot for a roll-back.
    pub fn previous(&self) -> Option<SlotFile> {
        let i = self.inactive_index();
        if matches!(self.transfer, Transfer::Idle) {
            self.files[i]
        } else {
            None
        }
    }

    /// Whether the active policy was activated and has not been evaluated successfully since (a
    /// fault in that first evaluation rolls it back).
    pub fn on_trial(&self) -> bool {
        self.trial
    }

    /// Transfer state as the status response reports it: 0 none, 1 receiving, 2 verified.
    pub fn transfer_state(&self) -> u8 {
        match self.transfer {
            Transfer::Idle => 0,
            Transfer::Receiving { .. } => 1,
            Transfer::Verified { .. } => 2,
        }
    }

    /// The slot a transfer writes: never the active one.
    pub fn inactive_index(&self) -> usize {
        match self.active {
            Some(i) => 1 - i,
            None => 0,
        }
    }

    /// The bytes of the inactive slot's file: the verified transfer, or else the previous policy.
    fn inactive_file(&self) -> Option<&[u8]> {
        let i = self.inactive_index();
        let len = match self.transfer {
            Transfer::Verified { size, .. } => size,
            Transfer::Idle => self.files[i]?.len,
            Transfer::Receiving { .. } => return None,
        };
        Some(file_bytes(self.regions[i], len))
    }

    /// Starts a transfer of `size` bytes into the inactive slot, abandoning any transfer under way.
    /// The inactive slot's header is invalidated first, so its previous policy is gone.
    pub fn begin(&mut self, size: usize) -> Result<(), SlotError> {
        self.transfer = Transfer::Idle;
        if size == 0 || size > self.capacity() {
            return Err(SlotError::TooLarge);
        }
        let i = self.inactive_index();
        invalidate(self.regions[i]);
        self.files[i] = None;
        self.transfer = Transfer::Receiving {
            size,
            written: 0,
            next_seq: 0,
            segments: 0,
            digest: CRC32.digest(),
        };
        Ok(())
    }

    /// Writes one data segment (`seq`, then 1..=6 bytes) into the inactive slot. `Ok(true)` when
    /// the segment completes a block or the file (acknowledged), `Ok(false)` inside a block. Any
    /// error abandons the transfer.
    pub fn segment(&mut self, seq: u8, payload: &[u8]) -> Result<bool, FlashStatus> {
        let i = self.inactive_index();
        let Transfer::Receiving {
            size,
            written,
            next_seq,
            segments,
            digest,
        } = &mut self.transfer
        else {
            return Err(FlashStatus::NoTransfer);
        };
        if seq != *next_seq || payload.is_empty() || payload.len() > SEGMENT_BYTES {
            self.transfer = Transfer::Idle;
            return Err(FlashStatus::Sequence);
        }
        let end = *written + payload.len();
        if end > *size {
            self.transfer = Transfer::Idle;
            return Err(FlashStatus::TooLarge);
        }
        let dst = &mut self.regions[i][SLOT_HEADER_BYTES + *written..SLOT_HEADER_BYTES + end];
        dst.copy_from_slice(payload);
        digest.update(payload);
        *written = end;
        *next_seq = next_seq.wrapping_add(1);
        *segments = segments.saturating_add(1);
        Ok(segments.is_multiple_of(BLOCK_SEGMENTS) || end == *size)
    }

    /// Ends the transfer: checks the length and `crc` (CRC-32 of the whole file), decodes the file
    /// and asks `accept` (the controller's checks) about it. On success the file waits, verified,
    /// for activation; any failure abandons the transfer.
    pub fn end(
        &mut self,
        crc: u32,
        accept: impl FnOnce(&PolicyView<'_>, &[u8]) -> Result<(), LoadError>,
    ) -> Result<(), FlashStatus> {
        let transfer = core::mem::replace(&mut self.transfer, Transfer::Idle);
        let Transfer::Receiving {
            size,
            written,
            digest,
            ..
        } = transfer
        else {
            return Err(FlashStatus::NoTransfer);
        };
        if written != size || digest.finalize() != crc {
            return Err(FlashStatus::Crc);
        }
        let file = file_bytes(self.regions[self.inactive_index()], size);
        let view = PolicyView::decode(file).map_err(|_| FlashStatus::Format)?;
        accept(&view, file).map_err(|_| FlashStatus::Refused)?;
        self.transfer = Transfer::Verified { size, crc };
        Ok(())
    }

    /// Writes bytes `offset..offset + data.len()` of the file being received (a stream: `offset`
    /// must be what was written so far). For transfers whose integrity the transport checks (the
    /// SDO program download, [`crate::canopen::program`]); any error abandons the transfer.
    pub fn write_at(&mut self, offset: usize, data: &[u8]) -> Result<(), FlashStatus> {
        let i = self.inactive_index();
        let Transfer::Receiving {
            size,
            written,
            digest,
            ..
        } = &mut self.transfer
        else {
            return Err(FlashStatus::NoTransfer);
        };
        if offset != *written {
            self.transfer = Transfer::Idle;
            return Err(FlashStatus::Sequence);
        }
        let end = *written + data.len();
        if end > *size {
            self.transfer = Transfer::Idle;
            return Err(FlashStatus::TooLarge);
        }
        self.regions[i][SLOT_HEADER_BYTES + *written..SLOT_HEADER_BYTES + end]
            .copy_from_slice(data);
        digest.update(data);
        *written = end;
        Ok(())
    }

    /// Ends a transfer written with [`PolicySlots::write_at`]: checks the length, decodes the file
    /// (its own CRC-32 included) and asks `accept` (the controller's checks) about it, as
    /// [`PolicySlots::end`] does without a transfer CRC. On success the file waits, verified, for
    /// activation; any failure abandons the transfer.
    pub fn finish(
        &mut self,
        accept: impl FnOnce(&PolicyView<'_>, &[u8]) -> Result<(), LoadError>,
    ) -> Result<(), FlashStatus> {
        let crc = match &self.transfer {
            Transfer::Receiving { digest, .. } => digest.clone().finalize(),
            _ => return Err(FlashStatus::NoTransfer),
        };
        self.end(crc, accept)
    }

    /// Discards a verified file waiting for activation (or a transfer under way): the inactive
    /// slot keeps nothing to activate. The previous policy, if the slot still held one, is kept.
    pub fn discard(&mut self) {
        if !matches!(self.transfer, Transfer::Idle) {
            let i = self.inactive_index();
            invalidate(self.regions[i]);
            self.files[i] = None;
        }
        self.transfer = Transfer::Idle;
    }

    /// Abandons the transfer under way (the inactive slot stays invalid).
    pub fn abort(&mut self) {
        self.transfer = Transfer::Idle;
    }

    /// Commits the activation of the verified file: writes its header with the next generation,
    /// and the slot becomes the active one (on trial until its first evaluation). `bind` builds the
    /// controller's view of the file before anything is written; its error refuses the activation.
    pub fn activate<T>(
        &mut self,
        bind: impl FnOnce(&PolicyView<'_>, &[u8]) -> Result<T, LoadError>,
    ) -> Result<T, SlotError> {
        let Transfer::Verified { size, crc } = self.transfer else {
            return Err(SlotError::NoImage);
        };
        let bound = self.bind_inactive(bind)?;
        let i = self.inactive_index();
        let generation = self.next_generation();
        let file = SlotFile {
            len: size,
            crc,
            generation,
        };
        write_header(self.regions[i], file);
        self.files[i] = Some(file);
        self.active = Some(i);
        self.transfer = Transfer::Idle;
        self.trial = true;
        Ok(bound)
    }

    /// Makes the previous policy active again (its header rewritten with the next generation); the
    /// policy left becomes the previous one. `bind` as for [`PolicySlots::activate`].
    pub fn roll_back<T>(
        &mut self,
        bind: impl FnOnce(&PolicyView<'_>, &[u8]) -> Result<T, LoadError>,
    ) -> Result<T, SlotError> {
        let Some(prev) = self.previous() else {
            return Err(SlotError::NoPrevious);
        };
        let bound = self.bind_inactive(bind)?;
        let i = self.inactive_index();
        let file = SlotFile {
            generation: self.next_generation(),
            ..prev
        };
        write_header(self.regions[i], file);
        self.files[i] = Some(file);
        self.active = Some(i);
        self.trial = false;
        Ok(bound)
    }

    /// The roll-back after a fault in a policy's first evaluation: the previous policy becomes
    /// active as by [`PolicySlots::roll_back`], then the faulty slot's header is invalidated (it
    /// is neither rolled back to nor mounted again). Refused unless the active policy is on trial.
    pub fn roll_back_trial<T>(
        &mut self,
        bind: impl FnOnce(&PolicyView<'_>, &[u8]) -> Result<T, LoadError>,
    ) -> Result<T, SlotError> {
        if !self.trial {
            return Err(SlotError::NoPrevious);
        }
        let faulty = self.active.ok_or(SlotError::NoActive)?;
        let bound = self.roll_back(bind)?;
        invalidate(self.regions[faulty]);
        self.files[faulty] = None;
        Ok(bound)
    }

    /// The active policy was evaluated successfully: it is no longer on trial.
    pub fn confirm(&mut self) {
        self.trial = false;
    }

    /// Binds the active file (at start-up, after [`PolicySlots::mount`]).
    pub fn bind_active<T>(
        &self,
        bind: impl FnOnce(&PolicyView<'_>, &[u8]) -> Result<T, LoadError>,
    ) -> Result<T, SlotError> {
        let file = self.active_file();
        if file.is_empty() {
            return Err(SlotError::NoActive);
        }
        let view = PolicyView::decode(file).map_err(SlotError::Format)?;
        bind(&view, file).map_err(SlotError::Refused)
    }

    fn bind_inactive<T>(
        &self,
        bind: impl FnOnce(&PolicyView<'_>, &[u8]) -> Result<T, LoadError>,
    ) -> Result<T, SlotError> {
        let file = self.inactive_file().ok_or(SlotError::NoImage)?;
        let view = PolicyView::decode(file).map_err(SlotError::Format)?;
        bind(&view, file).map_err(SlotError::Refused)
    }

    fn next_generation(&self) -> u32 {
        self.active()
            .map_or(1, |f| f.generation.wrapping_add(1).max(1))
    }

    /// Handles one flash request's data bytes (the frame on `0x600 + node`). Requests that need
    /// the controller come back as [`Request::Command`]; the caller carries them out and answers
    /// with [`PolicySlots::response`].
    pub fn request(&mut self, data: &[u8]) -> Request {
        let cmd = data.first().copied().unwrap_or(0);
        let status = match cmd {
            0x01 => match data.get(1..5) {
                Some(s) => {
                    let size = u32::from_le_bytes([s[0], s[1], s[2], s[3]]) as usize;
                    match self.begin(size) {
                        Ok(()) => FlashStatus::Ok,
                        Err(e) => e.status(),
                    }
                }
                None => {
                    self.transfer = Transfer::Idle;
                    FlashStatus::Format
                }
            },
            0x02 => {
                let seq = data.get(1).copied().unwrap_or(0);
                let payload = data.get(2..).unwrap_or(&[]);
                let status = match self.segment(seq, payload) {
                    Ok(false) => return Request::Silent,
                    Ok(true) => FlashStatus::Ok,
                    Err(s) => s,
                };
                return Request::Respond(ResponseBytes::new(&[0x82, status as u8, seq]));
            }
            0x03 => match (&self.transfer, data.get(1..5)) {
                (Transfer::Receiving { .. }, Some(_)) => {
                    return Request::Command(SlotCommand::Verify);
                }
                (Transfer::Receiving { .. }, None) => {
                    self.transfer = Transfer::Idle;
                    FlashStatus::Format
                }
                _ => {
                    self.transfer = Transfer::Idle;
                    FlashStatus::NoTransfer
                }
            },
            0x04 => return Request::Command(SlotCommand::Activate),
            0x05 => {
                self.abort();
                FlashStatus::Ok
            }
            0x06 => {
                let c = self.active_crc().to_le_bytes();
                let flags = u8::from(self.previous().is_some()) | (u8::from(self.trial) << 1);
                return Request::Respond(ResponseBytes::new(&[
                    0x86,
                    self.transfer_state(),
                    c[0],
                    c[1],
                    c[2],
                    c[3],
                    flags,
                ]));
            }
            0x07 => return Request::Command(SlotCommand::RollBack),
            _ => FlashStatus::Unknown,
        };
        Request::Respond(ResponseBytes::new(&[0x80 | cmd, status as u8]))
    }

    /// The response to a [`SlotCommand`] carried out with `status`.
    pub fn response(command: SlotCommand, status: FlashStatus) -> ResponseBytes {
        let cmd = match command {
            SlotCommand::Verify => 0x83,
            SlotCommand::Activate => 0x84,
            SlotCommand::RollBack => 0x87,
        };
        ResponseBytes::new(&[cmd, status as u8])
    }
}

/// The CRC of a verification request (`0x03 crc u32 LE`), if the bytes hold one.
pub fn end_crc(data: &[u8]) -> Option<u32> {
    data.get(1..5)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
}

fn file_bytes(region: &[u8], len: usize) -> &[u8] {
    region
        .get(SLOT_HEADER_BYTES..SLOT_HEADER_BYTES.saturating_add(len))
        .unwrap_or(&[])
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    match b.get(at..at + 4) {
        Some(s) => u32::from_le_bytes([s[0], s[1], s[2], s[3]]),
        None => 0,
    }
}

/// The committed file of a region, if its header and file are valid.
fn read_slot(region: &[u8]) -> Option<SlotFile> {
    let h = region.get(..HEADER_WRITTEN)?;
    if h[..4] != MAGIC || u32_at(h, HEADER_CHECKED) != CRC32.checksum(&h[..HEADER_CHECKED]) {
        return None;
    }
    let file = SlotFile {
        generation: u32_at(h, 4),
        len: u32_at(h, 8) as usize,
        crc: u32_at(h, 12),
    };
    let bytes = region.get(SLOT_HEADER_BYTES..SLOT_HEADER_BYTES.checked_add(file.len)?)?;
    if file.len == 0 || CRC32.checksum(bytes) != file.crc || PolicyView::decode(bytes).is_err() {
        return None;
    }
    Some(file)
}

/// Writes a slot header: the checked part first, its CRC last (the commit point).
fn write_header(region: &mut [u8], file: SlotFile) {
    let mut h = [0u8; HEADER_WRITTEN];
    h[..4].copy_from_slice(&MAGIC);
    h[4..8].copy_from_slice(&file.generation.to_le_bytes());
    h[8..12].copy_from_slice(&(file.len as u32).to_le_bytes());
    h[12..16].copy_from_slice(&file.crc.to_le_bytes());
    let check = CRC32.checksum(&h[..HEADER_CHECKED]);
    h[HEADER_CHECKED..].copy_from_slice(&check.to_le_bytes());
    region[..HEADER_WRITTEN].copy_from_slice(&h);
}

/// Makes a slot's header invalid (magic first).
fn invalidate(region: &mut [u8]) {
    region[..HEADER_WRITTEN].fill(0);
}
