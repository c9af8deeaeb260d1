//! `hil-sim slcan-bridge` against a stand-in device: a TCP server playing QEMU's serial socket.
//! Bus frames reach the device as SLCAN lines stamped with their bus time; the device's frame
//! lines reach the bus; its other lines (answers, BEL, garbage) do not.

use std::io::{BufRead, BufReader, Write};
use std::net::TcpListener;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use dex_hil_sim::bus::{Bus, BusClock, BusConfig};
use dex_hil_sim::client::{BusClient, Received};
use dex_hil_sim::slcan_bridge::{BridgeConfig, run_bridge, stamp_ms};
use dex_runtime::can::CanFrame;

#[test]
fn stamps_follow_bus_time_and_wrap() {
    assert_eq!(stamp_ms(0), 0);
    assert_eq!(stamp_ms(50_000), 50);
    assert_eq!(stamp_ms(60_000_000 + 1_250_000), 1_250);
}

#[test]
fn bridge_carries_frames_both_ways() {
    let bus = Bus::start(BusConfig {
        clock: BusClock::Virtual,
        ..BusConfig::default()
    })
    .unwrap();
    bus.set_time(61_234_000); // 61.234 s: stamps wrap at 60 s
    let device = TcpListener::bind("127.0.0.1:0").unwrap();
    let serial = device.local_addr().unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let bridge = {
        let stop = Arc::clone(&stop);
        let cfg = BridgeConfig {
            bus: bus.addr(),
            serial,
            stamp: true,
        };
        std::thread::spawn(move || run_bridge(cfg, &stop))
    };
    let (dev, _) = device.accept().unwrap();
    dev.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let mut dev_in = BufReader::new(dev.try_clone().unwrap());
    let mut dev_out = dev;
    let mut other = BusClient::connect(bus.addr(), "vcan0").unwrap();
    std::thread::sleep(Duration::from_millis(100));

    // Bus -> device, with the bus time as the stamp (61,234 ms modulo 60,000 = 0x04D2).
    other.queue(&CanFrame::standard(0x190, &[1, 2, 3]).unwrap());
    other.flush().unwrap();
    let mut line = Vec::new();
    dev_in.read_until(b'\r', &mut line).unwrap();
    assert_eq!(line, b"t190301020304D2\r");

    // Device -> bus: garbage, an answer and a BEL are not frames; the frame line is.
    dev_out.write_all(b"V0101\r\x07\rjunk\rt710105\r").unwrap();
    let got = loop {
        match other.receive_timeout(Duration::from_secs(5)).unwrap() {
            Some(Received::Frame(f, _)) => break f,
            Some(_) => continue,
            None => {
                stop.store(true, Ordering::SeqCst);
                panic!("no frame from the device: {:?}", bridge.join());
            }
        }
    };
    assert_eq!(got, CanFrame::standard(0x710, &[0x05]).unwrap());

    stop.store(true, Ordering::SeqCst);
    let stats = bridge.join().unwrap().unwrap();
    assert_eq!(stats.to_device, 1);
    assert_eq!(stats.to_bus, 1);
    assert_eq!(stats.other_lines, 3);
    bus.shutdown();
}
