//! The SDO server (CiA 301): expedited and segmented download and upload, and block download
//! (with CRC), over one object dictionary ([`ObjectDictionary`]). One request frame in, at most one
//! response frame out; every refusal is an abort frame with a CiA 301 code ([`SdoAbort`]).
//!
//! Requests come on `0x600 + node` and responses go on `0x580 + node` (the caller moves frames);
//! every request is 8 bytes. Byte 0 is the command specifier:
//!
//! | request | byte 0 | response |
//! |---|---|---|
//! | initiate download | `001 x nn e s` (`0x20..0x2F`) | `0x60` |
//! | download segment | `000 t nnn c` | `001 t 0000` |
//! | initiate upload | `0x40` | expedited `010 0 nn 1 1`, else `0x41` + size |
//! | upload segment | `011 t 0000` | `000 t nnn c` + 7 bytes |
//! | initiate block download | `110 00 cc s 0` | `101 00 sc 00` + block size |
//! | block download segment | `c seqno(7)` (only inside a sub-block) | after the sub-block: `0xA2 ackseq blksize` |
//! | end block download | `110 nnn 0 1` + CRC-16 | `0xA1` |
//! | abort | `0x80` + index, sub-index, code | none |
//!
//! Decisions where CiA 301 leaves room: a request that is not 8 bytes, an unknown command
//! specifier, a segment when no transfer runs and a block upload (objects here are at most a few
//! hundred bytes and upload segmented) are answered with abort 0x0504_0001; a new initiate while a
//! transfer runs aborts the running one (the dictionary drops what it received) and starts the new
//! one; a transfer with no request for [`SdoServer::timeout_ms`] is aborted with 0x0504_0000 by
//! [`SdoServer::poll`]. The block size offered is [`BLOCK_SIZE`]; a sub-block segment out of
//! sequence is dropped with everything after it, and the sub-block's acknowledgement names the
//! last segment received in order, so the client sends the rest again.

use crc::{Crc, Digest};

use super::abort::SdoAbort;
use super::od::ObjectDictionary;

/// Segments per block the server offers in block download (the most CiA 301 allows).
pub const BLOCK_SIZE: u8 = 127;
/// Default time without a request after which a running transfer is aborted.
pub const DEFAULT_TIMEOUT_MS: u32 = 1000;
/// CRC of block transfers: CRC-16/XMODEM (CCITT polynomial 0x1021, initial value 0).
pub static BLOCK_CRC: Crc<u16> = Crc::<u16>::new(&crc::CRC_16_XMODEM);

/// An 8-byte SDO frame payload.
pub type SdoFrame = [u8; 8];

/// The abort frame for `index`/`sub` with `abort`'s code.
pub fn abort_frame(index: u16, sub: u8, abort: SdoAbort) -> SdoFrame {
    let mut f = [0u8; 8];
    f[0] = 0x80;
    f[1..3].copy_from_slice(&index.to_le_bytes());
    f[3] = sub;
    f[4..8].copy_from_slice(&abort.code().to_le_bytes());
    f
}

/// The abort code of an SDO frame's data, if it is an abort (`0x80` and 8 bytes).
pub fn abort_code(data: &[u8]) -> Option<u32> {
    match data {
        [0x80, _, _, _, a, b, c, d] => Some(u32::from_le_bytes([*a, *b, *c, *d])),
        _ => None,
    }
}

fn reply(command: u8, index: u16, sub: u8, data: [u8; 4]) -> SdoFrame {
    let mut f = [0u8; 8];
    f[0] = command;
    f[1..3].copy_from_slice(&index.to_le_bytes());
    f[3] = sub;
    f[4..8].copy_from_slice(&data);
    f
}

/// A segmented transfer: `offset` bytes moved so far, the next segment's toggle.
#[derive(Clone, Copy)]
struct Segmented {
    index: u16,
    sub: u8,
    /// Bytes in all, when known (always for an upload).
    size: Option<u32>,
    offset: u32,
    toggle: bool,
}

/// A transfer in progress.
#[derive(Clone)]
enum Transfer {
    Idle,
    /// Segmented download.
    Download(Segmented),
    /// Segmented upload.
    Upload(Segmented),
    /// Block download, inside a sub-block or waiting for the end request.
    Block(BlockDownload),
}

