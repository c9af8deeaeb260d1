//! The subset of the socketcand text protocol that python-can 4.6.1 speaks, plus this bus's control
//! verbs (see `docs/sil.md`).
//!
//! Every message is `< word args... >`. The server greets with `< hi >`, answers `< open CHANNEL >`
//! and `< rawmode >` with `< ok >`, receives `< send ID LEN B0 B1 ... >` (length and bytes in hex,
//! bytes space-separated; a 3-digit id is standard, 8 digits extended) and delivers
//! `< frame ID SECONDS.MICROS DATAHEX >` (empty data gives a double space before `>`).
//!
//! CAN FD (a bus started with `--fd`): python-can 4.6.1's socketcand interface has no FD frames,
//! and socketcand's raw mode none either; socketcand's BCM mode names two FD verbs, taken here
//! into the raw mode: a client sends `< fdsend ID FLAGS LEN B0 B1 ... >` (FLAGS hex, Linux
//! `canfd_frame.flags`: 0x01 BRS, 0x02 ESI; LEN decimal, one of the FD lengths 0-8, 12, 16, 20,
//! 24, 32, 48, 64; the bytes hex, as socketcand's BCM `fdsend`) and receives
//! `< fdframe ID FLAGS SECONDS.MICROS DATAHEX >` (the word order of socketcand's BCM `fdframe`,
//! the data as one hex run as in this raw mode's `< frame >`). The candump log writes FD frames
//! as candump does: `ID##F DATAHEX`, F the flags nibble.

use std::fmt::Write as _;

use dex_runtime::can::{AnyFrame, CanFrame, FdFrame};
use embedded_can::{ExtendedId, Frame, Id, StandardId};

/// `canfd_frame.flags` bit: bit-rate switch (the data phase at the data bit rate).
pub const CANFD_BRS: u8 = 0x01;

/// Longest message accepted; a longer run without `>` is discarded as garbage.
pub const MAX_MESSAGE: usize = 512;

/// One parsed message from a client.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Request {
    /// `< open CHANNEL >`.
    Open(String),
    /// `< rawmode >`.
    RawMode,
    /// `< send ID LEN BYTES... >`.
    Send(CanFrame),
    /// `< fdsend ID FLAGS LEN BYTES... >` (CAN FD).
    SendFd(FdFrame),
    /// A control verb of this bus: `< fault ... >`, `< stats >`, `< diag >`, `< time US >`,
    /// `< txtime US >`, `< now >`, `< quit >`.
    Control(Vec<String>),
    /// Anything else (ignored, counted).
    Unknown,
}

/// One parsed message from the server (client side).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Reply {
    /// `< hi >`.
    Hi,
    /// `< ok >`.
    Ok,
    /// `< frame ID TS DATA >`: a frame and its bus time in microseconds.
    Frame(CanFrame, u64),
    /// `< fdframe ID FLAGS TS DATA >`: an FD frame and its bus time in microseconds.
    FdFrame(FdFrame, u64),
    /// `< error CLASS TS >`: an error frame (class bits as in Linux `can/error.h`).
    Error(u32, u64),
    /// Any other message, as words.
    Other(Vec<String>),
}

/// Splits a byte stream into `< ... >` messages, discarding bytes outside them and overlong runs.
#[derive(Debug, Default)]
pub struct Framer {
    buf: Vec<u8>,
    /// Bytes thrown away as garbage.
    pub discarded: u64,
}

impl Framer {
    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// The next complete message's inner text (between `<` and `>`, trimmed), if any.
    pub fn next_message(&mut self) -> Option<String> {
        let Some(start) = self.buf.iter().position(|&b| b == b'<') else {
            self.discarded += self.buf.len() as u64;
            self.buf.clear();
            return None;
        };
        if start > 0 {
            self.discarded += start as u64;
            self.buf.drain(..start);
        }
        match self.buf.iter().position(|&b| b == b'>') {
            Some(end) => {
                let inner: Vec<u8> = self.buf.drain(..=end).collect();
                let text = String::from_utf8_lossy(&inner[1..inner.len() - 1]);
                // A second `<` inside means the first message was cut: keep the last part.
                let text = text.rsplit('<').next().unwrap_or("").trim().to_string();
                Some(text)
            }
            None => {
                if self.buf.len() > MAX_MESSAGE {
                    self.discarded += self.buf.len() as u64;
                    self.buf.clear();
                }
                None
            }
        }
    }
}

fn parse_id(token: &str) -> Option<Id> {
    let raw = u32::from_str_radix(token, 16).ok()?;
    if token.len() <= 3 {
        StandardId::new(u16::try_from(raw).ok()?).map(Id::Standard)
    } else {
        ExtendedId::new(raw).map(Id::Extended)
    }
}

