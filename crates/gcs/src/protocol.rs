//! GCS 2.0 framing, as PI documents it, with no IO: a command line ends with LF, its
//! arguments are space-separated axis/value pairs, a reply line reads `axis=value`, and
//! every line of a multi-line reply but the last ends in space + LF. Single-byte
//! commands (`#5`, `#7`, `#24`) carry no LF.

use std::fmt::Write as _;

/// `#5`: the moving mask (hexadecimal, bit k = axis k+1 moving).
pub const MOVING: u8 = 5;
/// `#7`: controller ready (answers the byte 0xB1 when ready, 0xB0 when busy, then LF).
pub const READY: u8 = 7;
/// `#24`: stop all axes (sets error 10).
pub const STOP_ALL: u8 = 24;
/// The answer of `#7` when the controller is ready.
pub const READY_BYTE: u8 = 0xB1;
/// The answer of `#7` when the controller is busy.
pub const BUSY_BYTE: u8 = 0xB0;

/// A controller error code as `ERR?` reports it (PI's numbering).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ControllerError {
    /// 1: parameter syntax error.
    ParameterSyntax,
    /// 2: unknown command.
    UnknownCommand,
    /// 5: move commanded with the servo off.
    ServoOff,
    /// 7: position out of limits.
    PositionOutOfLimits,
    /// 10: motion stopped by `#24`, `HLT` or `STP`.
    Stopped,
    /// 15: invalid axis identifier.
    InvalidAxis,
    /// 17: parameter out of range.
    ParameterOutOfRange,
    /// Any other code.
    Other(i32),
}

impl ControllerError {
    /// The error of code `code` (`None` for 0, no error).
    pub fn from_code(code: i32) -> Option<Self> {
        Some(match code {
            0 => return None,
            1 => Self::ParameterSyntax,
            2 => Self::UnknownCommand,
            5 => Self::ServoOff,
            7 => Self::PositionOutOfLimits,
            10 => Self::Stopped,
            15 => Self::InvalidAxis,
            17 => Self::ParameterOutOfRange,
            c => Self::Other(c),
        })
    }

    /// PI's code.
    pub fn code(self) -> i32 {
        match self {
            Self::ParameterSyntax => 1,
            Self::UnknownCommand => 2,
            Self::ServoOff => 5,
            Self::PositionOutOfLimits => 7,
            Self::Stopped => 10,
            Self::InvalidAxis => 15,
            Self::ParameterOutOfRange => 17,
            Self::Other(c) => c,
        }
    }

    /// What the code means.
    pub fn meaning(self) -> &'static str {
        match self {
            Self::ParameterSyntax => "parameter syntax error",
            Self::UnknownCommand => "unknown command",
            Self::ServoOff => "move commanded with the servo off",
            Self::PositionOutOfLimits => "position out of limits",
            Self::Stopped => "motion stopped (#24, HLT or STP)",
            Self::InvalidAxis => "invalid axis identifier",
            Self::ParameterOutOfRange => "parameter out of range",
            Self::Other(_) => "controller error",
        }
    }
}

impl std::fmt::Display for ControllerError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "GCS error {} ({})", self.code(), self.meaning())
    }
}

/// Whether `name` may be sent as a command word: printable ASCII without spaces.
pub fn is_command_word(name: &str) -> bool {
    !name.is_empty() && name.bytes().all(|b| b.is_ascii_graphic())
}

/// Whether `axis` is a valid axis identifier (printable ASCII, no space, no `=`).
pub fn is_axis_id(axis: &str) -> bool {
    !axis.is_empty() && axis.bytes().all(|b| b.is_ascii_graphic() && b != b'=')
}

/// One command line: `NAME axis value axis value ...` + LF. Values print with enough
/// digits to round-trip an `f64`.
pub fn command_line(name: &str, pairs: &[(&str, f64)]) -> String {
    let mut s = String::with_capacity(16 + 24 * pairs.len());
    s.push_str(name);
    for (axis, v) in pairs {
        let _ = write!(s, " {axis} {v}");
    }
    s.push('\n');
    s
}

/// A query line: `NAME? axis axis ...` + LF (`name` includes the `?`).
pub fn query_line(name: &str, axes: &[&str]) -> String {
    let mut s = String::from(name);
    for a in axes {
        s.push(' ');
        s.push_str(a);
    }
    s.push('\n');
    s
}

