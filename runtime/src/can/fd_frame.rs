//! A CAN FD data frame (ISO 11898-1:2015): up to 64 data bytes in the lengths a DLC can name,
//! with the bit-rate switch (BRS) flag; and [`TxFrame`], the frame types a controller's outbox
//! can hold.

use embedded_can::{Frame, Id, StandardId};

use crate::can::frame::CanFrame;

/// The data lengths of an FD frame by DLC code 0..=15.
pub const FD_LENGTHS: [u8; 16] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64];

/// Most data bytes of an FD frame.
pub const FD_MAX_LEN: usize = 64;

/// The DLC code of an FD frame of `len` bytes, if `len` is one of [`FD_LENGTHS`].
pub const fn fd_dlc_code(len: usize) -> Option<u8> {
    let mut code = 0;
    while code < FD_LENGTHS.len() {
        if FD_LENGTHS[code] as usize == len {
            return Some(code as u8);
        }
        code += 1;
    }
    None
}

/// The shortest FD data length that holds `n` bytes (at most 64).
pub const fn fd_length(n: usize) -> Option<usize> {
    let mut code = 0;
    while code < FD_LENGTHS.len() {
        if FD_LENGTHS[code] as usize >= n {
            return Some(FD_LENGTHS[code] as usize);
        }
        code += 1;
    }
    None
}

/// A CAN FD data frame: an identifier, a data length of [`FD_LENGTHS`] and the bit-rate switch
/// flag (the data phase at the data bit rate). Implements [`embedded_can::Frame`]: `dlc()` is the
/// data length in bytes (as for classic frames), [`FdFrame::dlc_code`] the 4-bit code on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FdFrame {
    id: Id,
    len: u8,
    brs: bool,
    data: [u8; FD_MAX_LEN],
}

impl FdFrame {
    /// A frame with bit-rate switching on; `None` if `data` is not one of [`FD_LENGTHS`] long.
    pub fn new_fd(id: impl Into<Id>, data: &[u8], brs: bool) -> Option<Self> {
        fd_dlc_code(data.len())?;
        let mut buf = [0u8; FD_MAX_LEN];
        buf[..data.len()].copy_from_slice(data);
        Some(FdFrame {
            id: id.into(),
            len: data.len() as u8,
            brs,
            data: buf,
        })
    }

    /// A standard-id frame with bit-rate switching; `None` if `raw_id` is over 0x7FF or `data`
    /// not one of [`FD_LENGTHS`] long.
    pub fn standard(raw_id: u16, data: &[u8]) -> Option<Self> {
        Self::new_fd(StandardId::new(raw_id)?, data, true)
    }

    /// A standard-id frame with bit-rate switching that cannot fail: the id is masked to 11 bits,
    /// data past 64 bytes is dropped and the rest padded with zeros to an FD length. For the
    /// crate's own identifiers and layouts.
    pub(crate) fn from_parts(raw_id: u16, data: &[u8]) -> Self {
        let id = StandardId::new(raw_id & 0x7FF).unwrap_or(StandardId::MAX);
        let n = data.len().min(FD_MAX_LEN);
        let mut buf = [0u8; FD_MAX_LEN];
        buf[..n].copy_from_slice(&data[..n]);
        FdFrame {
            id: Id::Standard(id),
            len: fd_length(n).unwrap_or(FD_MAX_LEN) as u8,
            brs: true,
            data: buf,
        }
    }

    /// The 11-bit identifier, or `None` for an extended id.
    pub fn standard_id(&self) -> Option<u16> {
        match self.id {
            Id::Standard(s) => Some(s.as_raw()),
            Id::Extended(_) => None,
        }
    }

    /// Whether the data phase runs at the data bit rate (BRS).
    pub fn bit_rate_switch(&self) -> bool {
        self.brs
    }

    /// The 4-bit DLC code of the data length.
    pub fn dlc_code(&self) -> u8 {
        fd_dlc_code(usize::from(self.len)).unwrap_or(15)
    }
}

impl Frame for FdFrame {
    /// An FD frame with bit-rate switching; `None` if `data` is not one of [`FD_LENGTHS`] long.
    fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
        Self::new_fd(id, data, true)
    }

    /// CAN FD has no remote frames.
    fn new_remote(_id: impl Into<Id>, _dlc: usize) -> Option<Self> {
        None
    }

    fn is_extended(&self) -> bool {
        matches!(self.id, Id::Extended(_))
    }

    fn is_remote_frame(&self) -> bool {
        false
    }

    fn id(&self) -> Id {
        self.id
    }

    fn dlc(&self) -> usize {
        usize::from(self.len)
    }

    fn data(&self) -> &[u8] {
        &self.data[..usize::from(self.len)]
    }
}

