//! [`SlcanCan`]: an `embedded_can::nb::Can` device made of SLCAN lines on a serial port, for
//! targets without a CAN controller (QEMU's STM32F405). `receive` assembles lines from the
//! USART's receive register and answers SLCAN commands itself; `transmit` writes a frame line.

use dex_runtime::can::CanFrame;
use embedded_can::{ErrorKind, Frame};
use embedded_hal_nb::serial::{Read, Write};

use crate::counters::COUNTERS;
use crate::slcan_rx::{Reply, RxItem, SlcanRx};

/// Why `receive` produced no frame although bytes came in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SlcanLinkError {
    /// The USART's receive register was overwritten before it was read (ORE).
    Overrun,
    /// Framing, noise or parity error on the line.
    Line,
    /// A line that is no SLCAN command, or too long (answered with BEL, counted).
    BadLine,
}

impl embedded_can::Error for SlcanLinkError {
    fn kind(&self) -> ErrorKind {
        match self {
            SlcanLinkError::Overrun => ErrorKind::Overrun,
            SlcanLinkError::Line | SlcanLinkError::BadLine => ErrorKind::Other,
        }
    }
}

/// SLCAN over a serial port `S` (its receive and transmit halves).
#[derive(Debug)]
pub struct SlcanCan<S> {
    serial: S,
    rx: SlcanRx,
    stamp: Option<u16>,
}

impl<S> SlcanCan<S>
where
    S: Read<u8> + Write<u8>,
{
    /// Over `serial`.
    pub fn new(serial: S) -> Self {
        SlcanCan {
            serial,
            rx: SlcanRx::new(),
            stamp: None,
        }
    }

    /// The Lawicel time stamp of the frame `receive` returned last, if its line had one.
    pub fn last_stamp(&self) -> Option<u16> {
        self.stamp
    }

    fn write_all(&mut self, bytes: &[u8]) {
        for &b in bytes {
            // The USART's transmitter always drains: a blocking write ends.
            let _ = nb::block!(self.serial.write(b));
        }
    }

    fn answer(&mut self, reply: Reply) {
        match reply {
            Reply::Ok => self.write_all(b"\r"),
            Reply::Error => self.write_all(&[dex_slcan::BELL]),
            Reply::Version => self.write_all(b"V0101\r"),
            Reply::Serial => self.write_all(b"NDEX1\r"),
            Reply::Status => {
                let f = COUNTERS.slcan_flags();
                let hex = |n: u8| b"0123456789ABCDEF"[usize::from(n & 0xF)];
                self.write_all(&[b'F', hex(f >> 4), hex(f), b'\r']);
            }
        }
    }
}

impl<S> embedded_can::nb::Can for SlcanCan<S>
where
    S: Read<u8> + Write<u8>,
{
    type Frame = CanFrame;
    type Error = SlcanLinkError;

    fn transmit(&mut self, frame: &CanFrame) -> nb::Result<Option<CanFrame>, SlcanLinkError> {
        let line = dex_slcan::encode_frame(frame.id(), frame.data(), None);
        self.write_all(line.as_bytes());
        Ok(None)
    }

    fn receive(&mut self) -> nb::Result<CanFrame, SlcanLinkError> {
        loop {
            let byte = match self.serial.read() {
                Ok(b) => b,
                Err(nb::Error::WouldBlock) => return Err(nb::Error::WouldBlock),
                Err(nb::Error::Other(e)) => {
                    self.rx.on_line_error();
                    use embedded_hal_nb::serial::{Error, ErrorKind as SerialKind};
                    return Err(nb::Error::Other(match e.kind() {
                        SerialKind::Overrun => SlcanLinkError::Overrun,
                        _ => SlcanLinkError::Line,
                    }));
                }
            };
            match self.rx.push(byte, &COUNTERS) {
                None => {}
                Some(RxItem::Frame(f, stamp)) => {
                    self.stamp = stamp;
                    return Ok(f);
                }
                Some(RxItem::Reply(r)) => {
                    self.answer(r);
                    if r == Reply::Error {
                        return Err(nb::Error::Other(SlcanLinkError::BadLine));
                    }
                }
            }
        }
    }
}