/// Parses a client message (the inner text from [`Framer::next_message`]).
pub fn parse_request(text: &str) -> Request {
    let words: Vec<&str> = text.split_ascii_whitespace().collect();
    match words.as_slice() {
        ["open", channel] => Request::Open((*channel).to_string()),
        ["rawmode"] => Request::RawMode,
        ["send", id, len, bytes @ ..] => {
            parse_send(id, len, bytes).map_or(Request::Unknown, Request::Send)
        }
        ["fdsend", id, flags, len, bytes @ ..] => {
            parse_fdsend(id, flags, len, bytes).map_or(Request::Unknown, Request::SendFd)
        }
        [verb, ..]
            if matches!(
                *verb,
                "fault" | "stats" | "diag" | "time" | "txtime" | "now" | "quit"
            ) =>
        {
            Request::Control(words.iter().map(|w| (*w).to_string()).collect())
        }
        _ => Request::Unknown,
    }
}

fn parse_send(id: &str, len: &str, bytes: &[&str]) -> Option<CanFrame> {
    let id = parse_id(id)?;
    let len = usize::from_str_radix(len, 16).ok()?;
    if len != bytes.len() || len > 8 {
        return None;
    }
    let mut data = [0u8; 8];
    for (slot, b) in data.iter_mut().zip(bytes) {
        *slot = u8::from_str_radix(b, 16).ok()?;
    }
    CanFrame::new(id, &data[..len])
}

fn parse_fdsend(id: &str, flags: &str, len: &str, bytes: &[&str]) -> Option<FdFrame> {
    let id = parse_id(id)?;
    let flags = u8::from_str_radix(flags, 16).ok()?;
    let len: usize = len.parse().ok()?;
    if len != bytes.len() {
        return None;
    }
    let data = bytes
        .iter()
        .map(|b| u8::from_str_radix(b, 16).ok())
        .collect::<Option<Vec<u8>>>()?;
    FdFrame::new_fd(id, &data, flags & CANFD_BRS != 0)
}

/// Parses a server message (client side).
pub fn parse_reply(text: &str) -> Reply {
    let words: Vec<&str> = text.split_ascii_whitespace().collect();
    match words.as_slice() {
        ["hi"] => Reply::Hi,
        ["ok"] => Reply::Ok,
        ["frame", id, ts, rest @ ..] => {
            let data_hex = rest.first().copied().unwrap_or("");
            match (parse_id(id), parse_ts(ts), decode_hex(data_hex)) {
                (Some(id), Some(ts), Some(data)) => {
                    CanFrame::new(id, &data).map_or_else(|| other(&words), |f| Reply::Frame(f, ts))
                }
                _ => other(&words),
            }
        }
        ["fdframe", id, flags, ts, rest @ ..] => {
            let data_hex = rest.first().copied().unwrap_or("");
            match (
                parse_id(id),
                u8::from_str_radix(flags, 16),
                parse_ts(ts),
                decode_hex(data_hex),
            ) {
                (Some(id), Ok(flags), Some(ts), Some(data)) => {
                    FdFrame::new_fd(id, &data, flags & CANFD_BRS != 0)
                        .map_or_else(|| other(&words), |f| Reply::FdFrame(f, ts))
                }
                _ => other(&words),
            }
        }
        ["error", class, ts] => match (u32::from_str_radix(class, 16), parse_ts(ts)) {
            (Ok(c), Some(t)) => Reply::Error(c, t),
            _ => other(&words),
        },
        _ => other(&words),
    }
}

fn other(words: &[&str]) -> Reply {
    Reply::Other(words.iter().map(|w| (*w).to_string()).collect())
}

fn parse_ts(ts: &str) -> Option<u64> {
    let (s, us) = ts.split_once('.')?;
    let s: u64 = s.parse().ok()?;
    let us: u64 = format!("{us:0<6}").get(..6)?.parse().ok()?;
    Some(s * 1_000_000 + us)
}

fn decode_hex(hex: &str) -> Option<Vec<u8>> {
    if !hex.len().is_multiple_of(2) {
        return None;
    }
    (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(hex.get(i..i + 2)?, 16).ok())
        .collect()
}

fn id_text(id: Id) -> String {
    match id {
        Id::Standard(s) => format!("{:03X}", s.as_raw()),
        Id::Extended(e) => format!("{:08X}", e.as_raw()),
    }
}

/// `SECONDS.MICROS` of a bus time in microseconds.
pub fn ts_text(ts_us: u64) -> String {
    format!("{}.{:06}", ts_us / 1_000_000, ts_us % 1_000_000)
}

/// `< frame ID TS DATA >` as the server delivers it.
pub fn frame_message(frame: &CanFrame, ts_us: u64) -> String {
    let mut s = format!("< frame {} {} ", id_text(frame.id()), ts_text(ts_us));
    for b in frame.data() {
        let _ = write!(s, "{b:02X}");
    }
    s.push_str(" >");
    s
}