/// A frame type a controller's outbox holds ([`crate::controller::Outbox`]): every type holds
/// the classic frames; an FD-capable one also the FD frames of the FD layout.
pub trait TxFrame: Sized {
    /// Whether this type holds FD frames. A controller whose type holds classic frames only is in
    /// the classic layout, known at compile time: its frame path has no layout branches and no
    /// FD code ([`crate::Controller::layout`]).
    const HOLDS_FD: bool;
    /// A classic frame as this type.
    fn classic(frame: CanFrame) -> Self;
    /// An FD frame as this type, `None` if the type holds classic frames only.
    fn fd(frame: FdFrame) -> Option<Self>;
}

impl TxFrame for CanFrame {
    const HOLDS_FD: bool = false;

    fn classic(frame: CanFrame) -> Self {
        frame
    }

    fn fd(_frame: FdFrame) -> Option<Self> {
        None
    }
}

/// A frame of a CAN FD bus: a classic frame or an FD frame (a CAN FD controller sends both).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AnyFrame {
    /// A classic frame (at most 8 bytes).
    Classic(CanFrame),
    /// An FD frame.
    Fd(FdFrame),
}

impl AnyFrame {
    /// The 11-bit identifier, or `None` for an extended id.
    pub fn standard_id(&self) -> Option<u16> {
        match self {
            AnyFrame::Classic(f) => f.standard_id(),
            AnyFrame::Fd(f) => f.standard_id(),
        }
    }

    /// The identifier.
    pub fn id(&self) -> Id {
        match self {
            AnyFrame::Classic(f) => f.id(),
            AnyFrame::Fd(f) => f.id(),
        }
    }

    /// The data bytes.
    pub fn data(&self) -> &[u8] {
        match self {
            AnyFrame::Classic(f) => f.data(),
            AnyFrame::Fd(f) => f.data(),
        }
    }

    /// Whether it is an FD frame.
    pub fn is_fd(&self) -> bool {
        matches!(self, AnyFrame::Fd(_))
    }
}

impl Frame for AnyFrame {
    /// A classic frame up to 8 bytes, an FD frame (bit-rate switching on) of an FD length above.
    fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
        if data.len() <= 8 {
            CanFrame::new(id, data).map(AnyFrame::Classic)
        } else {
            FdFrame::new(id, data).map(AnyFrame::Fd)
        }
    }

    /// A classic remote frame (CAN FD has none).
    fn new_remote(id: impl Into<Id>, dlc: usize) -> Option<Self> {
        CanFrame::new_remote(id, dlc).map(AnyFrame::Classic)
    }

    fn is_extended(&self) -> bool {
        matches!(AnyFrame::id(self), Id::Extended(_))
    }

    fn is_remote_frame(&self) -> bool {
        false
    }

    fn id(&self) -> Id {
        AnyFrame::id(self)
    }

    fn dlc(&self) -> usize {
        AnyFrame::data(self).len()
    }

    fn data(&self) -> &[u8] {
        AnyFrame::data(self)
    }
}

impl TxFrame for AnyFrame {
    const HOLDS_FD: bool = true;

    fn classic(frame: CanFrame) -> Self {
        AnyFrame::Classic(frame)
    }

    fn fd(frame: FdFrame) -> Option<Self> {
        Some(AnyFrame::Fd(frame))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_dlc_lengths_make_frames() {
        for (code, &len) in FD_LENGTHS.iter().enumerate() {
            let f =
                FdFrame::standard(0x210, &[0xA5; 64][..usize::from(len)]).expect("an FD length");
            assert_eq!(
                (f.dlc_code(), f.dlc(), f.data().len()),
                (code as u8, usize::from(len), usize::from(len))
            );
            assert!(f.bit_rate_switch());
        }
        for bad in [9usize, 10, 11, 13, 47, 63, 65] {
            assert!(FdFrame::standard(0x210, &[0; 80][..bad]).is_none(), "{bad}");
        }
        assert!(FdFrame::standard(0x800, &[]).is_none());
        assert_eq!(fd_length(46), Some(48));
        assert_eq!(fd_length(65), None);
        assert!(FdFrame::new_remote(StandardId::ZERO, 0).is_none());
    }
}
