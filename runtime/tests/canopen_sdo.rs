//! The SDO server against a client written from CiA 301's frame layouts: expedited, segmented and
//! block transfers, and an abort with the documented code for every refusal.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_runtime::canopen::sdo::{BLOCK_CRC, BLOCK_SIZE};
use dex_runtime::canopen::{Access, Entry, ObjectDictionary, SdoAbort, SdoFrame, SdoServer};

/// A dictionary with a u32 (0x2000), a read-only string (0x2001), a write-only domain of at most
/// 4096 bytes that keeps what a completed download wrote (0x2002) and a u16 (0x2003, sub 1 only).
#[derive(Default)]
struct Dict {
    value: u32,
    word: u16,
    name: Vec<u8>,
    domain: Vec<u8>,
    pending: Vec<u8>,
    committed: u32,
    aborted: u32,
    /// `end_write` of the domain refuses (a program that fails verification).
    refuse_domain: bool,
}

impl ObjectDictionary for Dict {
    fn entry(&self, index: u16, sub: u8) -> Result<Entry, SdoAbort> {
        let e = |access, size, exact| Entry {
            access,
            size,
            exact,
        };
        match (index, sub) {
            (0x2000, 0) => Ok(e(Access::ReadWrite, Some(4), true)),
            (0x2001, 0) => Ok(e(Access::ReadOnly, Some(self.name.len() as u32), true)),
            (0x2002, 0) => Ok(e(Access::WriteOnly, Some(4096), false)),
            (0x2003, 1) => Ok(e(Access::ReadWrite, Some(2), true)),
            (0x2003, _) => Err(SdoAbort::NoSubIndex),
            _ => Err(SdoAbort::NoObject),
        }
    }

    fn read(
        &mut self,
        index: u16,
        _sub: u8,
        offset: u32,
        buf: &mut [u8],
    ) -> Result<usize, SdoAbort> {
        let bytes: Vec<u8> = match index {
            0x2000 => self.value.to_le_bytes().to_vec(),
            0x2001 => self.name.clone(),
            0x2003 => self.word.to_le_bytes().to_vec(),
            _ => return Err(SdoAbort::WriteOnly),
        };
        let rest = &bytes[offset as usize..];
        let n = rest.len().min(buf.len());
        buf[..n].copy_from_slice(&rest[..n]);
        Ok(n)
    }

    fn begin_write(&mut self, _index: u16, _sub: u8, _size: Option<u32>) -> Result<(), SdoAbort> {
        self.pending.clear();
        Ok(())
    }

    fn write(&mut self, _index: u16, _sub: u8, offset: u32, data: &[u8]) -> Result<(), SdoAbort> {
        assert_eq!(
            offset as usize,
            self.pending.len(),
            "offsets increase without gaps"
        );
        self.pending.extend_from_slice(data);
        Ok(())
    }

    fn end_write(&mut self, index: u16, _sub: u8, total: u32) -> Result<(), SdoAbort> {
        assert_eq!(total as usize, self.pending.len());
        match index {
            0x2000 => self.value = u32::from_le_bytes(self.pending[..4].try_into().unwrap()),
            0x2003 => self.word = u16::from_le_bytes(self.pending[..2].try_into().unwrap()),
            0x2002 if self.refuse_domain => return Err(SdoAbort::CannotStore),
            0x2002 => self.domain = self.pending.clone(),
            _ => return Err(SdoAbort::ReadOnly),
        }
        self.committed += 1;
        Ok(())
    }

    fn abort_write(&mut self, _index: u16, _sub: u8) {
        self.pending.clear();
        self.aborted += 1;
    }
}

fn request(bytes: &[u8]) -> SdoFrame {
    let mut f = [0u8; 8];
    f[..bytes.len()].copy_from_slice(bytes);
    f
}

fn abort_code(f: &SdoFrame) -> Option<u32> {
    (f[0] == 0x80).then(|| u32::from_le_bytes([f[4], f[5], f[6], f[7]]))
}

fn send(s: &mut SdoServer, d: &mut Dict, f: SdoFrame) -> Option<SdoFrame> {
    s.on_request(&f, 0, d)
}