/// Where a complete reply ends in `buf`: the index just past the LF of the first line
/// that is not followed by more lines (its LF not preceded by a space). `None` while
/// the reply is incomplete.
pub fn reply_end(buf: &[u8]) -> Option<usize> {
    let mut i = 0;
    while let Some(k) = buf[i..].iter().position(|&b| b == b'\n') {
        let lf = i + k;
        if lf == 0 || buf[lf - 1] != b' ' {
            return Some(lf + 1);
        }
        i = lf + 1;
    }
    None
}

/// The lines of a complete reply, without their terminators (the continuation space
/// and the LF).
pub fn reply_lines(reply: &str) -> Vec<&str> {
    let body = reply.strip_suffix('\n').unwrap_or(reply);
    body.split('\n')
        .map(|l| l.strip_suffix(' ').unwrap_or(l).trim_end_matches('\r'))
        .collect()
}

/// Why a reply could not be read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BadReply {
    /// The offending line.
    pub line: String,
    /// What is wrong with it.
    pub reason: &'static str,
}

/// Parses `axis=value` lines into pairs, in order.
pub fn parse_pairs(lines: &[&str]) -> Result<Vec<(String, String)>, BadReply> {
    lines
        .iter()
        .map(|l| {
            let (a, v) = l.split_once('=').ok_or_else(|| BadReply {
                line: (*l).to_string(),
                reason: "expected `axis=value`",
            })?;
            if !is_axis_id(a.trim()) {
                return Err(BadReply {
                    line: (*l).to_string(),
                    reason: "the axis identifier is empty or not printable",
                });
            }
            Ok((a.trim().to_string(), v.trim().to_string()))
        })
        .collect()
}

/// Parses a GCS number (decimal, optionally signed and with an exponent).
pub fn parse_number(s: &str) -> Option<f64> {
    let s = s.trim();
    if s.is_empty()
        || !s
            .bytes()
            .all(|b| b.is_ascii_digit() || matches!(b, b'+' | b'-' | b'.' | b'e' | b'E'))
    {
        return None;
    }
    s.parse::<f64>().ok().filter(|v| v.is_finite())
}

/// Parses a GCS boolean (`0` or `1`).
pub fn parse_bool(s: &str) -> Option<bool> {
    match s.trim() {
        "0" => Some(false),
        "1" => Some(true),
        _ => None,
    }
}

/// Parses the hexadecimal moving mask of `#5` (with or without `0x`).
pub fn parse_mask(s: &str) -> Option<u32> {
    let s = s.trim();
    let digits = s
        .strip_prefix("0x")
        .or_else(|| s.strip_prefix("0X"))
        .unwrap_or(s);
    if digits.is_empty() || digits.len() > 8 {
        return None;
    }
    u32::from_str_radix(digits, 16).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reply_ends_at_the_first_line_without_continuation() {
        assert_eq!(reply_end(b"1=2.5 \n2=3"), None);
        assert_eq!(reply_end(b"1=2.5 \n2=3\n"), Some(11));
        assert_eq!(reply_end(b"0\n1=0\n"), Some(2));
        assert_eq!(reply_end(b"\n"), Some(1));
        assert_eq!(reply_lines("1=2.5 \n2=3\n"), vec!["1=2.5", "2=3"]);
    }

    #[test]
    fn commands_and_numbers_round_trip() {
        let line = command_line("MOV", &[("1", 0.1 + 0.2), ("3", -1e-7)]);
        assert_eq!(line, "MOV 1 0.30000000000000004 3 -0.0000001\n");
        let words: Vec<&str> = line.split_whitespace().collect();
        assert_eq!(parse_number(words[2]), Some(0.1 + 0.2));
        assert_eq!(parse_number("1e-3"), Some(1e-3));
        assert_eq!(parse_number("nan"), None);
        assert_eq!(parse_number("inf"), None);
        assert_eq!(parse_number(""), None);
        assert_eq!(query_line("POS?", &["1", "2"]), "POS? 1 2\n");
    }

    #[test]
    fn pairs_masks_and_codes_parse() {
        assert_eq!(
            parse_pairs(&["1=0.5", "2 = 1"]).unwrap(),
            vec![("1".into(), "0.5".into()), ("2".into(), "1".into())]
        );
        assert!(parse_pairs(&["garbage"]).is_err());
        assert_eq!(parse_mask("5"), Some(5));
        assert_eq!(parse_mask("0x7"), Some(7));
        assert_eq!(parse_mask("zz"), None);
        for code in [1, 2, 5, 7, 10, 15, 17, 99] {
            assert_eq!(ControllerError::from_code(code).unwrap().code(), code);
        }
        assert_eq!(ControllerError::from_code(0), None);
    }
}
