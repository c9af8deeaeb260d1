//! Real CAN hardware for the controller node: Linux SocketCAN through the `socketcan` crate
//! (feature `socketcan`). Untested here: the development machines have no `AF_CAN`.

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use dex_runtime::can::CanFrame;
use embedded_can::Frame;
use socketcan::{CanSocket, Socket};

use crate::client::{ClientError, Received};
use crate::node::NodePort;

/// A SocketCAN interface (`can0`, `vcan0`) as the controller node's port.
#[derive(Debug)]
pub struct SocketCanPort {
    socket: CanSocket,
    queued: Vec<CanFrame>,
}

impl SocketCanPort {
    /// Opens interface `name`.
    pub fn open(name: &str) -> Result<Self, ClientError> {
        Ok(SocketCanPort {
            socket: CanSocket::open(name)?,
            queued: Vec::new(),
        })
    }
}

fn now_us() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64)
}

impl NodePort for SocketCanPort {
    fn queue(&mut self, frame: &CanFrame) {
        self.queued.push(*frame);
    }

    fn flush(&mut self) -> Result<(), ClientError> {
        for f in self.queued.drain(..) {
            let Some(out) = socketcan::CanFrame::new(f.id(), f.data()) else {
                continue;
            };
            self.socket.write_frame_insist(&out)?;
        }
        Ok(())
    }

    fn receive_timeout(&mut self, timeout: Duration) -> Result<Option<Received>, ClientError> {
        match self.socket.read_frame_timeout(timeout) {
            Ok(socketcan::CanFrame::Data(f)) => {
                Ok(CanFrame::from_frame(&f).map(|f| Received::Frame(f, now_us())))
            }
            Ok(socketcan::CanFrame::Remote(_)) => Ok(None),
            Ok(socketcan::CanFrame::Error(e)) => {
                Ok(Some(Received::Error(e.error_bits(), now_us())))
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock
                ) =>
            {
                Ok(None)
            }
            Err(e) => Err(e.into()),
        }
    }
}