#[test]
fn expedited_download_and_upload() {
    let (mut s, mut d) = (SdoServer::default(), Dict::default());
    // 0x23: expedited, size indicated, 4 bytes.
    let r = send(
        &mut s,
        &mut d,
        request(&[0x23, 0x00, 0x20, 0, 0x78, 0x56, 0x34, 0x12]),
    )
    .unwrap();
    assert_eq!(r, request(&[0x60, 0x00, 0x20, 0]));
    assert_eq!(d.value, 0x1234_5678);
    let r = send(&mut s, &mut d, request(&[0x40, 0x00, 0x20, 0])).unwrap();
    assert_eq!(r, request(&[0x43, 0x00, 0x20, 0, 0x78, 0x56, 0x34, 0x12]));
    // A u16: expedited with n = 2 unused bytes (0x2B), read back as 0x4B.
    let r = send(&mut s, &mut d, request(&[0x2B, 0x03, 0x20, 1, 0x34, 0x12])).unwrap();
    assert_eq!(r[0], 0x60);
    let r = send(&mut s, &mut d, request(&[0x40, 0x03, 0x20, 1])).unwrap();
    assert_eq!(r, request(&[0x4B, 0x03, 0x20, 1, 0x34, 0x12]));
    assert!(!s.busy());
}

#[test]
fn every_refusal_is_an_abort_with_its_cia_301_code() {
    let (mut s, mut d) = (SdoServer::default(), Dict::default());
    let cases: [(&[u8], u32); 7] = [
        (&[0x40, 0x99, 0x20, 0], 0x0602_0000), // no such object
        (&[0x40, 0x03, 0x20, 7], 0x0609_0011), // no such sub-index
        (&[0x23, 0x01, 0x20, 0, 1, 2, 3, 4], 0x0601_0002), // write a read-only object
        (&[0x40, 0x02, 0x20, 0], 0x0601_0001), // read a write-only object
        (&[0x2B, 0x00, 0x20, 0, 1, 2], 0x0607_0013), // 2 bytes into a u32
        (&[0x21, 0x00, 0x20, 0, 9, 0, 0, 0], 0x0607_0012), // 9 bytes into a u32
        (&[0xE0, 0x00, 0x20, 0], 0x0504_0001), // unknown command specifier
    ];
    for (req, code) in cases {
        let r = send(&mut s, &mut d, request(req)).unwrap();
        assert_eq!(abort_code(&r), Some(code), "{req:02x?}");
        assert_eq!(SdoAbort::from_code(code).map(SdoAbort::code), Some(code));
    }
    // A request with bit 7 set is not mistaken for a reply: 0x84 is a client abort (no answer).
    assert_eq!(send(&mut s, &mut d, request(&[0x84])), None);
    // A segment with no transfer running, and a request shorter than 8 bytes.
    let r = send(&mut s, &mut d, request(&[0x00, 1, 2, 3, 4, 5, 6, 7])).unwrap();
    assert_eq!(abort_code(&r), Some(0x0504_0001));
    let r = s.on_request(&[0x40, 0x00, 0x20], 0, &mut d).unwrap();
    assert_eq!(abort_code(&r), Some(0x0504_0001));
    assert_eq!(d.value, 0);
}

/// Downloads `data` to the domain segment by segment; returns the last response.
fn segmented_download(s: &mut SdoServer, d: &mut Dict, data: &[u8]) -> SdoFrame {
    let size = (data.len() as u32).to_le_bytes();
    let r = send(
        s,
        d,
        request(&[0x21, 0x02, 0x20, 0, size[0], size[1], size[2], size[3]]),
    )
    .unwrap();
    if r[0] != 0x60 {
        return r;
    }
    let chunks: Vec<&[u8]> = data.chunks(7).collect();
    let mut last = r;
    for (k, chunk) in chunks.iter().enumerate() {
        let toggle = (k % 2) as u8;
        let end = u8::from(k + 1 == chunks.len());
        let mut f = [0u8; 8];
        f[0] = (toggle << 4) | (((7 - chunk.len()) as u8) << 1) | end;
        f[1..1 + chunk.len()].copy_from_slice(chunk);
        last = send(s, d, f).unwrap();
        if last[0] == 0x80 {
            return last;
        }
        assert_eq!(last[0], 0x20 | (toggle << 4));
    }
    last
}

