//! The SLCAN bridge: joins a serial line that speaks SLCAN (Lawicel ASCII; the firmware node
//! under QEMU, whose `-serial` is a TCP socket) to the virtual bus.
//!
//! Bus -> serial: every frame as a `t`/`T` line; with [`BridgeConfig::stamp`] (lockstep runs) the
//! line carries the frame's bus time as a Lawicel time stamp (milliseconds modulo 60,000), which
//! the firmware takes as its clock. Serial -> bus: every frame line the device writes; its other
//! answers (`\r`-ended lines, and BEL, which SLCAN sends without a `\r`) are counted and dropped.
//!
//! Start-up handshake ([`Bridge::connect`]): a UART receives nothing before its firmware has
//! enabled it, and the line tells the sender nothing about it (QEMU's STM32 USART model drops
//! every byte that arrives before the firmware sets its enable bits, as the hardware would lose
//! them). A frame written in that window is lost, whole or in part, and nothing retransmits it.
//! So the bridge forwards no bus frame to the device before the device has answered an SLCAN
//! version request (`V`): it sends the request every [`PROBE_INTERVAL`] until the answer comes,
//! within [`BridgeConfig::ready_timeout`]. Repeating the request is what makes the handshake
//! work on a lossy start: a request lost to the disabled receiver is never answered. Any suffix
//! of the request (`\rV\r`) is harmless to the device: `V\r` is the request, `\r` an empty line.
//! Bus frames sent meanwhile wait in the bus connection and reach the device after the
//! handshake; the device's frames (its boot-up message) reach the bus throughout.
//!
//! One thread, polling both sides: the bus with a short timeout, the serial socket non-blocking.

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use dex_runtime::can::CanFrame;
use dex_slcan::{Command, LineReader, Push, encode_frame, parse_line};
use embedded_can::Frame;

use crate::client::{BusClient, ClientError, Received};

/// How often the start-up handshake repeats its version request until the device answers.
pub const PROBE_INTERVAL: Duration = Duration::from_millis(50);

/// The start-up version request: a `\r` first ends whatever partial line the device holds.
const PROBE: &[u8] = b"\rV\r";

/// Settings of the bridge.
#[derive(Debug, Clone, Copy)]
pub struct BridgeConfig {
    /// The bus.
    pub bus: SocketAddr,
    /// The serial line's TCP socket (QEMU `-serial tcp:HOST:PORT,server=on`).
    pub serial: SocketAddr,
    /// Stamp frames to the device with their bus time (lockstep).
    pub stamp: bool,
    /// How long the start-up handshake waits for the device's answer to the version request.
    pub ready_timeout: Duration,
}

/// What the bridge carried.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct BridgeStats {
    /// Version requests sent to the device by the start-up handshake.
    pub probes: u64,
    /// Frames from the bus to the device.
    pub to_device: u64,
    /// Frames from the device to the bus.
    pub to_bus: u64,
    /// Device answers that were not frames (version, BEL, other answers, garbage).
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
    /// The device did not answer the start-up version request in time.
    #[error("the device did not answer {probes} version requests (V) within {waited:?}")]
    NotReady {
        /// Requests sent.
        probes: u64,
        /// How long the handshake waited.
        waited: Duration,
    },
    /// The device closed the serial line before it answered the start-up version request.
    #[error("the device closed the serial line before answering the version request")]
    DeviceClosed,
}

/// The bus time of a frame as a Lawicel time stamp in milliseconds (the wrap is the encoder's).
pub fn stamp_ms(bus_us: u64) -> u32 {
    (bus_us / 1_000 % u64::from(dex_slcan::TIMESTAMP_WRAP_MS)) as u32
}

/// What one read of the serial line gave.
enum DeviceRead {
    /// Bytes came in (and were handled).
    Bytes,
    /// Nothing waiting.
    Idle,
    /// The device closed the line.
    Closed,
}

/// A bridge whose device has answered the start-up handshake ([`Bridge::connect`]); [`Bridge::run`]
/// carries frames both ways.
#[derive(Debug)]
pub struct Bridge {
    cfg: BridgeConfig,
    bus: BusClient,
    serial: TcpStream,
    reader: LineReader,
    stats: BridgeStats,
    version: Option<String>,
    out: Vec<u8>,
}

impl Bridge {
    /// Connects to the bus, then to the serial line, and runs the start-up handshake: the
    /// version request every [`PROBE_INTERVAL`] until the device answers (frames it sends
    /// meanwhile go to the bus; bus frames wait). Fails with [`BridgeError::NotReady`] after
    /// [`BridgeConfig::ready_timeout`] without an answer.
    pub fn connect(cfg: BridgeConfig) -> Result<Bridge, BridgeError> {
        let bus = BusClient::connect(cfg.bus, "vcan0")?;
        let serial = TcpStream::connect_timeout(&cfg.serial, Duration::from_secs(5))?;
        serial.set_nodelay(true)?;
        serial.set_nonblocking(true)?;
        let mut bridge = Bridge {
            cfg,
            bus,
            serial,
            reader: LineReader::new(),
            stats: BridgeStats::default(),
            version: None,
            out: Vec::with_capacity(4096),
        };
        let start = Instant::now();
        let mut next_probe = start;
        while bridge.version.is_none() {
            let now = Instant::now();
            if now >= next_probe {
                let waited = now.duration_since(start);
                if waited >= cfg.ready_timeout {
                    return Err(BridgeError::NotReady {
                        probes: bridge.stats.probes,
                        waited,
                    });
                }
                if !write_serial(&mut bridge.serial, PROBE)? {
                    return Err(BridgeError::DeviceClosed);
                }
                bridge.stats.probes += 1;
                next_probe = now + PROBE_INTERVAL;
            }
            match bridge.read_device()? {
                DeviceRead::Bytes => {}
                DeviceRead::Idle => std::thread::sleep(Duration::from_millis(1)),
                DeviceRead::Closed => return Err(BridgeError::DeviceClosed),
            }
        }
        Ok(bridge)
    }