/// The `canfd_frame.flags` of an FD frame.
fn fd_flags(frame: &FdFrame) -> u8 {
    if frame.bit_rate_switch() {
        CANFD_BRS
    } else {
        0
    }
}

/// `< fdframe ID FLAGS TS DATA >` as the server delivers an FD frame.
pub fn fd_frame_message(frame: &FdFrame, ts_us: u64) -> String {
    let mut s = format!(
        "< fdframe {} {:02X} {} ",
        id_text(frame.id()),
        fd_flags(frame),
        ts_text(ts_us)
    );
    for b in frame.data() {
        let _ = write!(s, "{b:02X}");
    }
    s.push_str(" >");
    s
}

/// The message delivering any frame: `< frame ... >` or `< fdframe ... >`.
pub fn any_frame_message(frame: &AnyFrame, ts_us: u64) -> String {
    match frame {
        AnyFrame::Classic(f) => frame_message(f, ts_us),
        AnyFrame::Fd(f) => fd_frame_message(f, ts_us),
    }
}

/// `< fdsend ID FLAGS LEN BYTES >` as a client sends an FD frame.
pub fn fdsend_message(frame: &FdFrame) -> String {
    let mut s = format!(
        "< fdsend {} {:x} {} ",
        id_text(frame.id()),
        fd_flags(frame),
        frame.data().len()
    );
    for b in frame.data() {
        let _ = write!(s, "{b:x} ");
    }
    s.push('>');
    s
}

/// The candump log line of any frame: classic `ID#DATA`, FD `ID##FDATA` (F the flags nibble).
pub fn candump_any_line(channel: &str, frame: &AnyFrame, ts_us: u64) -> String {
    match frame {
        AnyFrame::Classic(f) => candump_line(channel, f, ts_us),
        AnyFrame::Fd(f) => {
            let mut s = format!(
                "({}) {channel} {}##{:X}",
                ts_text(ts_us),
                id_text(f.id()),
                fd_flags(f)
            );
            for b in f.data() {
                let _ = write!(s, "{b:02X}");
            }
            s
        }
    }
}

/// Parses a line that [`candump_any_line`] wrote (classic or FD); `None` for anything else.
pub fn parse_candump_any(line: &str) -> Option<(u64, AnyFrame)> {
    let mut words = line.split_ascii_whitespace();
    let ts = parse_ts(words.next()?.strip_prefix('(')?.strip_suffix(')')?)?;
    let _channel = words.next()?;
    let frame = words.next()?;
    if words.next().is_some() {
        return None;
    }
    match frame.split_once("##") {
        Some((id, rest)) => {
            let flags = u8::from_str_radix(rest.get(..1)?, 16).ok()?;
            let data = decode_hex(rest.get(1..)?)?;
            let f = FdFrame::new_fd(parse_id(id)?, &data, flags & CANFD_BRS != 0)?;
            Some((ts, AnyFrame::Fd(f)))
        }
        None => parse_candump_line(line).map(|(ts, f)| (ts, AnyFrame::Classic(f))),
    }
}

/// `< error CLASS TS >` (class bits as in Linux `can/error.h`: 0x040 bus-off, 0x100 restarted).
pub fn error_message(class: u32, ts_us: u64) -> String {
    format!("< error {class:03X} {} >", ts_text(ts_us))
}

/// `< send ID LEN BYTES >` as a client sends it.
pub fn send_message(frame: &impl Frame) -> String {
    let mut s = format!("< send {} {:X} ", id_text(frame.id()), frame.data().len());
    for b in frame.data() {
        let _ = write!(s, "{b:x} ");
    }
    s.push('>');
    s
}

/// The candump log line of a frame: `(SECONDS.MICROS) CHANNEL ID#DATA`.
pub fn candump_line(channel: &str, frame: &CanFrame, ts_us: u64) -> String {
    let mut s = format!("({}) {channel} {}#", ts_text(ts_us), id_text(frame.id()));
    for b in frame.data() {
        let _ = write!(s, "{b:02X}");
    }
    s
}

