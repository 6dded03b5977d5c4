//! The typed GCS 2.0 command set over a [`Transport`].

use std::time::{Duration, Instant};

use thiserror::Error;

use crate::link::Transport;
use crate::protocol::{self, ControllerError};

/// Why a GCS exchange failed.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum GcsError {
    /// The controller reported an error (read back with `ERR?`).
    #[error("{link}: `{command}` -> {error}")]
    Controller {
        /// The link.
        link: String,
        /// The command that raised it.
        command: String,
        /// The code.
        error: ControllerError,
    },
    /// No complete reply within the timeout.
    #[error("{link}: no reply to `{command}` within {seconds} s")]
    Timeout {
        /// The link.
        link: String,
        /// The command.
        command: String,
        /// How long we waited.
        seconds: f64,
    },
    /// The link broke or could not be opened.
    #[error("{link}: {message}")]
    Link {
        /// The link.
        link: String,
        /// What the operating system said.
        message: String,
    },
    /// A reply the protocol does not allow.
    #[error("{link}: unexpected reply to `{command}`: {reply:?} ({reason})")]
    Reply {
        /// The link.
        link: String,
        /// The command.
        command: String,
        /// What came back.
        reply: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A request we refuse to send (unknown axis, value not finite, bad command word).
    #[error("{link}: {reason}")]
    Invalid {
        /// The link.
        link: String,
        /// What is wrong.
        reason: String,
    },
}

impl GcsError {
    /// The controller's code, if the controller raised it.
    pub fn controller_error(&self) -> Option<ControllerError> {
        match self {
            GcsError::Controller { error, .. } => Some(*error),
            _ => None,
        }
    }

    /// Whether the link is in doubt (timeout, broken link, garbage): the driver
    /// reconnects and stops the axes before its next command.
    pub fn link_lost(&self) -> bool {
        matches!(
            self,
            GcsError::Timeout { .. } | GcsError::Link { .. } | GcsError::Reply { .. }
        )
    }
}

/// A GCS 2.0 controller.
///
/// Every set command is sent together with `ERR?` in one write and the error read back
/// (sticky errors are cleared by that read). A timeout, a broken link or a reply the
/// protocol does not allow marks the link as lost: the next call reconnects, drops
/// whatever stale bytes arrive, and sends `STP` (then `ERR?`, to clear the code 10 it
/// raises) before anything else, so the axes never keep moving on a command we lost
/// track of.
pub struct Gcs {
    link: Box<dyn Transport>,
    timeout: Duration,
    buf: Vec<u8>,
    lost: bool,
    axes: Vec<String>,
    /// How many times the link was re-established.
    pub reconnections: u32,
}

type R<T> = Result<T, GcsError>;

impl Gcs {
    /// Opens the controller behind `link`: reads its axes (`SAI?`) and clears any
    /// pending error.
    pub fn new(link: Box<dyn Transport>, timeout: Duration) -> R<Self> {
        let mut g = Gcs {
            link,
            timeout,
            buf: Vec::with_capacity(256),
            lost: false,
            axes: Vec::new(),
            reconnections: 0,
        };
        g.link.set_timeout(timeout).map_err(|e| g.link_error(&e))?;
        if let Err(e) = g.error() {
            return Err(match e {
                GcsError::Timeout { link, seconds, .. } => GcsError::Link {
                    link,
                    message: format!(
                        "connected, but no reply to `ERR?` within {seconds} s (another client may hold the controller: it serves one at a time)"
                    ),
                },
                other => other,
            });
        }
        g.axes = g.axes_query()?;
        Ok(g)
    }

    /// Connects over TCP to `host:port`.
    pub fn tcp(address: &str, timeout: Duration) -> R<Self> {
        let link = crate::link::Tcp::connect(address, timeout).map_err(|e| GcsError::Link {
            link: format!("gcs://{address}"),
            message: format!("cannot connect: {e}"),
        })?;
        Self::new(Box::new(link), timeout)
    }

    /// Opens a serial line.
    #[cfg(feature = "serial")]
    pub fn serial(path: &str, baud: u32, timeout: Duration) -> R<Self> {
        let link = crate::link::Serial::open(path, baud, timeout).map_err(|e| GcsError::Link {
            link: format!("gcs-serial://{path}"),
            message: format!("cannot open: {e}"),
        })?;
        Self::new(Box::new(link), timeout)
    }