    /// The device's answer to the version request (e.g. `V0101`).
    pub fn device_version(&self) -> &str {
        self.version.as_deref().unwrap_or("")
    }

    /// What the bridge carried so far.
    pub fn stats(&self) -> BridgeStats {
        self.stats
    }

    /// Carries frames both ways until `stop` is set or either side closes (`Ok` then).
    pub fn run(mut self, stop: &AtomicBool) -> Result<BridgeStats, BridgeError> {
        while !stop.load(Ordering::Relaxed) {
            // Bus -> device: everything waiting, then one write.
            let mut wait = Duration::from_micros(200);
            loop {
                match self.bus.receive_timeout(wait) {
                    Ok(Some(Received::Frame(f, ts))) => {
                        let stamp = self.cfg.stamp.then(|| stamp_ms(ts));
                        let line = encode_frame(f.id(), f.data(), stamp);
                        self.out.extend_from_slice(line.as_bytes());
                        self.stats.to_device += 1;
                    }
                    // SLCAN (and the firmware's bxCAN) carries classic frames only.
                    Ok(Some(Received::Error(..) | Received::Fd(..))) => {}
                    Ok(None) => break,
                    Err(ClientError::Closed) => return Ok(self.stats),
                    Err(e) => return Err(e.into()),
                }
                wait = Duration::ZERO;
            }
            if !self.out.is_empty() {
                if !write_serial(&mut self.serial, &self.out)? {
                    return Ok(self.stats);
                }
                self.out.clear();
            }
            // Device -> bus.
            match self.read_device() {
                Ok(DeviceRead::Bytes | DeviceRead::Idle) => {}
                Ok(DeviceRead::Closed) | Err(BridgeError::Bus(ClientError::Closed)) => {
                    return Ok(self.stats);
                }
                Err(e) => return Err(e),
            }
        }
        Ok(self.stats)
    }

    /// One non-blocking read of the serial line: frame lines to the bus, the version answer
    /// noted, other answers counted.
    fn read_device(&mut self) -> Result<DeviceRead, BridgeError> {
        let mut buf = [0u8; 4096];
        let n = match self.serial.read(&mut buf) {
            Ok(0) => return Ok(DeviceRead::Closed),
            Ok(n) => n,
            Err(e) if e.kind() == ErrorKind::WouldBlock || e.kind() == ErrorKind::Interrupted => {
                return Ok(DeviceRead::Idle);
            }
            Err(e) if is_closed(&e) => return Ok(DeviceRead::Closed),
            Err(e) => return Err(e.into()),
        };
        for &b in &buf[..n] {
            let push = if b == dex_slcan::BELL {
                // An error answer, complete without a `\r`: it also ends any partial line, so
                // that the device's next line is read whole.
                self.stats.other_lines += 1;
                self.reader.push(dex_slcan::CR)
            } else {
                self.reader.push(b)
            };
            match push {
                Push::Pending => {}
                Push::Dropped => self.stats.long_lines += 1,
                Push::Line => self.device_line(),
            }
        }
        self.bus.flush()?;
        Ok(DeviceRead::Bytes)
    }

    /// The line the reader just completed.
    fn device_line(&mut self) {
        let line = self.reader.line();
        if line.first() == Some(&b'V') {
            self.stats.other_lines += 1;
            if self.version.is_none() {
                self.version = Some(String::from_utf8_lossy(line).into_owned());
            }
            return;
        }
        match parse_line(line) {
            Ok(Command::Frame(f)) if !f.remote => {
                if let Some(frame) = CanFrame::new(f.id, f.data()) {
                    self.bus.queue(&frame);
                    self.stats.to_bus += 1;
                }
            }
            Ok(Command::Empty) => {}
            _ => self.stats.other_lines += 1,
        }
    }
}

/// [`Bridge::connect`], then [`Bridge::run`] until `stop` is set or either side closes.
pub fn run_bridge(cfg: BridgeConfig, stop: &AtomicBool) -> Result<BridgeStats, BridgeError> {
    Bridge::connect(cfg)?.run(stop)
}

/// Writes `bytes` to the device whole (blocking); `false` when the device closed the line.
fn write_serial(serial: &mut TcpStream, bytes: &[u8]) -> Result<bool, BridgeError> {
    serial.set_nonblocking(false)?;
    let written = serial.write_all(bytes);
    serial.set_nonblocking(true)?;
    match written {
        Ok(()) => Ok(true),
        Err(e) if is_closed(&e) => Ok(false),
        Err(e) => Err(e.into()),
    }
}

fn is_closed(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        ErrorKind::BrokenPipe | ErrorKind::ConnectionReset | ErrorKind::ConnectionAborted
    )
}
