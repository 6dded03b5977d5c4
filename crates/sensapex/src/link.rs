//! The client side of SMCP1 over UDP, as Sensapex's libum behaves on the wire (its
//! `src/libum.c`, v1.504): a request asks for an ACK (and a response when it wants
//! data), is sent up to [`SENDS`] times with the same message id, [`Link::timeout`]
//! apart, and a reply is matched by its receiver (our id), message id and type.
//! Notifications (positions, status, goto completed) arriving meanwhile are kept per
//! device. A lost or late reply is a typed error naming the device and the address,
//! never a hang.

use std::collections::HashMap;
use std::net::{IpAddr, Ipv4Addr, SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use thiserror::Error;

use crate::protocol::{ALL_DEVICES, Frame, FrameError, MAX_DATAGRAM, PORT, cmd, opt};

/// Sends of one request before it has failed (libum's retransmit count).
pub const SENDS: u32 = 3;
/// How long each send waits for its reply by default (Sensapex's Python client).
pub const DEFAULT_TIMEOUT: Duration = Duration::from_millis(200);
/// The lowest of our SMCP1 ids: a PC's ids are above 0x200. Each link takes one of
/// the next 0xfd at random (as libum does), and starts its message ids at random: a
/// device that saw another process's request does not take ours for its
/// retransmission.
pub const OWN_ID: u16 = 0x0201;

/// A number that differs from process to process and from link to link.
fn entropy() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u128(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos()),
    );
    h.write_u32(std::process::id());
    h.finish()
}
/// Receiver ids a notification for a PC may carry: every control unit or PC.
const PCS: [u16; 3] = [0x01ff, 0x02ff, 0x03ff];

/// What can go wrong talking to a Sensapex device.
#[derive(Debug, Error)]
pub enum SensapexError {
    /// No reply after every send.
    #[error(
        "Sensapex device {device} at {address} did not answer {command} ({sends} sends, {seconds:.1} s)"
    )]
    Timeout {
        /// Device id.
        device: u16,
        /// Where it was sent.
        address: SocketAddr,
        /// The command, by name.
        command: &'static str,
        /// Sends made.
        sends: u32,
        /// Time waited, s.
        seconds: f64,
    },
    /// The device refused the request (the ERROR option).
    #[error("Sensapex device {device} at {address} refused {command}")]
    Refused {
        /// Device id.
        device: u16,
        /// Its address.
        address: SocketAddr,
        /// The command.
        command: &'static str,
    },
    /// A reply the protocol does not allow.
    #[error("Sensapex device {device} answered {command} with {reason}")]
    BadReply {
        /// Device id.
        device: u16,
        /// The command.
        command: &'static str,
        /// What was wrong.
        reason: String,
    },
    /// The socket failed.
    #[error("Sensapex link to {address}: {source}")]
    Io {
        /// The devices' address.
        address: SocketAddr,
        /// The OS error.
        source: std::io::Error,
    },
}

/// What the notifications said of one device.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Notes {
    /// Last notified positions, nm.
    pub positions: Option<Vec<i32>>,
    /// Last notified status bits.
    pub status: u32,
    /// The outcome of the last goto notified completed (0 or 2: reached, else
    /// failed), with the notification's message id.
    pub completed: Option<(u16, i32)>,
}

/// A command's name, for errors.
pub fn command_name(kind: u16) -> &'static str {
    match kind {
        cmd::PING => "PING",
        cmd::STOP => "STOP",
        cmd::GET_POSITIONS => "GET_POSITIONS",
        cmd::GET_PARAMETER => "GET_PARAMETER",
        cmd::SET_PARAMETER => "SET_PARAMETER",
        cmd::GET_VERSION => "GET_VERSION",
        cmd::GOTO_POS => "GOTO_POS",
        cmd::TAKE_STEP => "TAKE_STEP",
        cmd::READ_ERROR_STATE => "READ_ERROR_STATE",
        cmd::CLEAR_ERROR_STATE => "CLEAR_ERROR_STATE",
        cmd::UMS_GET_LENS_POSITION => "UMS_GET_LENS_POSITION",
        cmd::UMS_SET_LENS_POSITION => "UMS_SET_LENS_POSITION",
        cmd::UMV_SET_PRESSURE => "UMV_SET_PRESSURE",
        cmd::UMV_GET_PRESSURE => "UMV_GET_PRESSURE",
        cmd::UMV_SET_VALVE => "UMV_SET_VALVE",
        cmd::UMV_GET_VALVE => "UMV_GET_VALVE",
        cmd::UMV_MEASURE_PRESSURE => "UMV_MEASURE_PRESSURE",
        _ => "a command",
    }
}

