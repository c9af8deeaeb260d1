//! The structured input: what `arbitrary` decodes the fuzzer's bytes into (the operations a plant, an
//! NMT master, a clock, a CAN driver and a flashing tool perform), and the observation values it
//! selects.

use arbitrary::Arbitrary;
use dex_policy::synth::SplitMix64;
use dex_runtime::can::messages::RAW_NOT_AVAILABLE;
use dex_runtime::interface::{OBS_DIM, quantity_of};

/// One fuzz input: the controller's configuration, its initial policy and the operations to play
/// (decoded with `arbitrary`; the order of the fields and variants below is the input format).
#[derive(Arbitrary, Debug)]
pub struct Input {
    pub(crate) watchdog_cycles: u8,
    pub(crate) heartbeat_cycles: u8,
    pub(crate) e2e_max_delta: u8,
    pub(crate) node_id: u8,
    /// Index into the loadable images, or none.
    pub(crate) initial_policy: Option<u8>,
    pub(crate) ops: Vec<Op>,
}

#[derive(Arbitrary, Debug)]
pub(crate) enum Op {
    /// All 15 frames of one sample, in order, without flaws.
    Sample {
        sample: SampleSel,
        values: Values,
    },
    /// Frames `first ..= first + count` of one sample (the rest of it may come in a later op).
    Frames {
        sample: SampleSel,
        first: u8,
        count: u8,
        values: Values,
        flaw: Option<(u8, Flaw)>,
        reverse: bool,
    },
    Nmt {
        command: NmtSel,
        node: NodeSel,
    },
    Clock {
        step: Step,
        poll: bool,
    },
    Poll,
    BusOff,
    BusRecovered,
    FlashInit {
        image: u8,
    },
    FlashData {
        segments: u16,
    },
    FlashCorrupt {
        offset: u16,
        xor: u8,
    },
    FlashEnd {
        crc: CrcSel,
        reseal: bool,
    },
    FlashActivate,
    FlashAbort,
    /// `load_policy` with a prepared file, loadable or not.
    Load {
        image: u8,
    },
    /// Any frame (observation ids included: a random CRC sometimes matches).
    Raw {
        id: u16,
        data: [u8; 8],
        len: u8,
    },
}

#[derive(Arbitrary, Debug, Clone, Copy)]
pub(crate) enum SampleSel {
    Same,
    Next,
    Nibble(u8),
}

#[derive(Arbitrary, Debug, Clone, Copy)]
pub(crate) enum Values {
    /// Every value within `spread / 255` of its plausible range.
    Nominal { seed: u16, spread: u8 },
    /// Nominal except value `index`.
    Special {
        seed: u16,
        spread: u8,
        index: u8,
        value: Special,
    },
}

#[derive(Arbitrary, Debug, Clone, Copy)]
pub(crate) enum Special {
    NotAvailable,
    SaturatedHigh,
    SaturatedLow,
    AtLimit,
    BeyondLimit,
    Raw(i16),
}

#[derive(Arbitrary, Debug, Clone, Copy)]
pub(crate) enum Flaw {
    BadCrc(u8),
    RepeatCounter,
    SkipCounters(u8),
    Counter15,
    Short(u8),
    OtherSample(u8),
    Lost,
    Duplicate,
}

#[derive(Arbitrary, Debug, Clone, Copy)]
pub(crate) enum NmtSel {
    Start,
    Stop,
    PreOperational,
    ResetNode,
    ResetCommunication,
    Unknown(u8),
}

#[derive(Arbitrary, Debug, Clone, Copy)]
pub(crate) enum NodeSel {
    All,
    Own,
    Other(u8),
}

#[derive(Arbitrary, Debug, Clone, Copy)]
pub(crate) enum Step {
    Period,
    Periods(u8),
    Micros(u16),
    Long(u32),
}

#[derive(Arbitrary, Debug, Clone, Copy)]
pub(crate) enum CrcSel {
    /// CRC-32 of the bytes sent.
    Sent,
    /// CRC-32 of the file the transfer started with.
    Original,
    /// Neither.
    Wrong,
}

/// Raw signal of observation value `index`.
pub(crate) fn value_raw(values: Values, index: usize) -> i16 {
    let (seed, spread) = match values {
        Values::Nominal { seed, spread } | Values::Special { seed, spread, .. } => (seed, spread),
    };
    let q = quantity_of(index).expect("index within the observation");
    let limit = f64::from(q.limit()) / f64::from(q.lsb());
    if let Values::Special {
        index: special,
        value,
        ..
    } = values
        && usize::from(special) % OBS_DIM == index
    {
        return match value {
            Special::NotAvailable => RAW_NOT_AVAILABLE,
            Special::SaturatedHigh => i16::MAX,
            Special::SaturatedLow => -i16::MAX,
            Special::AtLimit => limit.floor() as i16,
            Special::BeyondLimit => -(limit.ceil() as i16 + 1),
            Special::Raw(r) => r,
        };
    }
    let mut rng = SplitMix64::new((u64::from(seed) << 8) | index as u64);
    let unit = f64::from(rng.uniform(-1.0, 1.0));
    (unit * limit * f64::from(spread) / 255.0) as i16
}