    /// Changes how long a reply may take from now on (e.g. a generous timeout to
    /// connect, a short one for a fast control loop).
    pub fn set_timeout(&mut self, timeout: Duration) -> R<()> {
        self.timeout = timeout;
        self.link
            .set_timeout(timeout)
            .map_err(|e| self.link_error(&e))
    }

    /// The axis identifiers the controller reported at connection.
    pub fn axis_ids(&self) -> &[String] {
        &self.axes
    }

    /// Where the link goes.
    pub fn describe(&self) -> String {
        self.link.describe()
    }

    fn link_error(&self, e: &std::io::Error) -> GcsError {
        GcsError::Link {
            link: self.link.describe(),
            message: e.to_string(),
        }
    }

    fn invalid(&self, reason: String) -> GcsError {
        GcsError::Invalid {
            link: self.link.describe(),
            reason,
        }
    }

    /// Re-establishes a lost link and stops the axes first.
    fn recover(&mut self) -> R<()> {
        if !self.lost {
            return Ok(());
        }
        self.link.reconnect().map_err(|e| self.link_error(&e))?;
        self.reconnections += 1;
        self.buf.clear();
        // Stale bytes of the lost exchange: drop what arrives within a short while.
        let _ = self.link.set_timeout(Duration::from_millis(20));
        let mut scratch = [0u8; 256];
        while let Ok(n) = self.link.receive(&mut scratch) {
            if n == 0 {
                break;
            }
        }
        self.link
            .set_timeout(self.timeout)
            .map_err(|e| self.link_error(&e))?;
        self.lost = false;
        self.link
            .send(b"STP\nERR?\n")
            .map_err(|e| self.lose(self.link_error(&e)))?;
        self.read_reply("STP")?;
        Ok(())
    }

    fn lose(&mut self, e: GcsError) -> GcsError {
        if e.link_lost() {
            self.lost = true;
        }
        e
    }

    /// Reads one complete reply (all its lines).
    fn read_reply(&mut self, command: &str) -> R<String> {
        let bytes = self.read_framed(command, protocol::reply_end)?;
        match String::from_utf8(bytes) {
            Ok(s) => Ok(s),
            Err(e) => Err(self.lose(GcsError::Reply {
                link: self.link.describe(),
                command: command.to_string(),
                reply: String::from_utf8_lossy(e.as_bytes()).into_owned(),
                reason: "not text",
            })),
        }
    }

    /// Reads until `end` finds a complete answer in what arrived (the index past it),
    /// within the timeout; returns the answer's bytes, keeping what follows.
    fn read_framed(&mut self, command: &str, end: fn(&[u8]) -> Option<usize>) -> R<Vec<u8>> {
        let start = Instant::now();
        loop {
            if let Some(k) = end(&self.buf) {
                return Ok(self.buf.drain(..k).collect());
            }
            if self.buf.len() > 1 << 16 {
                let reply = String::from_utf8_lossy(&self.buf[..64]).into_owned();
                return Err(self.lose(GcsError::Reply {
                    link: self.link.describe(),
                    command: command.to_string(),
                    reply,
                    reason: "more than 64 KiB without an end of reply",
                }));
            }
            if start.elapsed() >= self.timeout {
                return Err(self.lose(GcsError::Timeout {
                    link: self.link.describe(),
                    command: command.to_string(),
                    seconds: self.timeout.as_secs_f64(),
                }));
            }
            let mut chunk = [0u8; 512];
            match self.link.receive(&mut chunk) {
                Ok(0) => {
                    return Err(self.lose(GcsError::Link {
                        link: self.link.describe(),
                        message: format!("the controller closed the connection (waiting for the reply to `{command}`)"),
                    }));
                }
                Ok(n) => self.buf.extend_from_slice(&chunk[..n]),
                Err(e) if crate::link::is_wait(&e) => {}
                Err(e) => return Err(self.lose(self.link_error(&e))),
            }
        }
    }

