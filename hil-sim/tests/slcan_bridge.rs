//! `hil-sim slcan-bridge` against a stand-in device: a TCP server playing QEMU's serial socket.
//! The bridge forwards bus frames only after the device has answered its version request (the
//! start-up handshake); bus frames reach the device as SLCAN lines stamped with their bus time;
//! the device's frame lines reach the bus; its other answers (lines, BEL, garbage) do not.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use dex_hil_sim::bus::{Bus, BusClock, BusConfig};
use dex_hil_sim::client::{BusClient, ClientError, Received};
use dex_hil_sim::slcan_bridge::{
    Bridge, BridgeConfig, BridgeError, BridgeStats, PROBE_INTERVAL, run_bridge, stamp_ms,
};
use dex_runtime::can::CanFrame;

fn config(bus: &Bus, serial: std::net::SocketAddr) -> BridgeConfig {
    BridgeConfig {
        bus: bus.addr(),
        serial,
        stamp: true,
        ready_timeout: Duration::from_secs(5),
    }
}

/// A virtual-clock bus, a stand-in device (the TCP server QEMU's serial socket would be) and the
/// bridge between them on its own thread, with the device's end of the serial line accepted.
struct Rig {
    bus: Bus,
    stop: Arc<AtomicBool>,
    bridge: std::thread::JoinHandle<Result<BridgeStats, BridgeError>>,
    dev: TcpStream,
}

impl Rig {
    /// `before_bridge` runs on the bus before the bridge joins it (e.g. to set its time).
    fn start(before_bridge: impl FnOnce(&Bus)) -> Rig {
        let bus = Bus::start(BusConfig {
            clock: BusClock::Virtual,
            ..BusConfig::default()
        })
        .unwrap();
        before_bridge(&bus);
        let device = TcpListener::bind("127.0.0.1:0").unwrap();
        let serial = device.local_addr().unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let bridge = {
            let stop = Arc::clone(&stop);
            let cfg = config(&bus, serial);
            std::thread::spawn(move || run_bridge(cfg, &stop))
        };
        let (dev, _) = device.accept().unwrap();
        Rig {
            bus,
            stop,
            bridge,
            dev,
        }
    }

    /// Stops the bridge and the bus; the bridge's counts.
    fn finish(self) -> BridgeStats {
        self.stop.store(true, Ordering::SeqCst);
        let stats = self.bridge.join().unwrap().unwrap();
        self.bus.shutdown();
        stats
    }
}

/// The device side: answers every version request (`V`) with `V0101` and returns the first
/// frame line it reads, with the number of requests it answered.
fn answer_until_frame(
    dev_in: &mut BufReader<TcpStream>,
    dev_out: &mut TcpStream,
) -> std::io::Result<(Vec<u8>, u64)> {
    let mut answered = 0;
    loop {
        let mut line = Vec::new();
        dev_in.read_until(b'\r', &mut line)?;
        assert!(!line.is_empty(), "the bridge closed the serial line");
        match line.as_slice() {
            b"\r" => {}
            b"V\r" => {
                dev_out.write_all(b"V0101\r")?;
                answered += 1;
            }
            _ => return Ok((line, answered)),
        }
    }
}

/// The next frame another client sees on the bus.
fn next_frame(other: &mut BusClient) -> Result<Option<CanFrame>, ClientError> {
    loop {
        match other.receive_timeout(Duration::from_secs(5))? {
            Some(Received::Frame(f, _)) => return Ok(Some(f)),
            Some(_) => continue,
            None => return Ok(None),
        }
    }
}

#[test]
fn stamps_follow_bus_time_and_wrap() {
    assert_eq!(stamp_ms(0), 0);
    assert_eq!(stamp_ms(50_000), 50);
    assert_eq!(stamp_ms(60_000_000 + 1_250_000), 1_250);
}

