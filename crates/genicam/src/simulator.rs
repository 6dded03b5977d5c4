//! Aravis's GigE Vision camera simulator, `arv-fake-gv-camera-0.8` (Debian's
//! `aravis-tools`), run on 127.0.0.1: a camera that speaks the real protocol (discovery,
//! control, streaming) to try the whole path without hardware, as the tests do.

use std::process::{Child, Command, Stdio};
use std::time::Duration;

use crate::GenicamError;

/// The simulator's program.
pub const PROGRAM: &str = "arv-fake-gv-camera-0.8";

/// GigE Vision's control port, which one simulator on 127.0.0.1 holds.
const GVCP: &str = "127.0.0.1:3956";

/// A running `arv-fake-gv-camera-0.8 -i 127.0.0.1 -s SERIAL`, stopped when dropped.
#[derive(Debug)]
pub struct GvSimulator {
    child: Child,
    serial: String,
}

impl GvSimulator {
    /// Starts the simulator with the serial number `serial`, and gives it half a second
    /// to answer discovery. Refused when 127.0.0.1:3956 is already taken (another
    /// simulator there would answer in its place) or the program is not installed.
    pub fn start(serial: &str) -> Result<GvSimulator, GenicamError> {
        let err = |message: String| GenicamError::Device {
            id: format!("{PROGRAM} on {GVCP}"),
            message,
        };
        // Binding the port, and letting it go at once, is how to know it is free.
        if let Err(e) = std::net::UdpSocket::bind(GVCP) {
            return Err(err(format!(
                "the GigE Vision control port is taken ({e}): stop the simulator already \
                 running there (pkill -f arv-fake-gv-camera)"
            )));
        }
        let child = Command::new(PROGRAM)
            .args(["-i", "127.0.0.1", "-s", serial])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|e| err(format!("{e} (install Debian's aravis-tools)")))?;
        std::thread::sleep(Duration::from_millis(500));
        Ok(GvSimulator {
            child,
            serial: serial.to_owned(),
        })
    }

    /// The id Aravis knows it by (`Aravis-SERIAL`).
    pub fn id(&self) -> String {
        format!("Aravis-{}", self.serial)
    }

    /// Kills the simulator at once, as a camera unplugged mid-stream.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for GvSimulator {
    fn drop(&mut self) {
        self.kill();
    }
}