/// Parses a line that [`candump_line`] wrote: `(SECONDS.MICROS) CHANNEL ID#DATAHEX` into the
/// bus time in microseconds and the frame; `None` for anything else.
pub fn parse_candump_line(line: &str) -> Option<(u64, CanFrame)> {
    let mut words = line.split_ascii_whitespace();
    let ts = parse_ts(words.next()?.strip_prefix('(')?.strip_suffix(')')?)?;
    let _channel = words.next()?;
    let (id, data) = words.next()?.split_once('#')?;
    if words.next().is_some() {
        return None;
    }
    let frame = CanFrame::new(parse_id(id)?, &decode_hex(data)?)?;
    Some((ts, frame))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn std_frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::standard(id, data).unwrap_or_else(|| panic!("bad frame"))
    }

    #[test]
    fn candump_lines_parse_back() {
        let f = std_frame(0x280, &[0x91, 0x10, 0x0A]);
        let line = candump_line("vcan0", &f, 1_050_000);
        assert_eq!(parse_candump_line(&line), Some((1_050_000, f)));
        let e = CanFrame::new(
            embedded_can::ExtendedId::new(0x1ABC_DEF0).expect("29 bits"),
            &[],
        )
        .expect("valid frame");
        assert_eq!(
            parse_candump_line(&candump_line("vcan0", &e, 7)),
            Some((7, e))
        );
        for bad in [
            "",
            "(1.0) vcan0",
            "(x) vcan0 123#00",
            "(1.0) vcan0 123#0",
            "1.0 vcan0 123#",
        ] {
            assert_eq!(parse_candump_line(bad), None, "{bad}");
        }
    }

    #[test]
    fn python_can_send_and_frame_round_trip() {
        let f = std_frame(0x123, &[1, 2, 0xFF]);
        assert_eq!(send_message(&f), "< send 123 3 1 2 ff >");
        assert_eq!(parse_request("send 123 3 1 2 ff"), Request::Send(f));
        assert_eq!(
            frame_message(&f, 1_000_001),
            "< frame 123 1.000001 0102FF >"
        );
        assert_eq!(
            parse_reply("frame 123 1.000001 0102FF"),
            Reply::Frame(f, 1_000_001)
        );
        let empty = std_frame(7, &[]);
        assert_eq!(frame_message(&empty, 1_000_000), "< frame 007 1.000000  >");
        assert_eq!(
            parse_reply("frame 007 1.000000"),
            Reply::Frame(empty, 1_000_000)
        );
        assert_eq!(send_message(&empty), "< send 007 0 >");
        assert_eq!(parse_request("send 007 0"), Request::Send(empty));
        assert_eq!(
            candump_line("vcan0", &f, 2_500_000),
            "(2.500000) vcan0 123#0102FF"
        );
    }

    #[test]
    fn fd_frames_round_trip_through_fdsend_fdframe_and_candump() {
        let f = FdFrame::standard(0x210, &[0xAB; 48]).expect("48 bytes");
        let send = fdsend_message(&f);
        assert!(send.starts_with("< fdsend 210 1 48 ab ab "), "{send}");
        let inner = send.trim_start_matches('<').trim_end_matches('>').trim();
        assert_eq!(parse_request(inner), Request::SendFd(f));
        let msg = fd_frame_message(&f, 1_000_001);
        assert!(msg.starts_with("< fdframe 210 01 1.000001 ABAB"), "{msg}");
        let inner = msg.trim_start_matches('<').trim_end_matches('>').trim();
        assert_eq!(parse_reply(inner), Reply::FdFrame(f, 1_000_001));
        let line = candump_any_line("vcan0", &AnyFrame::Fd(f), 7);
        assert!(line.starts_with("(0.000007) vcan0 210##1ABAB"), "{line}");
        assert_eq!(parse_candump_any(&line), Some((7, AnyFrame::Fd(f))));
        let c = std_frame(0x080, &[]);
        let line = candump_any_line("vcan0", &AnyFrame::Classic(c), 7);
        assert_eq!(parse_candump_any(&line), Some((7, AnyFrame::Classic(c))));
        // Not an FD length, a length that does not match the bytes, bad flags: unknown.
        for bad in [
            "fdsend 210 1 9 1 2 3 4 5 6 7 8 9",
            "fdsend 210 1 12 1",
            "fdsend 210 x 0",
        ] {
            assert_eq!(parse_request(bad), Request::Unknown, "{bad}");
        }
    }

    #[test]
    fn garbage_is_discarded_and_bad_sends_are_unknown() {
        let mut fr = Framer::default();
        fr.push(b"xx< hi >junk<open vcan0><rawm");
        assert_eq!(fr.next_message().as_deref(), Some("hi"));
        assert_eq!(fr.next_message().as_deref(), Some("open vcan0"));
        assert_eq!(fr.next_message(), None);
        fr.push(b"ode >");
        assert_eq!(fr.next_message().as_deref(), Some("rawmode"));
        assert_eq!(fr.discarded, 6);
        fr.push(&[b'<'; MAX_MESSAGE + 10]);
        assert_eq!(fr.next_message(), None);
        fr.push(b"< ok >");
        assert_eq!(fr.next_message().as_deref(), Some("ok"));
        for bad in [
            "send 800 1 1",
            "send 123 2 1",
            "send 123 9 1 1 1 1 1 1 1 1 1",
            "send zz 0",
            "bogus",
        ] {
            assert_eq!(parse_request(bad), Request::Unknown, "{bad}");
        }
        assert!(matches!(
            parse_request("fault drop 200 1"),
            Request::Control(_)
        ));
    }
}