/// A UDP link to the Sensapex devices of one address and group.
#[derive(Debug)]
pub struct Link {
    socket: UdpSocket,
    target: SocketAddr,
    /// Where each device answered from (unicast after the first reply).
    learned: HashMap<u16, SocketAddr>,
    own_id: u16,
    message_id: u16,
    timeout: Duration,
    notes: HashMap<u16, Notes>,
}

impl Link {
    /// Opens a link to the devices at `address` (a device's address, the broadcast
    /// 169.254.255.255, or 127.0.0.1 for an emulator) in `group` (port 55555 +
    /// group). On loopback the local port is the devices' minus 2, as libum binds it,
    /// else any free port.
    pub fn open(address: IpAddr, group: u16) -> Result<Link, SensapexError> {
        let target = SocketAddr::new(address, PORT + group);
        let io = |source| SensapexError::Io {
            address: target,
            source,
        };
        let any = IpAddr::V4(Ipv4Addr::UNSPECIFIED);
        let socket = if address.is_loopback() {
            UdpSocket::bind((any, PORT + group - 2)).or_else(|_| UdpSocket::bind((any, 0)))
        } else {
            UdpSocket::bind((any, 0))
        }
        .map_err(io)?;
        socket.set_broadcast(true).map_err(io)?;
        Ok(Link::on(socket, target))
    }

    fn on(socket: UdpSocket, target: SocketAddr) -> Link {
        let e = entropy();
        Link {
            socket,
            target,
            learned: HashMap::new(),
            own_id: OWN_ID + (e % 0xfd) as u16,
            message_id: (e >> 16) as u16,
            timeout: DEFAULT_TIMEOUT,
            notes: HashMap::new(),
        }
    }

    /// Opens a link to devices at `target` (any address and port: an emulator on a
    /// port of its own), from any free local port.
    pub fn to(target: SocketAddr) -> Result<Link, SensapexError> {
        let any = match target {
            SocketAddr::V4(_) => IpAddr::V4(Ipv4Addr::UNSPECIFIED),
            SocketAddr::V6(_) => IpAddr::V6(std::net::Ipv6Addr::UNSPECIFIED),
        };
        let socket = UdpSocket::bind((any, 0)).map_err(|source| SensapexError::Io {
            address: target,
            source,
        })?;
        Ok(Link::on(socket, target))
    }

    /// The devices' address and port.
    pub fn target(&self) -> SocketAddr {
        self.target
    }

    /// How long each send waits for its reply.
    pub fn timeout(&self) -> Duration {
        self.timeout
    }

    /// Sets how long each send waits for its reply (at least 1 ms).
    pub fn set_timeout(&mut self, t: Duration) {
        self.timeout = t.max(Duration::from_millis(1));
    }

    /// Our SMCP1 id on this link.
    pub fn own_id(&self) -> u16 {
        self.own_id
    }

    /// What the notifications said of `device` so far (after [`Link::poll`]).
    pub fn notes(&self, device: u16) -> Notes {
        self.notes.get(&device).cloned().unwrap_or_default()
    }

    fn address_of(&self, device: u16) -> SocketAddr {
        self.learned.get(&device).copied().unwrap_or(self.target)
    }

    fn next_id(&mut self) -> u16 {
        self.message_id = self.message_id.wrapping_add(1).max(1);
        self.message_id
    }