    fn code_of(&mut self, command: &str, reply: &str) -> R<Option<ControllerError>> {
        let lines = protocol::reply_lines(reply);
        match (
            lines.as_slice(),
            lines.first().map(|l| l.trim().parse::<i32>()),
        ) {
            ([_], Some(Ok(code))) => Ok(ControllerError::from_code(code)),
            _ => Err(self.lose(GcsError::Reply {
                link: self.link.describe(),
                command: command.to_string(),
                reply: reply.to_string(),
                reason: "`ERR?` answers one integer",
            })),
        }
    }

    /// Sends a set command line and reads back `ERR?` (`expected` codes are not errors:
    /// 10 after a stop).
    fn set(&mut self, line: &str, expected: &[ControllerError]) -> R<()> {
        self.recover()?;
        let command = line.trim_end().to_string();
        let mut out = String::with_capacity(line.len() + 5);
        out.push_str(line);
        out.push_str("ERR?\n");
        self.link
            .send(out.as_bytes())
            .map_err(|e| self.lose(self.link_error(&e)))?;
        let reply = self.read_reply(&command)?;
        match self.code_of(&command, &reply)? {
            Some(e) if !expected.contains(&e) => Err(GcsError::Controller {
                link: self.link.describe(),
                command,
                error: e,
            }),
            _ => Ok(()),
        }
    }

    /// Sends a query line and returns its reply lines. A query the controller does not
    /// answer is explained by `ERR?` when the link still works.
    fn query(&mut self, line: &str) -> R<Vec<String>> {
        self.recover()?;
        let command = line.trim_end().to_string();
        self.link
            .send(line.as_bytes())
            .map_err(|e| self.lose(self.link_error(&e)))?;
        match self.read_reply(&command) {
            Ok(reply) => Ok(protocol::reply_lines(&reply)
                .into_iter()
                .map(str::to_string)
                .collect()),
            Err(e @ GcsError::Timeout { .. }) => {
                // Unanswered: a controller does not answer a query it refuses; ask
                // why on the same link. Anything but one error code: the link is lost.
                self.lost = false;
                if self.link.send(b"ERR?\n").is_ok()
                    && let Ok(r) = self.read_reply("ERR?")
                    && let Ok(Some(err)) = self.code_of("ERR?", &r)
                {
                    return Err(GcsError::Controller {
                        link: self.link.describe(),
                        command,
                        error: err,
                    });
                }
                self.lost = true;
                Err(e)
            }
            Err(e) => Err(e),
        }
    }

    fn check_axes(&self, axes: &[&str]) -> R<()> {
        for a in axes {
            if !self.axes.iter().any(|x| x == a) {
                return Err(self.invalid(format!(
                    "axis `{a}` is not one of the controller's axes {:?}",
                    self.axes
                )));
            }
        }
        Ok(())
    }

    fn check_pairs(&self, pairs: &[(&str, f64)]) -> R<()> {
        for (a, v) in pairs {
            self.check_axes(&[a])?;
            if !v.is_finite() {
                return Err(self.invalid(format!("axis `{a}`: {v} is not a finite number")));
            }
        }
        Ok(())
    }

    /// Parses `axis=value` replies for `axes` (all axes when empty), in order.
    fn values<T>(
        &mut self,
        name: &str,
        axes: &[&str],
        parse: impl Fn(&str) -> Option<T>,
    ) -> R<Vec<T>> {
        self.check_axes(axes)?;
        let lines = self.query(&protocol::query_line(name, axes))?;
        let refs: Vec<&str> = lines.iter().map(String::as_str).collect();
        let bad = |reply: String, reason| GcsError::Reply {
            link: self.link.describe(),
            command: name.to_string(),
            reply,
            reason,
        };
        let pairs = match protocol::parse_pairs(&refs) {
            Ok(p) => p,
            Err(b) => return Err(self.lose(bad(b.line, b.reason))),
        };
        let want: Vec<String> = if axes.is_empty() {
            self.axes.clone()
        } else {
            axes.iter().map(|a| a.to_string()).collect()
        };
        if pairs.len() != want.len() || pairs.iter().zip(&want).any(|((a, _), w)| a != w) {
            return Err(self.lose(bad(
                lines.join(" | "),
                "the axes of the reply are not those asked for",
            )));
        }
        let mut out = Vec::with_capacity(pairs.len());
        for (_, v) in pairs {
            match parse(&v) {
                Some(x) => out.push(x),
                None => return Err(self.lose(bad(v, "not a value of this query"))),
            }
        }
        Ok(out)
    }

