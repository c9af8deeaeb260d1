//! Policy flashing over CAN: the controller node's two policy slots, and the tool's side, an SDO
//! client doing CiA 302-3 program download.
//!
//! The node side (transfer, verification, activation, roll-back) is the runtime's
//! (`dex_runtime::canopen::program` over `dex_runtime::slots`, served by
//! `Controller::on_frame_slots`), the same code a microcontroller runs; this module holds the
//! node's storage for it: two fixed, 8-byte-aligned regions allocated once when the node starts
//! (standing for two flash sectors) and reused for every flash, so memory stays bounded however
//! often the node is flashed (`tests/flash_memory.rs`).
//!
//! The tool side is [`SdoClient`] (CiA 301: expedited download and upload, segmented download,
//! block download with CRC) and [`flash`]: the `.dxpl` downloaded into 0x1F50:1 (block transfer,
//! segmented on request or when the server does not take block transfers), program control
//! 0x1F51:1 = 1 (start), then 0x1F56:1 read back and compared with the file's CRC-32.
//! Requests on `0x600 + node`, responses on `0x580 + node` (`docs/sil.md`).

use std::time::{Duration, Instant};

use dex_runtime::can::CanFrame;
use dex_runtime::canopen::SdoAbort;
use dex_runtime::canopen::program::{PROGRAM_CONTROL, PROGRAM_DATA, PROGRAM_ID, control};
use dex_runtime::canopen::sdo::BLOCK_CRC;
use dex_runtime::controller::{SDO_REQUEST_BASE, SDO_RESPONSE_BASE};
use dex_runtime::slots::CRC32;
pub use dex_runtime::slots::SLOT_HEADER_BYTES;
use embedded_can::Frame;

use crate::client::{ClientError, Received};
use crate::node::NodePort;

/// Largest policy file accepted into a slot.
pub const SLOT_CAPACITY: usize = 512 * 1024;

/// The node's slot storage: two regions of [`SLOT_HEADER_BYTES`] + [`SLOT_CAPACITY`] bytes.
#[derive(Debug)]
pub struct SlotStorage {
    regions: [Box<[u64]>; 2],
}

impl SlotStorage {
    /// Two erased (zeroed) regions.
    pub fn new() -> Self {
        let words = (SLOT_HEADER_BYTES + SLOT_CAPACITY).div_ceil(8);
        SlotStorage {
            regions: [
                vec![0u64; words].into_boxed_slice(),
                vec![0u64; words].into_boxed_slice(),
            ],
        }
    }

    /// Both regions as bytes (8-byte aligned), for `PolicySlots::mount`.
    pub fn regions(&mut self) -> (&mut [u8], &mut [u8]) {
        let [a, b] = &mut self.regions;
        (bytemuck::cast_slice_mut(a), bytemuck::cast_slice_mut(b))
    }

    /// Bytes held, both regions together.
    pub fn bytes(&self) -> usize {
        self.regions.iter().map(|r| r.len() * 8).sum()
    }
}

impl Default for SlotStorage {
    fn default() -> Self {
        Self::new()
    }
}