/// State of a block download.
#[derive(Clone)]
struct BlockDownload {
    index: u16,
    sub: u8,
    size: Option<u32>,
    /// Bytes written to the dictionary (the held-back last segment excluded).
    offset: u32,
    /// Both sides check the CRC.
    crc: bool,
    digest: Digest<'static, u16>,
    /// Sequence number of the last segment received in order in this sub-block.
    last_seq: u8,
    /// A segment came out of order in this sub-block: the rest of it is dropped.
    lost: bool,
    /// The segment flagged last (`c = 1`), held back until the end request says how many of its
    /// bytes are data.
    final_segment: Option<[u8; 7]>,
}

/// The SDO server of one node.
#[derive(Clone)]
pub struct SdoServer {
    transfer: Transfer,
    last_request_ms: u32,
    /// Time without a request after which [`SdoServer::poll`] aborts a running transfer.
    pub timeout_ms: u32,
}

impl core::fmt::Debug for SdoServer {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("SdoServer")
            .field("current", &self.current())
            .field("last_request_ms", &self.last_request_ms)
            .field("timeout_ms", &self.timeout_ms)
            .finish()
    }
}

impl Default for SdoServer {
    fn default() -> Self {
        SdoServer::new(DEFAULT_TIMEOUT_MS)
    }
}

impl SdoServer {
    /// An idle server whose transfers time out after `timeout_ms` without a request.
    pub const fn new(timeout_ms: u32) -> Self {
        SdoServer {
            transfer: Transfer::Idle,
            last_request_ms: 0,
            timeout_ms,
        }
    }

    /// Whether a transfer is running.
    pub fn busy(&self) -> bool {
        !matches!(self.transfer, Transfer::Idle)
    }

    /// The object of the running transfer, if any.
    pub fn current(&self) -> Option<(u16, u8)> {
        match &self.transfer {
            Transfer::Idle => None,
            Transfer::Download(t) | Transfer::Upload(t) => Some((t.index, t.sub)),
            Transfer::Block(b) => Some((b.index, b.sub)),
        }
    }

    /// Aborts a running transfer from the device's side (e.g. a reset or bus-off): the dictionary
    /// drops a partial download. Returns the abort frame to send, if a transfer ran.
    pub fn abort(&mut self, od: &mut impl ObjectDictionary, why: SdoAbort) -> Option<SdoFrame> {
        let (index, sub) = self.current()?;
        self.drop_transfer(od);
        Some(abort_frame(index, sub, why))
    }

    /// Aborts a transfer that has seen no request for [`SdoServer::timeout_ms`].
    pub fn poll(&mut self, now_ms: u32, od: &mut impl ObjectDictionary) -> Option<SdoFrame> {
        if self.busy() && now_ms.wrapping_sub(self.last_request_ms) > self.timeout_ms {
            return self.abort(od, SdoAbort::Timeout);
        }
        None
    }

    fn drop_transfer(&mut self, od: &mut impl ObjectDictionary) {
        match core::mem::replace(&mut self.transfer, Transfer::Idle) {
            Transfer::Download(t) => od.abort_write(t.index, t.sub),
            Transfer::Block(b) => od.abort_write(b.index, b.sub),
            Transfer::Upload { .. } | Transfer::Idle => {}
        }
    }

    /// Fails the running transfer with `why`: the dictionary drops it, the client gets the abort.
    fn fail(
        &mut self,
        od: &mut impl ObjectDictionary,
        index: u16,
        sub: u8,
        why: SdoAbort,
    ) -> Option<SdoFrame> {
        self.drop_transfer(od);
        Some(abort_frame(index, sub, why))
    }

    /// Answers a request that fits no running transfer (abort 0x0504_0001, naming the running
    /// transfer's object if there is one, which is dropped).
    fn unexpected(&mut self, od: &mut impl ObjectDictionary) -> Option<SdoFrame> {
        let (index, sub) = self.current().unwrap_or((0, 0));
        self.fail(od, index, sub, SdoAbort::UnknownCommand)
    }