    fn single_line(&mut self, name: &str) -> R<String> {
        let lines = self.query(&format!("{name}\n"))?;
        Ok(lines.join("\n"))
    }

    /// `*IDN?`: vendor, model, serial number, firmware.
    pub fn identify(&mut self) -> R<String> {
        self.single_line("*IDN?")
    }

    /// `CSV?`: the GCS syntax version (`2.0`).
    pub fn syntax_version(&mut self) -> R<String> {
        self.single_line("CSV?")
    }

    fn axes_query(&mut self) -> R<Vec<String>> {
        let lines = self.query("SAI?\n")?;
        let axes: Vec<String> = lines.iter().map(|l| l.trim().to_string()).collect();
        if axes.is_empty() || axes.iter().any(|a| !protocol::is_axis_id(a)) {
            return Err(self.lose(GcsError::Reply {
                link: self.link.describe(),
                command: "SAI?".into(),
                reply: lines.join(" | "),
                reason: "`SAI?` answers one axis identifier per line",
            }));
        }
        Ok(axes)
    }

    /// `SAI?`: the axis identifiers (asked again).
    pub fn axes(&mut self) -> R<Vec<String>> {
        let a = self.axes_query()?;
        self.axes = a.clone();
        Ok(a)
    }

    /// `ERR?`: the sticky error, cleared by reading it.
    pub fn error(&mut self) -> R<Option<ControllerError>> {
        let r = self.query("ERR?\n")?;
        self.code_of("ERR?", &(r.join(" \n") + "\n"))
    }

    /// `SVO`: servo on or off per axis.
    pub fn set_servo(&mut self, axes: &[(&str, bool)]) -> R<()> {
        let pairs: Vec<(&str, f64)> = axes
            .iter()
            .map(|(a, on)| (*a, f64::from(u8::from(*on))))
            .collect();
        self.check_pairs(&pairs)?;
        self.set(&protocol::command_line("SVO", &pairs), &[])
    }

    /// `SVO?`.
    pub fn servo(&mut self, axes: &[&str]) -> R<Vec<bool>> {
        self.values("SVO?", axes, protocol::parse_bool)
    }

    /// `MOV`: absolute targets (µm of stack extension on the emulator).
    pub fn move_to(&mut self, targets: &[(&str, f64)]) -> R<()> {
        self.check_pairs(targets)?;
        self.set(&protocol::command_line("MOV", targets), &[])
    }

    /// `MOV?`: the targets.
    pub fn target(&mut self, axes: &[&str]) -> R<Vec<f64>> {
        self.values("MOV?", axes, protocol::parse_number)
    }

    /// `MVR`: relative moves.
    pub fn move_by(&mut self, steps: &[(&str, f64)]) -> R<()> {
        self.check_pairs(steps)?;
        self.set(&protocol::command_line("MVR", steps), &[])
    }

    /// `POS?`: the sensors' positions.
    pub fn position(&mut self, axes: &[&str]) -> R<Vec<f64>> {
        self.values("POS?", axes, protocol::parse_number)
    }

    /// `ONT?`: on target.
    pub fn on_target(&mut self, axes: &[&str]) -> R<Vec<bool>> {
        self.values("ONT?", axes, protocol::parse_bool)
    }

    /// `VEL`: closed-loop velocities.
    pub fn set_velocity(&mut self, axes: &[(&str, f64)]) -> R<()> {
        self.check_pairs(axes)?;
        self.set(&protocol::command_line("VEL", axes), &[])
    }

    /// `VEL?`.
    pub fn velocity(&mut self, axes: &[&str]) -> R<Vec<f64>> {
        self.values("VEL?", axes, protocol::parse_number)
    }

    /// `TMN?`: lowest targets.
    pub fn min_travel(&mut self, axes: &[&str]) -> R<Vec<f64>> {
        self.values("TMN?", axes, protocol::parse_number)
    }