#[test]
fn segmented_download_and_upload() {
    let (mut s, mut d) = (SdoServer::default(), Dict::default());
    let data: Vec<u8> = (0..100u8).collect();
    segmented_download(&mut s, &mut d, &data);
    assert_eq!(d.domain, data);
    assert!(!s.busy());

    d.name = b"dex-runtime controller".to_vec();
    let r = send(&mut s, &mut d, request(&[0x40, 0x01, 0x20, 0])).unwrap();
    assert_eq!(r[0], 0x41);
    assert_eq!(u32::from_le_bytes(r[4..8].try_into().unwrap()), 22);
    let mut got = Vec::new();
    for k in 0.. {
        let toggle = (k % 2) as u8;
        let r = send(&mut s, &mut d, request(&[0x60 | (toggle << 4)])).unwrap();
        assert_eq!(r[0] & 0x10, toggle << 4);
        let n = 7 - usize::from((r[0] >> 1) & 0x07);
        got.extend_from_slice(&r[1..1 + n]);
        if r[0] & 0x01 != 0 {
            break;
        }
    }
    assert_eq!(got, d.name);
    assert!(!s.busy());
}

#[test]
fn a_repeated_toggle_or_a_short_transfer_aborts_and_drops_what_was_written() {
    let (mut s, mut d) = (SdoServer::default(), Dict::default());
    d.domain = b"old".to_vec();
    let r = send(&mut s, &mut d, request(&[0x21, 0x02, 0x20, 0, 20, 0, 0, 0])).unwrap();
    assert_eq!(r[0], 0x60);
    send(&mut s, &mut d, request(&[0x00, 1, 2, 3, 4, 5, 6, 7])).unwrap();
    // The same toggle again.
    let r = send(&mut s, &mut d, request(&[0x00, 1, 2, 3, 4, 5, 6, 7])).unwrap();
    assert_eq!(abort_code(&r), Some(0x0503_0000));
    assert!(!s.busy());
    assert_eq!(d.domain, b"old");
    assert_eq!(d.aborted, 1);
    // 20 bytes announced, 14 sent with the last-segment flag.
    send(&mut s, &mut d, request(&[0x21, 0x02, 0x20, 0, 20, 0, 0, 0])).unwrap();
    send(&mut s, &mut d, request(&[0x00, 1, 2, 3, 4, 5, 6, 7])).unwrap();
    let r = send(&mut s, &mut d, request(&[0x11, 1, 2, 3, 4, 5, 6, 7])).unwrap();
    assert_eq!(abort_code(&r), Some(0x0607_0013));
    assert_eq!(d.domain, b"old");
    // A value the dictionary refuses to store at the end.
    d.refuse_domain = true;
    let r = segmented_download(&mut s, &mut d, &[9; 30]);
    assert_eq!(abort_code(&r), Some(0x0800_0020));
    assert_eq!(d.domain, b"old");
}

#[test]
fn a_silent_client_times_out_and_a_new_initiate_replaces_a_running_transfer() {
    let (mut s, mut d) = (SdoServer::new(500), Dict::default());
    s.on_request(&request(&[0x21, 0x02, 0x20, 0, 20, 0, 0, 0]), 1000, &mut d);
    assert_eq!(s.poll(1400, &mut d), None);
    let r = s.poll(1501, &mut d).unwrap();
    assert_eq!(abort_code(&r), Some(0x0504_0000));
    assert_eq!(u16::from_le_bytes([r[1], r[2]]), 0x2002);
    assert!(!s.busy());
    s.on_request(&request(&[0x21, 0x02, 0x20, 0, 20, 0, 0, 0]), 2000, &mut d);
    let r = s
        .on_request(&request(&[0x23, 0x00, 0x20, 0, 1, 0, 0, 0]), 2001, &mut d)
        .unwrap();
    assert_eq!(r[0], 0x60);
    assert_eq!((d.value, d.aborted), (1, 2));
    assert!(!s.busy());
}

