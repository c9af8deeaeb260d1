//! The SLCAN bridge: joins a serial line that speaks SLCAN (Lawicel ASCII; the firmware node
//! under QEMU, whose `-serial` is a TCP socket) to the virtual bus.
//!
//! Bus -> serial: every frame as a `t`/`T` line; with [`BridgeConfig::stamp`] (lockstep runs) the
//! line carries the frame's bus time as a Lawicel time stamp (milliseconds modulo 60,000), which
//! the firmware takes as its clock. Serial -> bus: every frame line the device writes; its other
//! lines (answers to commands, BEL) are counted and dropped.
//!
//! One thread, polling both sides: the bus with a short timeout, the serial socket non-blocking.

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use dex_runtime::can::CanFrame;
use dex_slcan::{Command, LineReader, Push, encode_frame, parse_line};
use embedded_can::Frame;

use crate::client::{BusClient, ClientError, Received};

/// Settings of the bridge.
#[derive(Debug, Clone, Copy)]
pub struct BridgeConfig {
    /// The bus.
    pub bus: SocketAddr,
    /// The serial line's TCP socket (QEMU `-serial tcp:HOST:PORT,server=on`).
    pub serial: SocketAddr,
    /// Stamp frames to the device with their bus time (lockstep).
    pub stamp: bool,
}

/// What the bridge carried.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct BridgeStats {
    /// Frames from the bus to the device.
    pub to_device: u64,
    /// Frames from the device to the bus.
    pub to_bus: u64,
    /// Device lines that were not frames (answers, BEL, garbage).
    pub other_lines: u64,
    /// Device lines dropped for being too long.
    pub long_lines: u64,
}

/// Errors of the bridge.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// The bus side failed.
    #[error("bus: {0}")]
    Bus(#[from] ClientError),
    /// The serial side failed.
    #[error("serial line: {0}")]
    Serial(#[from] std::io::Error),
}

/// The bus time of a frame as a Lawicel time stamp in milliseconds (the wrap is the encoder's).
pub fn stamp_ms(bus_us: u64) -> u32 {
    (bus_us / 1_000 % u64::from(dex_slcan::TIMESTAMP_WRAP_MS)) as u32
}

/// Runs the bridge until `stop` is set or either side closes (`Ok` then).
pub fn run_bridge(cfg: BridgeConfig, stop: &AtomicBool) -> Result<BridgeStats, BridgeError> {
    let mut bus = BusClient::connect(cfg.bus, "vcan0")?;
    let mut serial = TcpStream::connect_timeout(&cfg.serial, Duration::from_secs(5))?;
    serial.set_nodelay(true)?;
    serial.set_nonblocking(true)?;
    let mut stats = BridgeStats::default();
    let mut reader = LineReader::new();
    let mut buf = [0u8; 4096];
    let mut out = Vec::with_capacity(4096);
    while !stop.load(Ordering::Relaxed) {
        // Bus -> device: everything waiting, then one write.
        let mut wait = Duration::from_micros(200);
        loop {
            match bus.receive_timeout(wait) {
                Ok(Some(Received::Frame(f, ts))) => {
                    let line = encode_frame(f.id(), f.data(), cfg.stamp.then(|| stamp_ms(ts)));
                    out.extend_from_slice(line.as_bytes());
                    stats.to_device += 1;
                }
                Ok(Some(Received::Error(..))) => {}
                Ok(None) => break,
                Err(ClientError::Closed) => return Ok(stats),
                Err(e) => return Err(e.into()),
            }
            wait = Duration::ZERO;
        }
        if !out.is_empty() {
            serial.set_nonblocking(false)?;
            let written = serial.write_all(&out);
            serial.set_nonblocking(true)?;
            match written {
                Ok(()) => out.clear(),
                Err(e) if is_closed(&e) => return Ok(stats),
                Err(e) => return Err(e.into()),
            }
        }
        // Device -> bus.
        match serial.read(&mut buf) {
            Ok(0) => return Ok(stats),
            Ok(n) => {
                for &b in &buf[..n] {
                    match reader.push(b) {
                        Push::Pending => {}
                        Push::Dropped => stats.long_lines += 1,
                        Push::Line => match parse_line(reader.line()) {
                            Ok(Command::Frame(f)) if !f.remote => {
                                if let Some(frame) = CanFrame::new(f.id, f.data()) {
                                    bus.queue(&frame);
                                    stats.to_bus += 1;
                                }
                            }
                            Ok(Command::Empty) => {}
                            _ => stats.other_lines += 1,
                        },
                    }
                }
                match bus.flush() {
                    Ok(()) => {}
                    Err(ClientError::Closed) => return Ok(stats),
                    Err(e) => return Err(e.into()),
                }
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock || e.kind() == ErrorKind::Interrupted => {}
            Err(e) if is_closed(&e) => return Ok(stats),
            Err(e) => return Err(e.into()),
        }
    }
    Ok(stats)
}

fn is_closed(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        ErrorKind::BrokenPipe | ErrorKind::ConnectionReset | ErrorKind::ConnectionAborted
    )
}
