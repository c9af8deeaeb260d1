//! A socketcand client: the `embedded-can` adapter that puts a node on the virtual bus.
//!
//! [`BusClient`] implements [`embedded_can::blocking::Can`] (the trait a microcontroller's CAN
//! driver implements), plus a receive with a timeout that also hands back the bus timestamp and
//! error frames.

use std::collections::VecDeque;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::{Duration, Instant};

use dex_runtime::can::{CanFrame, FdFrame};
use embedded_can::Frame;

use crate::protocol::{Framer, Reply, fdsend_message, parse_reply, send_message};

/// Errors of a bus connection.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// Socket error.
    #[error("bus connection: {0}")]
    Io(#[from] std::io::Error),
    /// The server closed the connection.
    #[error("bus connection closed")]
    Closed,
    /// The handshake did not complete.
    #[error("socketcand handshake failed: expected {expected}, got {got}")]
    Handshake {
        /// What was expected.
        expected: &'static str,
        /// What came instead.
        got: String,
    },
    /// No answer in time.
    #[error("no answer from the bus within {0:?}")]
    Timeout(Duration),
}

impl embedded_can::Error for ClientError {
    fn kind(&self) -> embedded_can::ErrorKind {
        embedded_can::ErrorKind::Other
    }
}

/// Something received from the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Received {
    /// A data frame and its bus time (microseconds).
    Frame(CanFrame, u64),
    /// A CAN FD data frame and its bus time (a bus started with `--fd`).
    Fd(FdFrame, u64),
    /// An error frame (Linux `can/error.h` class bits) and its bus time.
    Error(u32, u64),
}

/// One node's connection to the bus.
#[derive(Debug)]
pub struct BusClient {
    read: TcpStream,
    write: TcpStream,
    framer: Framer,
    pending: VecDeque<Reply>,
    out: String,
}

impl BusClient {
    /// Connects and completes the socketcand handshake (`< hi >`, open, rawmode).
    pub fn connect(addr: SocketAddr, channel: &str) -> Result<Self, ClientError> {
        let mut c = Self::connect_raw(addr)?;
        c.send_line(&format!("< open {channel} >"))?;
        c.expect(Reply::Ok, "< ok >")?;
        c.send_line("< rawmode >")?;
        c.expect(Reply::Ok, "< ok >")?;
        Ok(c)
    }

    /// Connects and reads the greeting only (for control connections).
    pub fn connect_raw(addr: SocketAddr) -> Result<Self, ClientError> {
        let stream = TcpStream::connect_timeout(&addr, Duration::from_secs(2))?;
        stream.set_nodelay(true)?;
        let write = stream.try_clone()?;
        let mut c = BusClient {
            read: stream,
            write,
            framer: Framer::default(),
            pending: VecDeque::new(),
            out: String::new(),
        };
        c.expect(Reply::Hi, "< hi >")?;
        Ok(c)
    }

    fn expect(&mut self, want: Reply, name: &'static str) -> Result<(), ClientError> {
        let got = self.next_reply(Duration::from_secs(2))?;
        match got {
            Some(r) if r == want => Ok(()),
            Some(r) => Err(ClientError::Handshake {
                expected: name,
                got: format!("{r:?}"),
            }),
            None => Err(ClientError::Timeout(Duration::from_secs(2))),
        }
    }

    /// Sends one raw protocol line.
    pub fn send_line(&mut self, line: &str) -> Result<(), ClientError> {
        self.write.write_all(line.as_bytes())?;
        Ok(())
    }

    /// Sends a control command (`fault drop 205 1`, `stats`, ...) and returns the reply's words.
    pub fn control(&mut self, command: &str) -> Result<Vec<String>, ClientError> {
        self.send_line(&format!("< {command} >"))?;
        let deadline = Instant::now() + Duration::from_secs(2);
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.next_reply(left)? {
                Some(Reply::Ok) => return Ok(vec!["ok".into()]),
                Some(Reply::Other(words)) => return Ok(words),
                Some(_) => continue,
                None => return Err(ClientError::Timeout(Duration::from_secs(2))),
            }
        }
    }

    /// Queues a frame; [`BusClient::flush`] writes everything queued in one system call.
    pub fn queue(&mut self, frame: &impl Frame) {
        self.out.push_str(&send_message(frame));
    }

    /// Queues an FD frame (`< fdsend ... >`; a bus without `--fd` ignores it).
    pub fn queue_fd(&mut self, frame: &FdFrame) {
        self.out.push_str(&fdsend_message(frame));
    }

    /// Queues one raw protocol line (a control verb among the frames: written with them).
    pub fn queue_line(&mut self, line: &str) {
        self.out.push_str(line);
    }

    /// Writes the queued frames.
    pub fn flush(&mut self) -> Result<(), ClientError> {
        if !self.out.is_empty() {
            self.write.write_all(self.out.as_bytes())?;
            self.out.clear();
        }
        Ok(())
    }

    /// The next frame or error frame, waiting at most `timeout`.
    pub fn receive_timeout(&mut self, timeout: Duration) -> Result<Option<Received>, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.next_reply(left)? {
                Some(Reply::Frame(f, ts)) => return Ok(Some(Received::Frame(f, ts))),
                Some(Reply::FdFrame(f, ts)) => return Ok(Some(Received::Fd(f, ts))),
                Some(Reply::Error(c, ts)) => return Ok(Some(Received::Error(c, ts))),
                Some(_) => continue,
                None => return Ok(None),
            }
        }
    }

    fn next_reply(&mut self, timeout: Duration) -> Result<Option<Reply>, ClientError> {
        if let Some(r) = self.pending.pop_front() {
            return Ok(Some(r));
        }
        let deadline = Instant::now() + timeout;
        let mut buf = [0u8; 8192];
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            self.read
                .set_read_timeout(Some(left.max(Duration::from_micros(10))))?;
            match self.read.read(&mut buf) {
                Ok(0) => return Err(ClientError::Closed),
                Ok(n) => {
                    self.framer.push(&buf[..n]);
                    while let Some(text) = self.framer.next_message() {
                        self.pending.push_back(parse_reply(&text));
                    }
                    if let Some(r) = self.pending.pop_front() {
                        return Ok(Some(r));
                    }
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    if Instant::now() >= deadline {
                        return Ok(None);
                    }
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e.into()),
            }
        }
    }
}

impl embedded_can::blocking::Can for BusClient {
    type Frame = CanFrame;
    type Error = ClientError;

    fn transmit(&mut self, frame: &Self::Frame) -> Result<(), Self::Error> {
        self.queue(frame);
        self.flush()
    }

    fn receive(&mut self) -> Result<Self::Frame, Self::Error> {
        loop {
            if let Some(Received::Frame(f, _)) = self.receive_timeout(Duration::from_secs(1))? {
                return Ok(f);
            }
        }
    }
}