#[test]
fn bridge_carries_frames_both_ways() {
    let rig = Rig::start(|bus| bus.set_time(61_234_000)); // 61.234 s: stamps wrap at 60 s
    rig.dev
        .set_read_timeout(Some(Duration::from_secs(5)))
        .unwrap();
    let mut dev_in = BufReader::new(rig.dev.try_clone().unwrap());
    let mut dev_out = rig.dev.try_clone().unwrap();
    let mut other = BusClient::connect(rig.bus.addr(), "vcan0").unwrap();

    // Bus -> device, with the bus time as the stamp (61,234 ms modulo 60,000 = 0x04D2).
    other.queue(&CanFrame::standard(0x190, &[1, 2, 3]).unwrap());
    other.flush().unwrap();
    let (line, answered) = answer_until_frame(&mut dev_in, &mut dev_out).unwrap();
    assert_eq!(line, b"t190301020304D2\r");

    // Device -> bus: garbage, an answer and a BEL are not frames; the frame line is.
    dev_out.write_all(b"V0101\r\x07\rjunk\rt710105\r").unwrap();
    let Some(got) = next_frame(&mut other).unwrap() else {
        rig.stop.store(true, Ordering::SeqCst);
        panic!("no frame from the device: {:?}", rig.bridge.join());
    };
    assert_eq!(got, CanFrame::standard(0x710, &[0x05]).unwrap());

    let stats = rig.finish();
    assert!(stats.probes >= 1);
    assert_eq!(stats.to_device, 1);
    assert_eq!(stats.to_bus, 1);
    // The version answers to the handshake, then V0101, the BEL and the garbage line.
    assert_eq!(stats.other_lines, answered + 3);
}

/// A device whose receiver is not enabled yet at first (a UART before its firmware set it up:
/// QEMU's STM32 USART model drops those bytes) loses the first version requests, and would lose
/// any frame written then. The bridge repeats the request until the device answers and only then
/// writes the bus frame that was sent meanwhile: it arrives whole.
#[test]
fn frames_wait_for_a_device_that_is_not_listening_yet() {
    let rig = Rig::start(|_| {});
    let mut dev = rig.dev.try_clone().unwrap();
    // The bridge joins the bus before it connects the serial line: this frame is its to carry.
    let mut other = BusClient::connect(rig.bus.addr(), "vcan0").unwrap();
    other.queue(&CanFrame::standard(0x610, &[0xC6, 0x50, 0x1F, 0x01]).unwrap());
    other.flush().unwrap();

    // Deaf for a while: everything received is dropped, as by a disabled receiver.
    let deaf = Duration::from_millis(4 * PROBE_INTERVAL.as_millis() as u64);
    let start = Instant::now();
    let mut dropped = Vec::new();
    while start.elapsed() < deaf {
        dev.set_read_timeout(Some(Duration::from_millis(10)))
            .unwrap();
        let mut buf = [0u8; 256];
        if let Ok(n) = dev.read(&mut buf) {
            dropped.extend_from_slice(&buf[..n]);
        }
    }
    assert!(
        dropped.windows(2).any(|w| w == b"V\r"),
        "version requests while deaf: {dropped:?}"
    );
    assert!(
        !dropped.contains(&b't'),
        "a frame was written before the device answered: {dropped:?}"
    );

    // Listening now: the requests go on until one is answered, then the frame comes whole.
    dev.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let mut dev_in = BufReader::new(dev.try_clone().unwrap());
    let (line, answered) = answer_until_frame(&mut dev_in, &mut dev).unwrap();
    assert_eq!(line, b"t6104C6501F010000\r");
    assert!(answered >= 1);

    // A BEL is a whole answer: the frame line right behind it (no `\r` between) reaches the bus.
    dev.write_all(b"\x07t710100\r").unwrap();
    assert_eq!(
        next_frame(&mut other).unwrap(),
        Some(CanFrame::standard(0x710, &[0x00]).unwrap())
    );

    let stats = rig.finish();
    assert!(stats.probes >= 4, "{stats:?}");
    assert_eq!(stats.to_device, 1);
    assert_eq!(stats.to_bus, 1);
}

/// A device that never answers the version request: the bridge gives up after its timeout.
#[test]
fn a_silent_device_is_not_ready() {
    let bus = Bus::start(BusConfig::default()).unwrap();
    let device = TcpListener::bind("127.0.0.1:0").unwrap();
    let serial = device.local_addr().unwrap();
    let cfg = BridgeConfig {
        ready_timeout: Duration::from_millis(300),
        ..config(&bus, serial)
    };
    let bridge = std::thread::spawn(move || Bridge::connect(cfg).map(|b| b.stats()));
    let (_dev, _) = device.accept().unwrap();
    match bridge.join().unwrap() {
        Err(BridgeError::NotReady { probes, waited }) => {
            assert!(probes >= 2, "{probes} requests");
            assert!(waited >= Duration::from_millis(300), "{waited:?}");
        }
        other => panic!("want NotReady, got {other:?}"),
    }
    bus.shutdown();
}
