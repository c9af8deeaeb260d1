//! The CAN FD layout of the observation and the action: the same values, raw encoding (i16 LE,
//! [`crate::can::messages::to_raw`]) and E2E header (CRC-8 in byte 0, alive counter and sample
//! nibble in byte 1, keyed by the identifier: [`crate::can::e2e`]) as the classic frames, in
//! fewer, longer frames.
//!
//! | frame | identifier | bytes | content |
//! |---|---|---:|---|
//! | observation k = 0, 1 | RPDO k: `0x200 + 0x100*k + node` | 48 | CRC, counter + sample, 22 values (44 bytes), 2 bytes 0 |
//! | action | TPDO 0: `0x180 + node` | 20 | CRC, counter + sample, 9 values |
//!
//! The identifiers are those of the first RPDOs and TPDO of the classic layout (CiA 301's
//! pre-defined connection set, which CANopen FD, CiA 1301, keeps: a PDO there is up to 64 bytes
//! on the same COB-ID). The two layouts never share a bus for one node (a controller is
//! configured for one), the actions keep their priority over the observations, and the status,
//! policy-information, emergency, heartbeat, NMT and SDO frames stay classic frames on their
//! usual identifiers. 88 bytes of values and 2 of header do not fit one 64-byte frame, so the
//! observation takes two: values 0..22 and 22..44, each frame rounded up to the FD length 48.

use crate::can::e2e::E2eSender;
use crate::can::fd_frame::{FD_MAX_LEN, FdFrame, fd_length};
use crate::can::messages::{
    ACTION_QUANTITY, from_raw, observation_frame_index, rpdo_cob_id, to_raw, tpdo_cob_id,
};
use crate::interface::{ACT_DIM, OBS_DIM, Quantity, quantity_of};

/// Bytes of the E2E header before the values.
const HEADER: usize = 2;
/// Observation frames per cycle in the FD layout (RPDOs 0..FD_OBS_FRAMES).
pub const FD_OBS_FRAMES: usize = (2 * OBS_DIM).div_ceil(FD_MAX_LEN - HEADER);
/// Observation values per FD frame.
pub const FD_VALUES_PER_OBS_FRAME: usize = OBS_DIM.div_ceil(FD_OBS_FRAMES);
/// Bytes of an FD observation frame (an FD length).
pub const FD_OBS_LEN: usize = match fd_length(HEADER + 2 * FD_VALUES_PER_OBS_FRAME) {
    Some(n) => n,
    None => FD_MAX_LEN,
};
/// Action frames per cycle in the FD layout (TPDO 0).
pub const FD_ACTION_FRAMES: usize = (2 * ACT_DIM).div_ceil(FD_MAX_LEN - HEADER);
/// Bytes of the FD action frame (an FD length).
pub const FD_ACTION_LEN: usize = match fd_length(HEADER + 2 * ACT_DIM) {
    Some(n) => n,
    None => FD_MAX_LEN,
};

const _: () = assert!(FD_OBS_FRAMES == 2 && FD_OBS_LEN == 48);
const _: () = assert!(FD_ACTION_FRAMES == 1 && FD_ACTION_LEN == 20);

/// Index of the FD observation frame (RPDO) of `node` with CAN id `id`, if it is one.
pub fn fd_observation_frame_index(node: u8, id: u16) -> Option<usize> {
    observation_frame_index(node, id).filter(|&k| k < FD_OBS_FRAMES)
}

/// Index of the FD action frame (TPDO) of `node` with CAN id `id`, if it is one.
pub fn fd_action_frame_index(node: u8, id: u16) -> Option<usize> {
    (id == tpdo_cob_id(node, 0)).then_some(0)
}

/// An FD frame of `LEN` bytes on `id`: the header (sample nibble, then the E2E counter and CRC
/// of `sender`), then `values` as raw i16 LE (`lsb_of` their position in `values`), zeros after.
fn fd_values_frame<const LEN: usize>(
    id: u16,
    sample: u8,
    sender: &mut E2eSender,
    values: &[f32],
    lsb_of: impl Fn(usize) -> f32,
) -> FdFrame {
    let mut data = [0u8; LEN];
    data[1] = (sample & 0x0F) << 4;
    for (chunk, (s, &v)) in data[HEADER..]
        .chunks_exact_mut(2)
        .zip(values.iter().enumerate())
    {
        chunk.copy_from_slice(&to_raw(v, lsb_of(s)).to_le_bytes());
    }
    sender.protect(id, &mut data);
    FdFrame::from_parts(id, &data)
}