    /// The running segmented transfer (a download when `download`) that segment request `f`
    /// continues, after its toggle check; else the abort to send.
    fn segment_of(
        &mut self,
        f: &SdoFrame,
        od: &mut impl ObjectDictionary,
        download: bool,
    ) -> Result<Segmented, Option<SdoFrame>> {
        let seg = match (&self.transfer, download) {
            (Transfer::Download(t), true) | (Transfer::Upload(t), false) => *t,
            _ => return Err(self.unexpected(od)),
        };
        if (f[0] & 0x10 != 0) != seg.toggle {
            return Err(self.fail(od, seg.index, seg.sub, SdoAbort::ToggleBit));
        }
        Ok(seg)
    }

    /// Handles one request (the data of a frame on `0x600 + node`) at time `now_ms`; returns the
    /// response to send on `0x580 + node`, if any.
    pub fn on_request(
        &mut self,
        data: &[u8],
        now_ms: u32,
        od: &mut impl ObjectDictionary,
    ) -> Option<SdoFrame> {
        self.last_request_ms = now_ms;
        let Ok(frame) = <[u8; 8]>::try_from(data) else {
            return self.unexpected(od);
        };
        let index = u16::from_le_bytes([frame[1], frame[2]]);
        let sub = frame[3];
        // Inside a sub-block every frame is a segment, except an abort (sequence number 0).
        if let Transfer::Block(b) = &self.transfer
            && b.final_segment.is_none()
            && frame[0] != 0x80
        {
            return self.block_segment(&frame, od);
        }
        match frame[0] >> 5 {
            4 => {
                // Abort from the client: no answer.
                self.drop_transfer(od);
                None
            }
            1 => {
                self.drop_transfer(od);
                self.initiate_download(&frame, index, sub, od)
            }
            0 => self.download_segment(&frame, od),
            2 => {
                self.drop_transfer(od);
                self.initiate_upload(index, sub, od)
            }
            3 => self.upload_segment(&frame, od),
            6 if frame[0] & 0x01 == 0 => {
                self.drop_transfer(od);
                self.initiate_block_download(&frame, index, sub, od)
            }
            6 => self.end_block_download(&frame, od),
            _ => match self.current() {
                Some(_) => self.unexpected(od),
                None => Some(abort_frame(index, sub, SdoAbort::UnknownCommand)),
            },
        }
    }

    /// Checks an object for a download of `len` bytes (when known).
    fn check_write(
        od: &impl ObjectDictionary,
        index: u16,
        sub: u8,
        len: Option<u32>,
    ) -> Result<(), SdoAbort> {
        let entry = od.entry(index, sub)?;
        if !entry.access.writable() {
            return Err(SdoAbort::ReadOnly);
        }
        match (entry.size, len) {
            (Some(max), Some(n)) if entry.exact && n != max => Err(if n > max {
                SdoAbort::TooLong
            } else {
                SdoAbort::TooShort
            }),
            (Some(max), Some(n)) if n > max => Err(SdoAbort::TooLong),
            _ => Ok(()),
        }
    }

    fn initiate_download(
        &mut self,
        f: &SdoFrame,
        index: u16,
        sub: u8,
        od: &mut impl ObjectDictionary,
    ) -> Option<SdoFrame> {
        let expedited = f[0] & 0x02 != 0;
        let sized = f[0] & 0x01 != 0;
        if expedited {
            let len = if sized {
                4 - u32::from((f[0] >> 2) & 0x03)
            } else {
                4
            };
            let data = &f[4..4 + len as usize];
            let done = Self::check_write(od, index, sub, Some(len))
                .and_then(|()| od.begin_write(index, sub, Some(len)))
                .and_then(|()| {
                    od.write(index, sub, 0, data)
                        .and_then(|()| od.end_write(index, sub, len))
                });
            return match done {
                Ok(()) => Some(reply(0x60, index, sub, [0; 4])),
                Err(e) => {
                    od.abort_write(index, sub);
                    Some(abort_frame(index, sub, e))
                }
            };
        }
        let size = sized.then(|| u32::from_le_bytes([f[4], f[5], f[6], f[7]]));
        if let Err(e) =
            Self::check_write(od, index, sub, size).and_then(|()| od.begin_write(index, sub, size))
        {
            return Some(abort_frame(index, sub, e));
        }
        self.transfer = Transfer::Download(Segmented {
            index,
            sub,
            size,
            offset: 0,
            toggle: false,
        });
        Some(reply(0x60, index, sub, [0; 4]))
    }