/// A block download of `data` as CiA 301's client does it; `drop` names a (sub-block, sequence
/// number) whose first sending is lost. Returns the final response.
fn block_download(
    s: &mut SdoServer,
    d: &mut Dict,
    data: &[u8],
    drop: Option<(usize, u8)>,
    bad_crc: bool,
) -> SdoFrame {
    let size = (data.len() as u32).to_le_bytes();
    // 0xC6: block download initiate, client CRC, size indicated.
    let r = send(
        s,
        d,
        request(&[0xC6, 0x02, 0x20, 0, size[0], size[1], size[2], size[3]]),
    )
    .unwrap();
    if r[0] == 0x80 {
        return r;
    }
    assert_eq!(r[0] & 0xE3, 0xA0, "block download initiate response");
    let mut blksize = r[4];
    assert_eq!(blksize, BLOCK_SIZE);
    let chunks: Vec<&[u8]> = data.chunks(7).collect();
    let mut next = 0usize;
    let mut block = 0usize;
    let mut dropped = false;
    let mut lost_any = 0;
    while next < chunks.len() {
        let mut ack = None;
        for seq in 1..=blksize {
            let k = next + usize::from(seq) - 1;
            if k >= chunks.len() {
                break;
            }
            let last = k + 1 == chunks.len();
            let mut f = [0u8; 8];
            f[0] = (u8::from(last) << 7) | seq;
            f[1..1 + chunks[k].len()].copy_from_slice(chunks[k]);
            if !dropped && drop == Some((block, seq)) {
                dropped = true;
                lost_any += 1;
                continue;
            }
            let r = send(s, d, f);
            if let Some(r) = r {
                ack = Some(r);
                break;
            }
        }
        let ack = ack.expect("the server acknowledges each sub-block");
        if ack[0] == 0x80 {
            return ack;
        }
        assert_eq!(ack[0], 0xA2);
        next += usize::from(ack[1]);
        blksize = ack[2];
        block += 1;
    }
    assert_eq!(
        lost_any,
        usize::from(drop.is_some()),
        "the segment to lose was sent"
    );
    let unused = (7 - chunks.last().map_or(0, |c| c.len())) as u8;
    let mut crc = BLOCK_CRC.checksum(data);
    if bad_crc {
        crc ^= 1;
    }
    let c = crc.to_le_bytes();
    send(s, d, request(&[0xC1 | (unused << 2), c[0], c[1]])).unwrap()
}

#[test]
fn block_download_with_crc_and_a_lost_segment() {
    let (mut s, mut d) = (SdoServer::default(), Dict::default());
    let data: Vec<u8> = (0..2000u32).map(|i| (i * 7 + 3) as u8).collect();
    let r = block_download(&mut s, &mut d, &data, None, false);
    assert_eq!(r[0], 0xA1);
    assert_eq!(d.domain, data);
    assert!(!s.busy());

    // Segment 40 of the first sub-block is lost: the sub-block's ack names 39 and the client
    // sends from there again.
    let data2: Vec<u8> = data.iter().rev().copied().collect();
    let r = block_download(&mut s, &mut d, &data2, Some((0, 40)), false);
    assert_eq!(r[0], 0xA1);
    assert_eq!(d.domain, data2);
    // A segment lost just before the one flagged last: the last one, out of order, ends the
    // sub-block and its ack names the segment before the lost one. (When the last segment itself is
    // lost, the server cannot know the sub-block ended: the client's timeout aborts the transfer.)
    let segments = data.len().div_ceil(7);
    let full_blocks = (segments - 1) / usize::from(BLOCK_SIZE);
    let last_seq = (segments - full_blocks * usize::from(BLOCK_SIZE)) as u8;
    let r = block_download(
        &mut s,
        &mut d,
        &data,
        Some((full_blocks, last_seq - 1)),
        false,
    );
    assert_eq!(r[0], 0xA1);
    assert_eq!(d.domain, data);
}

#[test]
fn a_block_download_with_a_wrong_crc_or_length_is_aborted_and_dropped() {
    let (mut s, mut d) = (SdoServer::default(), Dict::default());
    d.domain = b"old".to_vec();
    let data = vec![5u8; 500];
    let r = block_download(&mut s, &mut d, &data, None, true);
    assert_eq!(abort_code(&r), Some(0x0504_0004));
    assert_eq!(d.domain, b"old");
    assert!(!s.busy());
    // More than the domain can take is refused at the initiate.
    let r = block_download(&mut s, &mut d, &vec![1u8; 5000], None, false);
    assert_eq!(abort_code(&r), Some(0x0607_0012));
    // An abort from the client in the middle of a sub-block ends it without an answer.
    let r = send(
        &mut s,
        &mut d,
        request(&[0xC6, 0x02, 0x20, 0, 100, 0, 0, 0]),
    )
    .unwrap();
    assert_eq!(r[0] & 0xE3, 0xA0);
    assert_eq!(
        send(&mut s, &mut d, request(&[0x01, 1, 2, 3, 4, 5, 6, 7])),
        None
    );
    assert_eq!(
        send(
            &mut s,
            &mut d,
            request(&[0x80, 0x02, 0x20, 0, 0, 0, 0, 0x08])
        ),
        None
    );
    assert!(!s.busy());
    assert_eq!(d.domain, b"old");
}