    /// Reads one datagram, waiting at most `wait`; keeps notifications and learns
    /// addresses. `Ok(None)` when nothing (usable) came.
    fn receive(&mut self, wait: Duration) -> Result<Option<Frame>, SensapexError> {
        let io = |source| SensapexError::Io {
            address: self.target,
            source,
        };
        self.socket
            .set_read_timeout(Some(wait.max(Duration::from_micros(100))))
            .map_err(io)?;
        let mut buf = [0u8; MAX_DATAGRAM];
        let (n, from) = match self.socket.recv_from(&mut buf) {
            Ok(x) => x,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                return Ok(None);
            }
            // A port unreachable from an earlier send (ICMP on loopback).
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => return Ok(None),
            Err(e) => return Err(io(e)),
        };
        let f: Result<Frame, FrameError> = Frame::decode(&buf[..n]);
        let Ok(f) = f else { return Ok(None) };
        self.learned.insert(f.sender, from);
        if f.options & opt::NOTIFY != 0 && (f.receiver == self.own_id || PCS.contains(&f.receiver))
        {
            let values = f.ints(0);
            let notes = self.notes.entry(f.sender).or_default();
            match f.kind {
                cmd::NOTIFY_POSITION_CHANGED if !values.is_empty() => {
                    notes.positions = Some(values);
                }
                cmd::NOTIFY_STATUS_CHANGED => {
                    notes.status = values.first().map_or(0, |&s| s as u32);
                }
                cmd::NOTIFY_GOTO_POS_COMPLETED => {
                    let code = values.first().copied().unwrap_or(-1);
                    if notes.completed.map(|(id, _)| id) != Some(f.message_id) {
                        notes.completed = Some((f.message_id, code));
                    }
                }
                _ => {}
            }
            return Ok(None);
        }
        if f.receiver != self.own_id {
            return Ok(None);
        }
        Ok(Some(f))
    }

    /// Reads every datagram waiting (notifications).
    pub fn poll(&mut self) -> Result<(), SensapexError> {
        let end = Instant::now() + Duration::from_millis(1);
        while Instant::now() < end {
            if self.receive(Duration::from_micros(100))?.is_none() {
                break;
            }
        }
        Ok(())
    }

    /// Sends `kind` with `args` to `device` and waits for its ACK, and for its
    /// response when `respond`: the response's values (empty without one).
    pub fn request(
        &mut self,
        device: u16,
        kind: u16,
        args: &[i32],
        respond: bool,
    ) -> Result<Vec<i32>, SensapexError> {
        let mut options = opt::REQ_ACK;
        if respond {
            options |= opt::REQ_RESP;
        }
        if kind == cmd::GOTO_POS {
            options |= opt::REQ_NOTIFY;
        }
        self.exchange(device, kind, &[args], options)
    }

    /// [`Link::request`] with several sub-blocks of arguments (a goto's per-axis
    /// speeds), options as given.
    pub fn exchange(
        &mut self,
        device: u16,
        kind: u16,
        blocks: &[&[i32]],
        options: u32,
    ) -> Result<Vec<i32>, SensapexError> {
        let id = self.next_id();
        let mut f = Frame::request(kind, self.own_id, device, id, options, &[]);
        f.blocks = blocks
            .iter()
            .filter(|b| !b.is_empty())
            .map(|b| crate::protocol::SubBlock::i32s(b))
            .collect();
        let bytes = f.encode();
        let to = self.address_of(device);
        let command = command_name(kind);
        let respond = options & opt::REQ_RESP != 0;
        let start = Instant::now();
        let mut acked = false;
        for _ in 0..SENDS {
            if !acked {
                self.socket
                    .send_to(&bytes, to)
                    .map_err(|source| SensapexError::Io {
                        address: to,
                        source,
                    })?;
            }
            let round = Instant::now() + self.timeout;
            loop {
                let now = Instant::now();
                if now >= round {
                    break;
                }
                let Some(r) = self.receive(round - now)? else {
                    continue;
                };
                if r.message_id != id || r.kind != kind && r.options & opt::ACK == 0 {
                    continue;
                }
                if r.options & opt::ERROR != 0 {
                    return Err(SensapexError::Refused {
                        device,
                        address: to,
                        command,
                    });
                }
                if r.options & opt::ACK != 0 {
                    acked = true;
                    if !respond {
                        return Ok(Vec::new());
                    }
                    continue;
                }
                if r.is_request() {
                    continue;
                }
                if r.blocks.is_empty() {
                    return Err(SensapexError::BadReply {
                        device,
                        command,
                        reason: "a response without data".into(),
                    });
                }
                return Ok(r.ints(0));
            }
        }
        Err(SensapexError::Timeout {
            device,
            address: to,
            command,
            sends: SENDS,
            seconds: start.elapsed().as_secs_f64(),
        })
    }

    /// The devices that answer a PING to every device within the link's timeout.
    pub fn discover(&mut self) -> Result<Vec<u16>, SensapexError> {
        let id = self.next_id();
        let f = Frame::request(cmd::PING, self.own_id, ALL_DEVICES, id, opt::REQ_ACK, &[]);
        self.socket
            .send_to(&f.encode(), self.target)
            .map_err(|source| SensapexError::Io {
                address: self.target,
                source,
            })?;
        let end = Instant::now() + self.timeout;
        let mut found = Vec::new();
        loop {
            let now = Instant::now();
            if now >= end {
                break;
            }
            if let Some(r) = self.receive(end - now)?
                && r.message_id == id
                && r.options & opt::ACK != 0
                && !found.contains(&r.sender)
            {
                found.push(r.sender);
            }
        }
        found.sort_unstable();
        Ok(found)
    }
}