    fn download_segment(
        &mut self,
        f: &SdoFrame,
        od: &mut impl ObjectDictionary,
    ) -> Option<SdoFrame> {
        let seg = match self.segment_of(f, od, true) {
            Ok(seg) => seg,
            Err(abort) => return abort,
        };
        let Segmented {
            index,
            sub,
            size,
            offset,
            toggle,
        } = seg;
        let t = toggle;
        let len = 7 - u32::from((f[0] >> 1) & 0x07);
        let last = f[0] & 0x01 != 0;
        let end = offset + len;
        if size.is_some_and(|s| end > s) {
            return self.fail(od, index, sub, SdoAbort::TooLong);
        }
        if let Err(e) = od.write(index, sub, offset, &f[1..1 + len as usize]) {
            return self.fail(od, index, sub, e);
        }
        let response = [0x20 | (u8::from(t) << 4), 0, 0, 0, 0, 0, 0, 0];
        if last {
            self.transfer = Transfer::Idle;
            if size.is_some_and(|s| end != s) {
                od.abort_write(index, sub);
                return Some(abort_frame(index, sub, SdoAbort::TooShort));
            }
            if let Err(e) = od.end_write(index, sub, end) {
                od.abort_write(index, sub);
                return Some(abort_frame(index, sub, e));
            }
        } else {
            self.transfer = Transfer::Download(Segmented {
                offset: end,
                toggle: !toggle,
                ..seg
            });
        }
        Some(response)
    }

    fn initiate_upload(
        &mut self,
        index: u16,
        sub: u8,
        od: &mut impl ObjectDictionary,
    ) -> Option<SdoFrame> {
        let entry = match od.entry(index, sub) {
            Ok(e) => e,
            Err(e) => return Some(abort_frame(index, sub, e)),
        };
        if !entry.access.readable() {
            return Some(abort_frame(index, sub, SdoAbort::WriteOnly));
        }
        let Some(size) = entry.size else {
            return Some(abort_frame(index, sub, SdoAbort::UnsupportedAccess));
        };
        if size <= 4 {
            let mut data = [0u8; 4];
            return match od.read(index, sub, 0, &mut data[..size as usize]) {
                Ok(n) if n == size as usize => {
                    let unused = (4 - size as u8) << 2;
                    Some(reply(0x43 | unused, index, sub, data))
                }
                Ok(_) => Some(abort_frame(index, sub, SdoAbort::General)),
                Err(e) => Some(abort_frame(index, sub, e)),
            };
        }
        self.transfer = Transfer::Upload(Segmented {
            index,
            sub,
            size: Some(size),
            offset: 0,
            toggle: false,
        });
        Some(reply(0x41, index, sub, size.to_le_bytes()))
    }

    fn upload_segment(&mut self, f: &SdoFrame, od: &mut impl ObjectDictionary) -> Option<SdoFrame> {
        let seg = match self.segment_of(f, od, false) {
            Ok(seg) => seg,
            Err(abort) => return abort,
        };
        let Segmented {
            index,
            sub,
            offset,
            toggle,
            ..
        } = seg;
        let size = seg.size.unwrap_or(offset);
        let t = toggle;
        let want = (size - offset).min(7) as usize;
        let mut out = [0u8; 8];
        match od.read(index, sub, offset, &mut out[1..1 + want]) {
            Ok(n) if n == want => {}
            Ok(_) => return self.fail(od, index, sub, SdoAbort::General),
            Err(e) => return self.fail(od, index, sub, e),
        }
        let end = offset + want as u32;
        let last = end == size;
        out[0] = (u8::from(t) << 4) | (((7 - want) as u8) << 1) | u8::from(last);
        self.transfer = if last {
            Transfer::Idle
        } else {
            Transfer::Upload(Segmented {
                offset: end,
                toggle: !toggle,
                ..seg
            })
        };
        Some(out)
    }

