//! Byte transports to a controller: TCP (PI's port 50000) and, with the `serial`
//! feature, a serial line. A transport can reconnect after the link broke.

use std::io::{self, Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::time::Duration;

/// Whether an IO error only means "nothing yet" (a read timeout, an interrupted call).
pub fn is_wait(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut | io::ErrorKind::Interrupted
    )
}

/// A byte link to a controller.
pub trait Transport: Send {
    /// Sends all of `bytes` (one write: a command is never split by us).
    fn send(&mut self, bytes: &[u8]) -> io::Result<()>;
    /// Reads what has arrived, waiting at most the timeout (`Ok(0)`: the peer closed).
    fn receive(&mut self, buf: &mut [u8]) -> io::Result<usize>;
    /// The longest a single `receive` waits.
    fn set_timeout(&mut self, timeout: Duration) -> io::Result<()>;
    /// Drops the link and opens it again.
    fn reconnect(&mut self) -> io::Result<()>;
    /// Where the link goes, for messages (`tcp://127.0.0.1:50000`).
    fn describe(&self) -> String;
}

/// TCP to `host:port`.
pub struct Tcp {
    address: String,
    stream: Option<TcpStream>,
    timeout: Duration,
}

impl Tcp {
    /// Connects to `address` (`host:port`) within `timeout`.
    pub fn connect(address: &str, timeout: Duration) -> io::Result<Self> {
        let mut t = Tcp {
            address: address.to_string(),
            stream: None,
            timeout,
        };
        t.reconnect()?;
        Ok(t)
    }

    fn stream(&mut self) -> io::Result<&mut TcpStream> {
        self.stream
            .as_mut()
            .ok_or_else(|| io::Error::new(io::ErrorKind::NotConnected, "not connected"))
    }
}

impl Transport for Tcp {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        let r = self.stream()?.write_all(bytes);
        if r.is_err() {
            self.stream = None;
        }
        r
    }
    fn receive(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.stream()?.read(buf)
    }
    fn set_timeout(&mut self, timeout: Duration) -> io::Result<()> {
        self.timeout = timeout;
        if let Some(s) = &self.stream {
            s.set_read_timeout(Some(timeout))?;
            s.set_write_timeout(Some(timeout))?;
        }
        Ok(())
    }
    fn reconnect(&mut self) -> io::Result<()> {
        self.stream = None;
        let mut last = io::Error::new(io::ErrorKind::NotFound, "the address resolves to nothing");
        for addr in self.address.to_socket_addrs()? {
            match TcpStream::connect_timeout(&addr, self.timeout) {
                Ok(s) => {
                    s.set_nodelay(true)?;
                    s.set_read_timeout(Some(self.timeout))?;
                    s.set_write_timeout(Some(self.timeout))?;
                    self.stream = Some(s);
                    return Ok(());
                }
                Err(e) => last = e,
            }
        }
        Err(last)
    }
    fn describe(&self) -> String {
        format!("gcs://{}", self.address)
    }
}

/// A serial line (8N1, no flow control) through the `serialport` crate.
#[cfg(feature = "serial")]
pub struct Serial {
    path: String,
    baud: u32,
    port: Option<Box<dyn serialport::SerialPort>>,
    timeout: Duration,
}

#[cfg(feature = "serial")]
impl Serial {
    /// Opens `path` at `baud`.
    pub fn open(path: &str, baud: u32, timeout: Duration) -> io::Result<Self> {
        let mut s = Serial {
            path: path.to_string(),
            baud,
            port: None,
            timeout,
        };
        s.reconnect()?;
        Ok(s)
    }

    /// Wraps a port opened elsewhere (a pseudo-terminal in tests); `reconnect` reopens
    /// it by `path`.
    pub fn from_port(port: Box<dyn serialport::SerialPort>, path: &str, timeout: Duration) -> Self {
        let baud = port.baud_rate().unwrap_or(115_200);
        Serial {
            path: path.to_string(),
            baud,
            port: Some(port),
            timeout,
        }
    }

    fn port(&mut self) -> io::Result<&mut Box<dyn serialport::SerialPort>> {
        self.port
            .as_mut()
            .ok_or_else(|| io::Error::new(io::ErrorKind::NotConnected, "port closed"))
    }
}

#[cfg(feature = "serial")]
impl Transport for Serial {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        let p = self.port()?;
        p.write_all(bytes)?;
        p.flush()
    }
    fn receive(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self.port()?.read(buf) {
            // A serial line has no end of stream: nothing yet is a timeout.
            Ok(0) => Err(io::Error::new(io::ErrorKind::TimedOut, "nothing received")),
            r => r,
        }
    }
    fn set_timeout(&mut self, timeout: Duration) -> io::Result<()> {
        self.timeout = timeout;
        if let Some(p) = self.port.as_mut() {
            p.set_timeout(timeout).map_err(io::Error::from)?;
        }
        Ok(())
    }
    fn reconnect(&mut self) -> io::Result<()> {
        self.port = None;
        let p = serialport::new(&self.path, self.baud)
            .timeout(self.timeout)
            .open()
            .map_err(io::Error::from)?;
        self.port = Some(p);
        Ok(())
    }
    fn describe(&self) -> String {
        format!("gcs-serial://{}", self.path)
    }
}