/// Plant side: encodes one observation into the [`FD_OBS_FRAMES`] FD observation frames of
/// controller `node`, tagged with `sample` (its low 4 bits): frame `k` carries values
/// `22k .. 22k + 22`.
pub fn encode_observation_fd(
    node: u8,
    obs: &[f32; OBS_DIM],
    sample: u8,
    senders: &mut [E2eSender; FD_OBS_FRAMES],
) -> [FdFrame; FD_OBS_FRAMES] {
    core::array::from_fn(|k| {
        let first = (k * FD_VALUES_PER_OBS_FRAME).min(OBS_DIM);
        let end = (first + FD_VALUES_PER_OBS_FRAME).min(OBS_DIM);
        fd_values_frame::<FD_OBS_LEN>(
            rpdo_cob_id(node, k),
            sample,
            &mut senders[k],
            &obs[first..end],
            |s| quantity_of(first + s).map_or(1.0, Quantity::lsb),
        )
    })
}

/// Controller side: encodes one action into the FD action frame (TPDO 0) of controller `node`,
/// tagged with `sample`.
pub fn encode_action_fd(
    node: u8,
    action: &[f32; ACT_DIM],
    sample: u8,
    sender: &mut E2eSender,
) -> FdFrame {
    fd_values_frame::<FD_ACTION_LEN>(tpdo_cob_id(node, 0), sample, sender, action, |_| {
        ACTION_QUANTITY.lsb()
    })
}

/// Raw value `s` after the header of a signal frame (classic or FD), if the frame has it.
pub fn raw_value(data: &[u8], s: usize) -> Option<i16> {
    let at = HEADER + 2 * s;
    Some(i16::from_le_bytes([*data.get(at)?, *data.get(at + 1)?]))
}

/// Plant side: decodes the FD action frame into `action` (physical values); returns the sample
/// nibble, `None` for a frame of another length. The caller checks E2E first.
pub fn decode_action_fd(data: &[u8], action: &mut [f32; ACT_DIM]) -> Option<u8> {
    if data.len() != FD_ACTION_LEN {
        return None;
    }
    for (s, slot) in action.iter_mut().enumerate() {
        *slot = from_raw(raw_value(data, s)?, ACTION_QUANTITY.lsb());
    }
    Some(data[1] >> 4)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::can::e2e::{E2eReceiver, E2eStatus};
    use crate::can::messages::{
        ACTION_FRAMES, OBS_FRAMES, encode_action, encode_observation, split_signal_frame,
    };
    use embedded_can::Frame;

    #[test]
    fn the_fd_frames_carry_the_classic_frames_raw_values() {
        let obs: [f32; OBS_DIM] = core::array::from_fn(|i| (i as f32 * 0.37).sin() * 2.0);
        let classic = encode_observation(0x10, &obs, 5, &mut [E2eSender::default(); OBS_FRAMES]);
        let fd = encode_observation_fd(0x10, &obs, 5, &mut [E2eSender::default(); FD_OBS_FRAMES]);
        assert_eq!(
            fd.map(|f| (f.standard_id(), f.data().len())),
            [(Some(0x210), 48), (Some(0x310), 48)]
        );
        for i in 0..OBS_DIM {
            let (_, raw) = split_signal_frame(classic[i / 3].data()).expect("8 bytes");
            let k = i / FD_VALUES_PER_OBS_FRAME;
            assert_eq!(
                raw_value(fd[k].data(), i % FD_VALUES_PER_OBS_FRAME),
                Some(raw[i % 3]),
                "{i}"
            );
        }
        for f in &fd {
            assert_eq!(f.data()[1] >> 4, 5);
            assert_eq!(&f.data()[46..], &[0, 0]);
            let id = f.standard_id().unwrap_or(0);
            assert_eq!(E2eReceiver::new(1).check(id, f.data()), E2eStatus::Ok);
            assert_eq!(
                E2eReceiver::new(1).check(id + 1, f.data()),
                E2eStatus::Error
            );
        }
        let action: [f32; ACT_DIM] = core::array::from_fn(|j| j as f32 * 0.1 - 0.4);
        let fa = encode_action_fd(0x10, &action, 9, &mut E2eSender::default());
        assert_eq!((fa.standard_id(), fa.data().len()), (Some(0x190), 20));
        let mut back = [0.0; ACT_DIM];
        assert_eq!(decode_action_fd(fa.data(), &mut back), Some(9));
        let mut classic_back = [0.0; ACT_DIM];
        for (k, f) in encode_action(0x10, &action, 9, &mut [E2eSender::default(); ACTION_FRAMES])
            .iter()
            .enumerate()
        {
            crate::can::messages::decode_action_frame(k, f.data(), &mut classic_back);
        }
        assert_eq!(back.map(f32::to_bits), classic_back.map(f32::to_bits));
        assert_eq!(decode_action_fd(&fa.data()[..12], &mut back), None);
        assert_eq!(fd_observation_frame_index(0x10, 0x310), Some(1));
        assert_eq!(fd_observation_frame_index(0x10, 0x410), None);
        assert_eq!(fd_action_frame_index(0x10, 0x190), Some(0));
        assert_eq!(fd_action_frame_index(0x10, 0x290), None);
    }
}
