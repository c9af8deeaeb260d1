//! The SLCAN codec: round trips, time stamps, and every kind of bad line.

use dex_slcan::{Command, LineReader, MAX_LINE, Push, SlcanError, encode_frame, parse_line};
use embedded_can::{ExtendedId, Id, StandardId};

fn std_id(raw: u16) -> Id {
    Id::Standard(StandardId::new(raw).unwrap_or(StandardId::ZERO))
}

fn frame_of(line: &[u8]) -> dex_slcan::SlcanFrame {
    match parse_line(line) {
        Ok(Command::Frame(f)) => f,
        other => panic!("not a frame: {other:?}"),
    }
}

#[test]
fn standard_frame_round_trips() {
    let line = encode_frame(std_id(0x190), &[1, 2, 0xAB], None);
    assert_eq!(line.as_bytes(), b"t19030102AB\r");
    let f = frame_of(&line.as_bytes()[..line.as_bytes().len() - 1]);
    assert_eq!(f.id, std_id(0x190));
    assert_eq!(f.data(), &[1, 2, 0xAB]);
    assert_eq!(f.timestamp_ms, None);
}

#[test]
fn time_stamp_round_trips_and_wraps() {
    let line = encode_frame(std_id(0x80), &[], Some(60_000 + 1_234));
    assert_eq!(line.as_bytes(), b"t080004D2\r");
    let f = frame_of(b"t080004D2");
    assert_eq!(f.timestamp_ms, Some(1_234));
    assert!(f.data().is_empty());
}

#[test]
fn extended_and_remote_frames_parse() {
    let f = frame_of(b"T1ABCDEF02BEEF");
    assert_eq!(
        f.id,
        Id::Extended(ExtendedId::new(0x1ABC_DEF0).unwrap_or(ExtendedId::ZERO))
    );
    assert_eq!(f.data(), &[0xBE, 0xEF]);
    let r = frame_of(b"r1238");
    assert!(r.remote);
    assert_eq!(r.len, 8);
}

#[test]
fn commands_parse() {
    assert_eq!(parse_line(b"O"), Ok(Command::Open));
    assert_eq!(parse_line(b"C"), Ok(Command::Close));
    assert_eq!(parse_line(b"S6"), Ok(Command::Bitrate(6)));
    assert_eq!(parse_line(b"V"), Ok(Command::Version));
    assert_eq!(parse_line(b"F"), Ok(Command::Status));
    assert_eq!(parse_line(b"Z1"), Ok(Command::Timestamps(true)));
    assert_eq!(parse_line(b"z"), Ok(Command::Ack));
    assert_eq!(parse_line(b""), Ok(Command::Empty));
}

#[test]
fn bad_lines_are_errors_not_panics() {
    let cases: &[(&[u8], SlcanError)] = &[
        (b"x", SlcanError::UnknownCommand(b'x')),
        (b"t12", SlcanError::BadLength),
        (b"t1G31", SlcanError::NotHex),
        (b"t8001", SlcanError::BadId),
        (b"t1009", SlcanError::BadDlc),
        (b"t1002AA", SlcanError::BadLength),
        (b"t1001AAB", SlcanError::BadLength),
        (b"T2000000000", SlcanError::BadId),
        (b"S9", SlcanError::BadArgument),
        (b"Ox", SlcanError::BadLength),
        (b"t10000FFFFF", SlcanError::BadLength),
        (b"t1000EA60", SlcanError::BadArgument),
    ];
    for (line, want) in cases {
        assert_eq!(
            parse_line(line),
            Err(*want),
            "{}",
            String::from_utf8_lossy(line)
        );
    }
    // Every byte value as a one-byte line, and every prefix of a valid line: no panic.
    for b in 0..=255u8 {
        let _ = parse_line(&[b]);
    }
    let good = b"t19081122334455667788";
    for k in 0..good.len() {
        let _ = parse_line(&good[..k]);
    }
}

#[test]
fn reader_splits_lines_and_drops_long_ones() {
    let mut r = LineReader::new();
    let mut lines = Vec::new();
    let mut dropped = 0;
    let mut input = Vec::new();
    input.extend_from_slice(b"t1230\r\n");
    input.extend(std::iter::repeat_n(b'A', MAX_LINE + 5));
    input.extend_from_slice(b"\rV\r");
    for b in input {
        match r.push(b) {
            Push::Line => lines.push(r.line().to_vec()),
            Push::Dropped => dropped += 1,
            Push::Pending => {}
        }
    }
    assert_eq!(lines, vec![b"t1230".to_vec(), b"V".to_vec()]);
    assert_eq!(dropped, 1);
    // A reset (overrun) drops the partial line up to the next CR.
    r.push(b't');
    r.reset();
    assert_eq!(r.push(b'\r'), Push::Dropped);
}