/// Why an SDO transfer failed.
#[derive(Debug, thiserror::Error)]
pub enum SdoError {
    /// The bus connection failed.
    #[error(transparent)]
    Bus(#[from] ClientError),
    /// The server aborted the transfer.
    #[error("SDO abort {code:#010x} on {index:#06x}:{sub}: {meaning}")]
    Aborted {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// The CiA 301 abort code.
        code: u32,
        /// What the code means (CiA 301), or "unknown abort code".
        meaning: &'static str,
    },
    /// No response in time (the client sent an abort 0x0504_0000 to the server).
    #[error("no SDO response from node {node} within {timeout:?} ({index:#06x}:{sub})")]
    Timeout {
        /// Node id.
        node: u8,
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// How long the client waited.
        timeout: Duration,
    },
    /// A response the protocol does not allow at this point (the client sent an abort to the
    /// server).
    #[error("unexpected SDO response {got:02x?} to {index:#06x}:{sub}: expected {expected}")]
    Unexpected {
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// What the client waited for.
        expected: &'static str,
        /// The response's bytes.
        got: Vec<u8>,
    },
    /// An expedited download of more than 4 bytes, or a download of nothing.
    #[error("SDO download of {0} bytes: not 1..=4 (expedited) or at least 1 (block, segmented)")]
    Size(usize),
}

impl SdoError {
    /// The abort code, if the server aborted.
    pub fn abort_code(&self) -> Option<u32> {
        match self {
            SdoError::Aborted { code, .. } => Some(*code),
            _ => None,
        }
    }
}

/// Why flashing failed.
#[derive(Debug, thiserror::Error)]
pub enum FlashError {
    /// The download into 0x1F50:1 failed (an abort 0x0800_0020 means the node refused the file:
    /// not a policy file, or not one for this controller).
    #[error("program download (0x1F50): {0}")]
    Download(SdoError),
    /// Program control 0x1F51:1 = 1 (start) failed (0x0800_0022: the node is operational;
    /// 0x0800_0024: nothing verified to start).
    #[error("program start (0x1F51): {0}")]
    Start(SdoError),
    /// Reading the program software identification 0x1F56:1 failed.
    #[error("program identification (0x1F56): {0}")]
    Identify(SdoError),
    /// The node runs another file than the one downloaded.
    #[error("the node reports program {got:#010x} (0x1F56), the file's CRC-32 is {expected:#010x}")]
    Mismatch {
        /// The file's CRC-32.
        expected: u32,
        /// What 0x1F56:1 holds.
        got: u32,
    },
}

/// How [`flash`] downloads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Transfer {
    /// Block download with CRC; segmented when the server answers the block initiate with
    /// 0x0504_0001 (no block transfers).
    #[default]
    Block,
    /// Segmented download only.
    Segmented,
}

/// What a successful [`flash`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Flashed {
    /// CRC-32 of the file, as 0x1F56:1 now reports it.
    pub crc: u32,
    /// Bytes downloaded.
    pub bytes: usize,
    /// The transfer used (segmented after a block refusal).
    pub transfer: Transfer,
    /// Request frames sent.
    pub requests: usize,
}

/// An SDO client (CiA 301) for one node over a [`NodePort`].
pub struct SdoClient<'p, P: NodePort> {
    port: &'p mut P,
    node: u8,
    /// How long to wait for each response.
    pub timeout: Duration,
    requests: usize,
}

fn request(command: u8, index: u16, sub: u8, data: [u8; 4]) -> [u8; 8] {
    let i = index.to_le_bytes();
    [command, i[0], i[1], sub, data[0], data[1], data[2], data[3]]
}

impl<'p, P: NodePort> SdoClient<'p, P> {
    /// A client for node `node` over `port`, waiting 1 s for each response.
    pub fn new(port: &'p mut P, node: u8) -> Self {
        SdoClient {
            port,
            node,
            timeout: Duration::from_secs(1),
            requests: 0,
        }
    }

    /// Request frames sent so far.
    pub fn requests(&self) -> usize {
        self.requests
    }

    fn queue(&mut self, data: &[u8; 8]) {
        // An 8-byte standard frame on a valid 11-bit id always builds.
        if let Some(f) = CanFrame::standard(SDO_REQUEST_BASE + u16::from(self.node), data) {
            self.port.queue(&f);
            self.requests += 1;
        }
    }

    fn send(&mut self, data: &[u8; 8]) -> Result<(), SdoError> {
        self.queue(data);
        Ok(self.port.flush()?)
    }

    /// Sends an abort for `index`:`sub` to the server.
    fn send_abort(&mut self, index: u16, sub: u8, why: SdoAbort) {
        let _ = self.send(&request(0x80, index, sub, why.code().to_le_bytes()));
    }

