//! A/B policy slots: two caller-provided byte regions (two flash sectors, two static buffers), one
//! active, one inactive: a transfer (program download over CAN) writes the inactive one.
//!
//! - A transfer writes only the inactive slot, so a power cut at any byte of it leaves the active
//!   slot's bytes, and the active policy, untouched.
//! - A transferred file is verified before it can be activated: length (the transport checked the
//!   bytes: the SDO block download's CRC-16), then the
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
//! No heap, no unbounded loops: a write is one SDO segment (at most 7 bytes); verification and mounting read each
//! file once or twice (CRC and decode), bounded by the region's length.
//!
//! # Program download
//!
//! The slots are written over CAN by CANopen program download (CiA 302-3, object 0x1F50 through
//! the controller's SDO server: [`crate::canopen::program`]), which calls [`PolicySlots::begin`],
//! [`PolicySlots::write_at`] for each chunk, [`PolicySlots::finish`] at the end (or
//! [`PolicySlots::abort`] when the SDO transfer is aborted or times out), and through the
//! controller [`PolicySlots::activate`] and [`PolicySlots::roll_back`] on program control
//! (0x1F51).

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

/// The header's magic.
const MAGIC: [u8; 4] = *b"DXSL";
/// Header bytes covered by the header CRC.
const HEADER_CHECKED: usize = 16;
/// Header bytes written (the rest is padding).
const HEADER_WRITTEN: usize = HEADER_CHECKED + 4;

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
    /// No transfer is under way (a write or an end without [`PolicySlots::begin`]).
    NoTransfer,
    /// A write did not continue where the transfer stood: the transfer is abandoned.
    OutOfOrder,
    /// The transfer ended before all announced bytes arrived: the transfer is abandoned.
    Incomplete,
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
            SlotError::NoTransfer => f.write_str("no transfer under way"),
            SlotError::OutOfOrder => f.write_str("transfer bytes out of order"),
            SlotError::Incomplete => f.write_str("transfer ended before all announced bytes"),
        }
    }
}

impl core::error::Error for SlotError {}

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
        digest: Digest<'static, u32>,
    },
    /// A verified file of `size` bytes, CRC `crc`, waits for activation.
    Verified { size: usize, crc: u32 },
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

    /// CRC-32 of the active policy file (0 when none): program software identification (0x1F56).
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

    /// Transfer state: 0 none (or the inactive slot holds the previous policy), 1 receiving, 2
    /// verified (staged for activation).
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
            digest: CRC32.digest(),
        };
        Ok(())
    }

    /// Writes bytes `offset..offset + data.len()` of the file being received (a stream: `offset`
    /// must be what was written so far). The transport checks the bytes' integrity (the SDO block
    /// download's CRC-16, [`crate::canopen::program`]), the file its own CRC-32 at
    /// [`PolicySlots::finish`]; any error abandons the transfer.
    pub fn write_at(&mut self, offset: usize, data: &[u8]) -> Result<(), SlotError> {
        let i = self.inactive_index();
        let Transfer::Receiving {
            size,
            written,
            digest,
            ..
        } = &mut self.transfer
        else {
            return Err(SlotError::NoTransfer);
        };
        if offset != *written {
            self.transfer = Transfer::Idle;
            return Err(SlotError::OutOfOrder);
        }
        let end = *written + data.len();
        if end > *size {
            self.transfer = Transfer::Idle;
            return Err(SlotError::TooLarge);
        }
        self.regions[i][SLOT_HEADER_BYTES + *written..SLOT_HEADER_BYTES + end]
            .copy_from_slice(data);
        digest.update(data);
        *written = end;
        Ok(())
    }

    /// Ends the transfer: checks the length, decodes the file (its own CRC-32 included) and asks
    /// `accept` (the controller's checks) about it. On success the file waits, verified, for
    /// activation; any failure abandons the transfer.
    pub fn finish(
        &mut self,
        accept: impl FnOnce(&PolicyView<'_>, &[u8]) -> Result<(), LoadError>,
    ) -> Result<(), SlotError> {
        let transfer = core::mem::replace(&mut self.transfer, Transfer::Idle);
        let Transfer::Receiving {
            size,
            written,
            digest,
        } = transfer
        else {
            return Err(SlotError::NoTransfer);
        };
        if written != size {
            return Err(SlotError::Incomplete);
        }
        let crc = digest.finalize();
        let file = file_bytes(self.regions[self.inactive_index()], size);
        let view = PolicyView::decode(file).map_err(SlotError::Format)?;
        accept(&view, file).map_err(SlotError::Refused)?;
        self.transfer = Transfer::Verified { size, crc };
        Ok(())
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
