//! Fuzzes the controller with arbitrary frame sequences, clock steps and bus-off reports: it must
//! never panic and must stay in a defined state.
#![no_main]

use dex_runtime::can::CanFrame;
use dex_runtime::{Controller, ControllerConfig, MockClock};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let clock = MockClock::new(0);
    let mut controller = Controller::<64>::new(ControllerConfig::default());
    controller.poll(&clock);
    // Records of 11 bytes: clock step (1), id (2), length (1), data (up to 7 + 1 spare).
    for rec in data.chunks(11) {
        if rec.len() < 4 {
            break;
        }
        clock.advance(u64::from(rec[0]) * 1000);
        let id = u16::from_le_bytes([rec[1], rec[2]]) & 0x7FF;
        let len = usize::from(rec[3] % 9).min(rec.len() - 4);
        // The controller uses neither 0x7FE nor 0x7FF: they stand for the driver's bus-off and
        // recovery reports.
        match id {
            0x7FE => {
                let _ = controller.on_bus_off();
            }
            0x7FF => {
                let _ = controller.on_bus_recovered();
            }
            _ => {
                if let Some(frame) = CanFrame::standard(id, &rec[4..4 + len]) {
                    let _ = controller.on_frame(&frame, &clock);
                }
            }
        }
        let _ = controller.poll(&clock);
    }
});