    /// The next response on `0x580 + node`; an abort becomes [`SdoError::Aborted`].
    fn response(&mut self, index: u16, sub: u8) -> Result<[u8; 8], SdoError> {
        let id = SDO_RESPONSE_BASE + u16::from(self.node);
        let deadline = Instant::now() + self.timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                self.send_abort(index, sub, SdoAbort::Timeout);
                return Err(SdoError::Timeout {
                    node: self.node,
                    index,
                    sub,
                    timeout: self.timeout,
                });
            }
            let Some(Received::Frame(f, _)) = self.port.receive_timeout(left)? else {
                continue;
            };
            if f.standard_id() != Some(id) {
                continue;
            }
            let mut d = [0u8; 8];
            let n = f.data().len().min(8);
            d[..n].copy_from_slice(&f.data()[..n]);
            if d[0] == 0x80 {
                let code = u32::from_le_bytes([d[4], d[5], d[6], d[7]]);
                return Err(SdoError::Aborted {
                    index: u16::from_le_bytes([d[1], d[2]]),
                    sub: d[3],
                    code,
                    meaning: SdoAbort::from_code(code)
                        .map_or("unknown abort code", SdoAbort::description),
                });
            }
            return Ok(d);
        }
    }

    /// A response whose command byte, masked with `mask`, is `want`; else the server is sent an
    /// abort and the error names `expected`.
    fn expect(
        &mut self,
        index: u16,
        sub: u8,
        mask: u8,
        want: u8,
        expected: &'static str,
    ) -> Result<[u8; 8], SdoError> {
        let r = self.response(index, sub)?;
        if r[0] & mask != want {
            self.send_abort(index, sub, SdoAbort::UnknownCommand);
            return Err(SdoError::Unexpected {
                index,
                sub,
                expected,
                got: r.to_vec(),
            });
        }
        Ok(r)
    }

    /// Expedited download of 1 to 4 bytes.
    pub fn download_expedited(
        &mut self,
        index: u16,
        sub: u8,
        value: &[u8],
    ) -> Result<(), SdoError> {
        if value.is_empty() || value.len() > 4 {
            return Err(SdoError::Size(value.len()));
        }
        let mut data = [0u8; 4];
        data[..value.len()].copy_from_slice(value);
        let unused = (4 - value.len()) as u8;
        self.send(&request(0x23 | (unused << 2), index, sub, data))?;
        self.expect(index, sub, 0xFF, 0x60, "initiate download response 0x60")?;
        Ok(())
    }

    /// Expedited upload of a value of at most 4 bytes (the bytes the server sent).
    pub fn upload_expedited(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, SdoError> {
        self.send(&request(0x40, index, sub, [0; 4]))?;
        let r = self.expect(index, sub, 0xE2, 0x42, "expedited upload response")?;
        let n = if r[0] & 0x01 != 0 {
            4 - usize::from((r[0] >> 2) & 0x03)
        } else {
            4
        };
        Ok(r[4..4 + n].to_vec())
    }

    /// Reads a u32 (expedited upload, little endian, shorter values zero-extended).
    pub fn read_u32(&mut self, index: u16, sub: u8) -> Result<u32, SdoError> {
        let b = self.upload_expedited(index, sub)?;
        let mut v = [0u8; 4];
        v[..b.len()].copy_from_slice(&b);
        Ok(u32::from_le_bytes(v))
    }

    /// Segmented download of `data` (size indicated).
    pub fn download_segmented(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoError> {
        if data.is_empty() {
            return Err(SdoError::Size(0));
        }
        self.send(&request(
            0x21,
            index,
            sub,
            (data.len() as u32).to_le_bytes(),
        ))?;
        self.expect(index, sub, 0xFF, 0x60, "initiate download response 0x60")?;
        let chunks: Vec<&[u8]> = data.chunks(7).collect();
        for (k, chunk) in chunks.iter().enumerate() {
            let toggle = (k % 2) as u8;
            let last = u8::from(k + 1 == chunks.len());
            let mut f = [0u8; 8];
            f[0] = (toggle << 4) | (((7 - chunk.len()) as u8) << 1) | last;
            f[1..1 + chunk.len()].copy_from_slice(chunk);
            self.send(&f)?;
            self.expect(
                index,
                sub,
                0xFF,
                0x20 | (toggle << 4),
                "download segment response",
            )?;
        }
        Ok(())
    }

    /// Block download of `data` with CRC (CiA 301): sub-blocks of the size the server offers, a
    /// sub-block repeated from the first segment the server did not acknowledge.
    pub fn download_block(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoError> {
        if data.is_empty() {
            return Err(SdoError::Size(0));
        }
        self.send(&request(
            0xC6,
            index,
            sub,
            (data.len() as u32).to_le_bytes(),
        ))?;
        let r = self.expect(index, sub, 0xFB, 0xA0, "initiate block download response")?;
        let mut blksize = usize::from(r[4]);
        let chunks: Vec<&[u8]> = data.chunks(7).collect();
        let mut next = 0;
        while next < chunks.len() {
            if blksize == 0 || blksize > 127 {
                self.send_abort(index, sub, SdoAbort::InvalidBlockSize);
                return Err(SdoError::Unexpected {
                    index,
                    sub,
                    expected: "a block size of 1..=127",
                    got: r.to_vec(),
                });
            }
            let count = blksize.min(chunks.len() - next);
            for seq in 1..=count {
                let k = next + seq - 1;
                let mut f = [0u8; 8];
                f[0] = (u8::from(k + 1 == chunks.len()) << 7) | seq as u8;
                f[1..1 + chunks[k].len()].copy_from_slice(chunks[k]);
                self.queue(&f);
            }
            self.port.flush()?;
            let ack = self.expect(index, sub, 0xFF, 0xA2, "block acknowledgement 0xA2")?;
            let acked = usize::from(ack[1]);
            if acked > count {
                self.send_abort(index, sub, SdoAbort::InvalidSequence);
                return Err(SdoError::Unexpected {
                    index,
                    sub,
                    expected: "an acknowledged sequence number within the sub-block",
                    got: ack.to_vec(),
                });
            }
            next += acked;
            blksize = usize::from(ack[2]);
        }
        let unused = chunks.last().map_or(0, |c| 7 - c.len()) as u8;
        let crc = BLOCK_CRC.checksum(data).to_le_bytes();
        self.send(&[0xC1 | (unused << 2), crc[0], crc[1], 0, 0, 0, 0, 0])?;
        self.expect(index, sub, 0xFF, 0xA1, "end block download response 0xA1")?;
        Ok(())
    }
}

/// Flashes `image` (a `.dxpl`) into node `node` over `port`: downloads it into 0x1F50:1 (`how`),
/// starts it (0x1F51:1 = 1) and checks that 0x1F56:1 reports the file's CRC-32, waiting at most
/// `timeout` for each response. The node must not be operational (0x0800_0022); a file it
/// refuses aborts the download with 0x0800_0020 and the node keeps its policy.
pub fn flash<P: NodePort>(
    port: &mut P,
    node: u8,
    image: &[u8],
    how: Transfer,
    timeout: Duration,
) -> Result<Flashed, FlashError> {
    let mut sdo = SdoClient::new(port, node);
    sdo.timeout = timeout;
    let used = match how {
        Transfer::Segmented => {
            sdo.download_segmented(PROGRAM_DATA, 1, image)
                .map_err(FlashError::Download)?;
            Transfer::Segmented
        }
        Transfer::Block => match sdo.download_block(PROGRAM_DATA, 1, image) {
            Ok(()) => Transfer::Block,
            Err(SdoError::Aborted { code, .. }) if code == SdoAbort::UnknownCommand.code() => {
                sdo.download_segmented(PROGRAM_DATA, 1, image)
                    .map_err(FlashError::Download)?;
                Transfer::Segmented
            }
            Err(e) => return Err(FlashError::Download(e)),
        },
    };
    sdo.download_expedited(PROGRAM_CONTROL, 1, &[control::START])
        .map_err(FlashError::Start)?;
    let got = sdo.read_u32(PROGRAM_ID, 1).map_err(FlashError::Identify)?;
    let expected = CRC32.checksum(image);
    if got != expected {
        return Err(FlashError::Mismatch { expected, got });
    }
    Ok(Flashed {
        crc: got,
        bytes: image.len(),
        transfer: used,
        requests: sdo.requests(),
    })
}
