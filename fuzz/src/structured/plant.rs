//! The plant's sending side: observation frames sealed as the plant seals them (CRC, alive counter,
//! sample nibble), with the flaws an input asks for.

use dex_runtime::can::CanFrame;
use dex_runtime::can::e2e::{COUNTER_MAX, next_counter, protect};
use dex_runtime::can::messages::{OBS_FRAMES, SIGNALS_PER_FRAME, rpdo_cob_id};
use dex_runtime::interface::OBS_DIM;

use super::input::{Flaw, SampleSel, Values, value_raw};

/// The plant's sending side: one alive counter per observation frame and the current sample.
#[derive(Debug, Default)]
pub(crate) struct Plant {
    /// The controller's node id (its RPDO identifiers).
    pub(crate) node: u8,
    next: [u8; OBS_FRAMES],
    last: [Option<u8>; OBS_FRAMES],
    sample: u8,
}

impl Plant {
    pub(crate) fn select(&mut self, sel: SampleSel) -> u8 {
        self.sample = match sel {
            SampleSel::Same => self.sample,
            SampleSel::Next => (self.sample + 1) & 0x0F,
            SampleSel::Nibble(n) => n & 0x0F,
        };
        self.sample
    }

    /// The frames observation frame `k` turns into on the bus (none if lost, two if duplicated).
    pub(crate) fn frames(
        &mut self,
        k: usize,
        sample: u8,
        values: Values,
        flaw: Option<Flaw>,
    ) -> Vec<CanFrame> {
        let id = rpdo_cob_id(self.node, k);
        let mut counter = self.next[k];
        match flaw {
            Some(Flaw::RepeatCounter) => counter = self.last[k].unwrap_or(counter),
            Some(Flaw::SkipCounters(n)) => {
                for _ in 0..=(n % COUNTER_MAX) {
                    counter = next_counter(counter);
                }
            }
            _ => {}
        }
        let nibble = match flaw {
            Some(Flaw::OtherSample(n)) => n & 0x0F,
            _ => sample,
        };
        let mut data = [0u8; 8];
        data[1] = nibble << 4;
        for s in 0..SIGNALS_PER_FRAME {
            let index = k * SIGNALS_PER_FRAME + s;
            if index < OBS_DIM {
                let raw = value_raw(values, index);
                data[2 + 2 * s..4 + 2 * s].copy_from_slice(&raw.to_le_bytes());
            }
        }
        let sent = if matches!(flaw, Some(Flaw::Counter15)) {
            15
        } else {
            counter
        };
        protect(id, sent, &mut data);
        if sent <= COUNTER_MAX {
            self.last[k] = Some(sent);
            self.next[k] = next_counter(sent);
        }
        let mut len = 8;
        match flaw {
            Some(Flaw::BadCrc(x)) => data[0] ^= x.max(1),
            Some(Flaw::Short(l)) => len = usize::from(l % 8),
            Some(Flaw::Lost) => return Vec::new(),
            _ => {}
        }
        let frame = CanFrame::standard(id, &data[..len]).expect("observation frame");
        if matches!(flaw, Some(Flaw::Duplicate)) {
            vec![frame, frame]
        } else {
            vec![frame]
        }
    }
}
