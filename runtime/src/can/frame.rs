//! A classic CAN data frame that any `embedded-can` driver can send.

use embedded_can::{Frame, Id, StandardId};

/// A classic (8-byte) CAN data frame. Implements [`embedded_can::Frame`], so a driver's own frame
/// type is built with `F::new(frame.id(), frame.data())`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CanFrame {
    id: Id,
    len: u8,
    data: [u8; 8],
}

impl CanFrame {
    /// A standard-id data frame; `None` if `raw_id` is over 0x7FF or `data` over 8 bytes.
    pub fn standard(raw_id: u16, data: &[u8]) -> Option<Self> {
        Frame::new(StandardId::new(raw_id)?, data)
    }

    /// A standard-id frame that cannot fail: the id is masked to 11 bits and data past 8 bytes is
    /// dropped. For the crate's own constant identifiers.
    pub(crate) fn from_parts(raw_id: u16, data: &[u8]) -> Self {
        let id = StandardId::new(raw_id & 0x7FF).unwrap_or(StandardId::MAX);
        let len = data.len().min(8);
        let mut buf = [0u8; 8];
        buf[..len].copy_from_slice(&data[..len]);
        CanFrame {
            id: Id::Standard(id),
            len: len as u8,
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

    /// Copies any `embedded-can` frame (remote frames keep their id and length, no data).
    pub fn from_frame(frame: &impl Frame) -> Option<Self> {
        if frame.is_remote_frame() {
            let mut f = Self::new_remote(frame.id(), frame.dlc())?;
            f.len = frame.dlc().min(8) as u8;
            Some(f)
        } else {
            Self::new(frame.id(), frame.data())
        }
    }
}

impl Frame for CanFrame {
    fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
        if data.len() > 8 {
            return None;
        }
        let mut buf = [0u8; 8];
        buf[..data.len()].copy_from_slice(data);
        Some(CanFrame {
            id: id.into(),
            len: data.len() as u8,
            data: buf,
        })
    }

    /// Remote frames are not used by this interface; they are represented with no data.
    fn new_remote(id: impl Into<Id>, dlc: usize) -> Option<Self> {
        if dlc > 8 {
            return None;
        }
        Some(CanFrame {
            id: id.into(),
            len: 0,
            data: [0; 8],
        })
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
