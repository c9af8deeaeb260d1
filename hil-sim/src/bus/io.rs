//! Client connections: the acceptor, and per client a reader and a writer thread.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::sync::mpsc::{self, Receiver, Sender};

use dex_runtime::can::AnyFrame;

use crate::protocol::{Framer, Request, parse_request};

use super::HANDSHAKE_GRACE;
use super::control::parse_control;
use super::thread::{Event, Shared};

pub(super) enum Outgoing {
    Line(String),
    Grace,
}

/// Sets `SO_SNDBUF` (best effort).
fn set_send_buffer(stream: &TcpStream, bytes: usize) {
    use std::os::fd::AsRawFd;
    let value = libc::c_int::try_from(bytes).unwrap_or(libc::c_int::MAX);
    // SAFETY: the descriptor is open for the lifetime of `stream`, and the option value is a
    // c_int whose size is passed alongside.
    unsafe {
        libc::setsockopt(
            stream.as_raw_fd(),
            libc::SOL_SOCKET,
            libc::SO_SNDBUF,
            (&value as *const libc::c_int).cast(),
            std::mem::size_of::<libc::c_int>() as libc::socklen_t,
        );
    }
}

pub(super) fn accept_loop(
    listener: TcpListener,
    events: Sender<Event>,
    shared: Arc<Shared>,
    depth: usize,
    sndbuf: Option<usize>,
) {
    let mut next_id = 0u64;
    for conn in listener.incoming() {
        if shared.stop.load(Ordering::SeqCst) {
            break;
        }
        let Ok(stream) = conn else { continue };
        let _ = stream.set_nodelay(true);
        if let Some(bytes) = sndbuf {
            set_send_buffer(&stream, bytes);
        }
        let Ok(write_half) = stream.try_clone() else {
            continue;
        };
        next_id += 1;
        let client = next_id;
        let (out_tx, out_rx) = mpsc::sync_channel(depth);
        if events
            .send(Event::Join {
                client,
                out: out_tx,
            })
            .is_err()
        {
            break;
        }
        let ev = events.clone();
        let spawned_reader = std::thread::Builder::new()
            .name(format!("bus-rd-{client}"))
            .spawn(move || reader_loop(client, stream, ev));
        let spawned_writer = std::thread::Builder::new()
            .name(format!("bus-wr-{client}"))
            .spawn(move || writer_loop(write_half, out_rx));
        if spawned_reader.is_err() || spawned_writer.is_err() {
            let _ = events.send(Event::Leave { client });
        }
    }
}

fn reader_loop(client: u64, mut stream: TcpStream, events: Sender<Event>) {
    let mut framer = Framer::default();
    // Large enough that a node's write (a few hundred bytes per answer) comes in one read.
    let mut buf = vec![0u8; 64 * 1024];
    loop {
        let n = match stream.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        framer.push(&buf[..n]);
        // Every complete message of this read in one event (see the module's documentation).
        let mut batch = Vec::new();
        while let Some(text) = framer.next_message() {
            batch.push(match parse_request(&text) {
                Request::Open(_) => Event::Open { client },
                Request::RawMode => Event::Subscribe { client },
                Request::Send(frame) => Event::Frame {
                    client,
                    frame: AnyFrame::Classic(frame),
                },
                Request::SendFd(frame) => Event::Frame {
                    client,
                    frame: AnyFrame::Fd(frame),
                },
                Request::Control(words) => Event::Control {
                    client: Some(client),
                    command: parse_control(&words),
                },
                Request::Unknown => Event::Unknown,
            });
        }
        let event = match batch.len() {
            0 => continue,
            1 => batch.swap_remove(0),
            _ => Event::Batch(batch),
        };
        if events.send(event).is_err() {
            return;
        }
    }
    let _ = stream.shutdown(std::net::Shutdown::Both);
    let _ = events.send(Event::Leave { client });
}

fn writer_loop(mut stream: TcpStream, out: Receiver<Outgoing>) {
    let mut batch = String::new();
    while let Ok(first) = out.recv() {
        let mut next = Some(first);
        while let Some(msg) = next.take() {
            match msg {
                Outgoing::Line(line) => {
                    batch.push_str(&line);
                    if batch.len() < 16 * 1024 {
                        next = out.try_recv().ok();
                    }
                }
                Outgoing::Grace => {
                    if stream.write_all(batch.as_bytes()).is_err() {
                        return;
                    }
                    batch.clear();
                    std::thread::sleep(HANDSHAKE_GRACE);
                }
            }
        }
        if !batch.is_empty() {
            if stream.write_all(batch.as_bytes()).is_err() {
                return;
            }
            batch.clear();
        }
    }
    let _ = stream.shutdown(std::net::Shutdown::Both);
}