    /// `TMX?`: highest targets.
    pub fn max_travel(&mut self, axes: &[&str]) -> R<Vec<f64>> {
        self.values("TMX?", axes, protocol::parse_number)
    }

    /// `SVA`: open-loop voltages.
    pub fn set_voltage(&mut self, axes: &[(&str, f64)]) -> R<()> {
        self.check_pairs(axes)?;
        self.set(&protocol::command_line("SVA", axes), &[])
    }

    /// `SVA?`: the commanded open-loop voltages.
    pub fn voltage_command(&mut self, axes: &[&str]) -> R<Vec<f64>> {
        self.values("SVA?", axes, protocol::parse_number)
    }

    /// `VOL?`: the amplifiers' output voltages.
    pub fn output_voltage(&mut self, axes: &[&str]) -> R<Vec<f64>> {
        self.values("VOL?", axes, protocol::parse_number)
    }

    /// `HLT`: halts axes smoothly (the controller raises error 10, read and accepted).
    pub fn halt(&mut self, axes: &[&str]) -> R<()> {
        self.check_axes(axes)?;
        let mut line = protocol::query_line("HLT", axes);
        if axes.is_empty() {
            line = "HLT\n".into();
        }
        self.set(&line, &[ControllerError::Stopped])
    }

    /// `STP`: stops all axes at once (error 10, read and accepted).
    pub fn stop(&mut self) -> R<()> {
        self.set("STP\n", &[ControllerError::Stopped])
    }

    /// `#5`: which axes move (bit k: the k-th axis of `SAI?`).
    pub fn moving_mask(&mut self) -> R<u32> {
        self.recover()?;
        self.link
            .send(&[protocol::MOVING])
            .map_err(|e| self.lose(self.link_error(&e)))?;
        let r = self.read_reply("#5")?;
        match protocol::parse_mask(r.trim_end()) {
            Some(m) => Ok(m),
            None => Err(self.lose(GcsError::Reply {
                link: self.link.describe(),
                command: "#5".into(),
                reply: r,
                reason: "`#5` answers a hexadecimal mask",
            })),
        }
    }

    /// `#7`: whether the controller is ready.
    pub fn ready(&mut self) -> R<bool> {
        self.recover()?;
        self.link
            .send(&[protocol::READY])
            .map_err(|e| self.lose(self.link_error(&e)))?;
        let line = self.read_framed("#7", |b| b.iter().position(|&c| c == b'\n').map(|k| k + 1))?;
        match line.as_slice() {
            [protocol::READY_BYTE, b'\n'] => Ok(true),
            [protocol::BUSY_BYTE, b'\n'] => Ok(false),
            _ => Err(self.lose(GcsError::Reply {
                link: self.link.describe(),
                command: "#7".into(),
                reply: format!("{line:02X?}"),
                reason: "`#7` answers the byte 0xB1 or 0xB0 and LF",
            })),
        }
    }

    /// `#24`: stops every axis at once (then reads and accepts error 10).
    pub fn stop_all(&mut self) -> R<()> {
        self.recover()?;
        self.link
            .send(&[protocol::STOP_ALL, b'E', b'R', b'R', b'?', b'\n'])
            .map_err(|e| self.lose(self.link_error(&e)))?;
        let r = self.read_reply("#24")?;
        match self.code_of("#24", &r)? {
            None | Some(ControllerError::Stopped) => Ok(()),
            Some(e) => Err(GcsError::Controller {
                link: self.link.describe(),
                command: "#24".into(),
                error: e,
            }),
        }
    }

    /// Sends any command line (for tools and tests): a set command when `name` has no
    /// `?` (its `ERR?` read back), else a query whose reply lines are returned.
    pub fn raw(&mut self, line: &str) -> R<Vec<String>> {
        let word = line.split_whitespace().next().unwrap_or("");
        if !protocol::is_command_word(word) || line.contains('\n') {
            return Err(self.invalid(format!("`{line}` is not one command line")));
        }
        let full = format!("{line}\n");
        if word.ends_with('?') {
            self.query(&full)
        } else {
            self.set(&full, &[]).map(|()| Vec::new())
        }
    }
}
