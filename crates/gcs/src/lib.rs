//! # cellinject-gcs
//!
//! A driver for piezo controllers that speak PI's GCS 2.0 (ASCII commands over TCP,
//! port 50000 by default, or a serial line): the framing ([`protocol`]), the
//! transports ([`link`]), the typed command set with sticky errors read back by
//! `ERR?` after every set command ([`Gcs`]), and the controller's axes behind
//! cellinject's hardware traits ([`devices`]).
//!
//! **Architecture invariant:** this crate never depends on the twin (it is tested
//! against `cellinject-gcs-emulator`, which does): it knows GCS and the hardware traits,
//! nothing of the mechanism.
//!
//! **Architecture invariant:** a command leaves in one write, whole, with its `ERR?`;
//! after a timeout, a broken link or a reply the protocol does not allow, nothing else
//! is sent before the link was re-established and `STP` stopped the axes.

pub mod controller;
pub mod devices;
pub mod link;
pub mod protocol;

pub use controller::{Gcs, GcsError};
pub use protocol::ControllerError;

/// Where a backend lives, parsed from `--backend`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Endpoint {
    /// `gcs://HOST:PORT` (PORT defaults to 50000).
    Tcp(String),
    /// `gcs-serial:///dev/ttyX[?baud=N]` (115200 baud by default).
    Serial {
        /// Device path.
        path: String,
        /// Baud rate.
        baud: u32,
    },
}

impl Endpoint {
    /// Parses `gcs://HOST[:PORT]` or `gcs-serial://PATH[?baud=N]`.
    pub fn parse(s: &str) -> Result<Self, String> {
        if let Some(rest) = s.strip_prefix("gcs://") {
            let rest = rest.trim_end_matches('/');
            if rest.is_empty() {
                return Err(format!("`{s}`: gcs://HOST:PORT needs a host"));
            }
            let has_port = rest.rsplit_once(':').is_some_and(|(h, p)| {
                !h.ends_with(':') && !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit())
            });
            if has_port {
                let port = rest.rsplit_once(':').map(|(_, p)| p).unwrap_or("");
                if port.parse::<u16>().is_err() {
                    return Err(format!("`{s}`: port `{port}` is not in 0..65535"));
                }
                Ok(Endpoint::Tcp(rest.to_string()))
            } else if rest.contains(':') && !rest.starts_with('[') {
                Err(format!(
                    "`{s}`: the port must be a number (gcs://HOST:PORT)"
                ))
            } else {
                Ok(Endpoint::Tcp(format!("{rest}:50000")))
            }
        } else if let Some(rest) = s.strip_prefix("gcs-serial://") {
            let (path, query) = rest.split_once('?').unwrap_or((rest, ""));
            if path.is_empty() {
                return Err(format!("`{s}`: gcs-serial://PATH needs a device path"));
            }
            let mut baud = 115_200;
            if !query.is_empty() {
                let v = query
                    .strip_prefix("baud=")
                    .ok_or_else(|| format!("`{s}`: the only option is ?baud=N"))?;
                baud = v
                    .parse()
                    .ok()
                    .filter(|b| *b > 0)
                    .ok_or_else(|| format!("`{s}`: baud `{v}` is not a positive integer"))?;
            }
            Ok(Endpoint::Serial {
                path: path.to_string(),
                baud,
            })
        } else {
            Err(format!(
                "`{s}` is not a backend: use twin, gcs://HOST:PORT or gcs-serial:///dev/ttyX"
            ))
        }
    }

    /// Opens the controller.
    pub fn open(&self, timeout: std::time::Duration) -> Result<Gcs, GcsError> {
        match self {
            Endpoint::Tcp(a) => Gcs::tcp(a, timeout),
            #[cfg(feature = "serial")]
            Endpoint::Serial { path, baud } => Gcs::serial(path, *baud, timeout),
            #[cfg(not(feature = "serial"))]
            Endpoint::Serial { path, .. } => Err(GcsError::Invalid {
                link: format!("gcs-serial://{path}"),
                reason: "built without the `serial` feature".into(),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoints_parse_and_bad_ones_say_why() {
        assert_eq!(
            Endpoint::parse("gcs://127.0.0.1:5000"),
            Ok(Endpoint::Tcp("127.0.0.1:5000".into()))
        );
        assert_eq!(
            Endpoint::parse("gcs://lab-e727"),
            Ok(Endpoint::Tcp("lab-e727:50000".into()))
        );
        assert_eq!(
            Endpoint::parse("gcs-serial:///dev/ttyUSB0?baud=57600"),
            Ok(Endpoint::Serial {
                path: "/dev/ttyUSB0".into(),
                baud: 57600
            })
        );
        for bad in [
            "gcs://",
            "gcs://h:99999",
            "gcs://h:x",
            "tcp://h:1",
            "gcs-serial://",
            "gcs-serial:///dev/x?baud=0",
        ] {
            assert!(Endpoint::parse(bad).is_err(), "{bad}");
        }
    }
}