    fn initiate_block_download(
        &mut self,
        f: &SdoFrame,
        index: u16,
        sub: u8,
        od: &mut impl ObjectDictionary,
    ) -> Option<SdoFrame> {
        let client_crc = f[0] & 0x04 != 0;
        let sized = f[0] & 0x02 != 0;
        let size = sized.then(|| u32::from_le_bytes([f[4], f[5], f[6], f[7]]));
        if let Err(e) =
            Self::check_write(od, index, sub, size).and_then(|()| od.begin_write(index, sub, size))
        {
            return Some(abort_frame(index, sub, e));
        }
        self.transfer = Transfer::Block(BlockDownload {
            index,
            sub,
            size,
            offset: 0,
            crc: client_crc,
            digest: BLOCK_CRC.digest(),
            last_seq: 0,
            lost: false,
            final_segment: None,
        });
        // The server always computes the CRC (sc = 1).
        Some(reply(0xA4, index, sub, [BLOCK_SIZE, 0, 0, 0]))
    }

    fn block_segment(&mut self, f: &SdoFrame, od: &mut impl ObjectDictionary) -> Option<SdoFrame> {
        let Transfer::Block(mut b) = core::mem::replace(&mut self.transfer, Transfer::Idle) else {
            return None;
        };
        let seq = f[0] & 0x7F;
        let last = f[0] & 0x80 != 0;
        let in_order = !b.lost && seq == b.last_seq + 1;
        if in_order {
            if last {
                let mut data = [0u8; 7];
                data.copy_from_slice(&f[1..8]);
                b.final_segment = Some(data);
            } else {
                let end = b.offset + 7;
                if b.size.is_some_and(|s| end > s) {
                    self.transfer = Transfer::Block(b.clone());
                    return self.fail(od, b.index, b.sub, SdoAbort::TooLong);
                }
                if let Err(e) = od.write(b.index, b.sub, b.offset, &f[1..8]) {
                    self.transfer = Transfer::Block(b.clone());
                    return self.fail(od, b.index, b.sub, e);
                }
                b.digest.update(&f[1..8]);
                b.offset = end;
            }
            b.last_seq = seq;
        } else {
            b.lost = true;
        }
        // The sub-block ends at the block size or at the segment flagged last.
        if seq == BLOCK_SIZE || (last && (in_order || b.lost)) {
            let ack = [0xA2, b.last_seq, BLOCK_SIZE, 0, 0, 0, 0, 0];
            b.last_seq = 0;
            b.lost = false;
            self.transfer = Transfer::Block(b);
            return Some(ack);
        }
        if seq == 0 || seq > BLOCK_SIZE {
            self.transfer = Transfer::Block(b.clone());
            return self.fail(od, b.index, b.sub, SdoAbort::InvalidSequence);
        }
        self.transfer = Transfer::Block(b);
        None
    }

    fn end_block_download(
        &mut self,
        f: &SdoFrame,
        od: &mut impl ObjectDictionary,
    ) -> Option<SdoFrame> {
        if !matches!(self.transfer, Transfer::Block(_)) {
            // (A running segmented transfer is dropped, its partial download included.)
            return self.unexpected(od);
        }
        let Transfer::Block(b) = core::mem::replace(&mut self.transfer, Transfer::Idle) else {
            return None;
        };
        let (index, sub) = (b.index, b.sub);
        let Some(final_segment) = b.final_segment else {
            self.transfer = Transfer::Block(b);
            return self.fail(od, index, sub, SdoAbort::UnknownCommand);
        };
        let unused = usize::from((f[0] >> 2) & 0x07);
        let len = 7 - unused;
        let data = &final_segment[..len];
        let total = b.offset + len as u32;
        let mut digest = b.digest;
        digest.update(data);
        let crc = digest.finalize();
        let failed = if b.size.is_some_and(|s| total != s) {
            Some(if b.size.is_some_and(|s| total > s) {
                SdoAbort::TooLong
            } else {
                SdoAbort::TooShort
            })
        } else if b.crc && crc != u16::from_le_bytes([f[1], f[2]]) {
            Some(SdoAbort::Crc)
        } else {
            od.write(index, sub, b.offset, data)
                .and_then(|()| od.end_write(index, sub, total))
                .err()
        };
        if let Some(e) = failed {
            od.abort_write(index, sub);
            return Some(abort_frame(index, sub, e));
        }
        Some([0xA1, 0, 0, 0, 0, 0, 0, 0])
    }
}
