//! SMCP1 framing: the 16-byte header and the typed sub-blocks that follow it, as
//! Sensapex's open SDK defines them (`inc/smcp1.h` of umsdk, v1.504).
//!
//! Every field is big-endian (network byte order). A frame is
//!
//! ```text
//! u8 version (0x10)  u8 extra  u16 receiver id
//! u16 sender id      u16 message id
//! u32 options (REQ, ACK, NOTIFY, ERROR, REQ_ACK, REQ_RESP, REQ_NOTIFY ...)
//! u16 type (the command)       u16 sub-block count
//! then each sub-block: u16 data type, u16 element count, the elements, each
//! sub-block padded with zeros to a multiple of 4 bytes.
//! ```
//!
//! Pure: no IO. [`Frame::encode`] and [`Frame::decode`] are each other's inverse
//! (property-tested).

use thiserror::Error;

/// Protocol version byte of SMCP1.
pub const VERSION: u8 = 0x10;
/// Header size in bytes.
pub const HEADER: usize = 16;
/// The largest datagram either side sends or accepts.
pub const MAX_DATAGRAM: usize = 1500;
/// UDP port of group 0; group `g` uses `PORT + g`.
pub const PORT: u16 = 55555;
/// The link-local broadcast address devices listen on by default.
pub const BROADCAST: &str = "169.254.255.255";
/// An argument left undefined (an axis a goto does not move).
pub const ARG_UNDEF: i32 = i32::MAX;
/// Receiver id addressing every device.
pub const ALL_DEVICES: u16 = 0x00ff;

/// Option bits of the header.
pub mod opt {
    /// The frame is a request (else a response).
    pub const REQ: u32 = 0x01;
    /// The frame is an acknowledgement.
    pub const ACK: u32 = 0x02;
    /// The frame is a notification.
    pub const NOTIFY: u32 = 0x04;
    /// The request failed (on an ACK or a response).
    pub const ERROR: u32 = 0x08;
    /// The sender asks for an ACK.
    pub const REQ_ACK: u32 = 0x10;
    /// The sender asks for a response.
    pub const REQ_RESP: u32 = 0x20;
    /// The sender asks for a notification when the operation completes.
    pub const REQ_NOTIFY: u32 = 0x40;
    /// The sender asks for the answer by broadcast.
    pub const REQ_BCAST: u32 = 0x80;
}

/// Command (frame type) numbers used here.
pub mod cmd {
    /// Ping: the response echoes the request.
    pub const PING: u16 = 0;
    /// Stop every axis.
    pub const STOP: u16 = 1;
    /// Read one parameter.
    pub const GET_PARAMETER: u16 = 16;
    /// Set one parameter.
    pub const SET_PARAMETER: u16 = 15;
    /// Positions now (nm), synchronously.
    pub const GET_POSITIONS: u16 = 14;
    /// Firmware version, as UINT32 parts.
    pub const GET_VERSION: u16 = 23;
    /// Drive to a position (nm), speed (µm/s), mode, acceleration.
    pub const GOTO_POS: u16 = 33;
    /// Step by nm from the current position.
    pub const TAKE_STEP: u16 = 34;
    /// Error state (UINT32).
    pub const READ_ERROR_STATE: u16 = 41;
    /// Clears the error state.
    pub const CLEAR_ERROR_STATE: u16 = 42;
    /// uMs: the lens changer's position.
    pub const UMS_GET_LENS_POSITION: u16 = 63;
    /// uMs: moves the lens changer.
    pub const UMS_SET_LENS_POSITION: u16 = 64;
    /// uMv: pressure set point of a channel.
    pub const UMV_SET_PRESSURE: u16 = 88;
    /// uMv: the set point of a channel.
    pub const UMV_GET_PRESSURE: u16 = 89;
    /// uMv: opens or closes a channel's valve.
    pub const UMV_SET_VALVE: u16 = 92;
    /// uMv: a valve's state.
    pub const UMV_GET_VALVE: u16 = 93;
    /// uMv: the pressure a channel's sensor measures.
    pub const UMV_MEASURE_PRESSURE: u16 = 94;
    /// A device announces itself.
    pub const NOTIFY_HELLO: u16 = 100;
    /// Positions changed (nm).
    pub const NOTIFY_POSITION_CHANGED: u16 = 101;
    /// Status changed (bits of [`super::status`]).
    pub const NOTIFY_STATUS_CHANGED: u16 = 102;
    /// A goto completed (or failed, with ERROR).
    pub const NOTIFY_GOTO_POS_COMPLETED: u16 = 104;
}

/// Status bits (STATUS_CHANGED, the drive status).
pub mod status {
    /// Idle.
    pub const IDLE: u32 = 0;
    /// Processing (not necessarily moving).
    pub const BUSY: u32 = 0x01;
    /// In an error state.
    pub const ERROR: u32 = 0x08;
    /// X moving; Y, Z and W are the next bits.
    pub const X_MOVING: u32 = 0x10;
}

/// Parameter ids used here.
pub mod param {
    /// Memory drive speed.
    pub const MEM_SPEED: u16 = 2;
    /// Device id.
    pub const DEV_ID: u16 = 3;
    /// Hardware id.
    pub const HW_ID: u16 = 0x101;
    /// Serial number.
    pub const SN: u16 = 0x102;
    /// Number of axes.
    pub const AXIS_COUNT: u16 = 0x105;
}

/// The data type of a sub-block (`smcp1_data_type`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DataType {
    /// No data.
    Void,
    /// u8.
    U8,
    /// i8.
    I8,
    /// u16.
    U16,
    /// i16.
    I16,
    /// u32.
    U32,
    /// i32.
    I32,
    /// u64.
    U64,
    /// i64.
    I64,
    /// UTF-8 text, bytes.
    Text,
}

impl DataType {
    /// The code on the wire.
    pub fn code(self) -> u16 {
        self as u16
    }

    /// The type of a wire code.
    pub fn from_code(code: u16) -> Option<Self> {
        use DataType::*;
        Some(match code {
            0 => Void,
            1 => U8,
            2 => I8,
            3 => U16,
            4 => I16,
            5 => U32,
            6 => I32,
            7 => U64,
            8 => I64,
            9 => Text,
            _ => return None,
        })
    }

    /// Bytes per element.
    pub fn width(self) -> usize {
        use DataType::*;
        match self {
            Void => 0,
            U8 | I8 | Text => 1,
            U16 | I16 => 2,
            U32 | I32 => 4,
            U64 | I64 => 8,
        }
    }

    fn signed(self) -> bool {
        matches!(
            self,
            DataType::I8 | DataType::I16 | DataType::I32 | DataType::I64
        )
    }
}

/// One sub-block: its type and its elements (integers widened to i64; text as
/// its bytes, one element each).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SubBlock {
    /// Data type.
    pub data_type: DataType,
    /// Elements.
    pub values: Vec<i64>,
}

impl SubBlock {
    /// INT32 elements.
    pub fn i32s(values: &[i32]) -> Self {
        SubBlock {
            data_type: DataType::I32,
            values: values.iter().map(|&v| i64::from(v)).collect(),
        }
    }

    /// UINT32 elements.
    pub fn u32s(values: &[u32]) -> Self {
        SubBlock {
            data_type: DataType::U32,
            values: values.iter().map(|&v| i64::from(v)).collect(),
        }
    }

    /// Text (UTF-8).
    pub fn text(s: &str) -> Self {
        SubBlock {
            data_type: DataType::Text,
            values: s.bytes().map(i64::from).collect(),
        }
    }

    /// Bytes on the wire: the 4-byte header and the elements, padded to 4 bytes.
    fn wire_len(&self) -> usize {
        4 + (self.values.len() * self.data_type.width()).next_multiple_of(4)
    }
}

/// One SMCP1 frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    /// Reserved byte (0).
    pub extra: u8,
    /// Receiver id.
    pub receiver: u16,
    /// Sender id.
    pub sender: u16,
    /// Message id (a counter of the sender's).
    pub message_id: u16,
    /// Option bits ([`opt`]).
    pub options: u32,
    /// Command ([`cmd`]).
    pub kind: u16,
    /// Sub-blocks.
    pub blocks: Vec<SubBlock>,
}

/// A datagram that is not an SMCP1 frame.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum FrameError {
    /// Shorter than the header.
    #[error("{len} bytes: shorter than the 16-byte SMCP1 header")]
    Short {
        /// Bytes received.
        len: usize,
    },
    /// Another protocol version.
    #[error("version byte 0x{found:02x}, SMCP1 is 0x10")]
    Version {
        /// The byte found.
        found: u8,
    },
    /// Unknown data type.
    #[error("sub-block {index}: unknown data type {code}")]
    DataType {
        /// Which sub-block.
        index: usize,
        /// The code found.
        code: u16,
    },
    /// The sub-blocks run past the datagram.
    #[error("sub-block {index} runs past the end of the {len}-byte datagram")]
    Truncated {
        /// Which sub-block.
        index: usize,
        /// Datagram length.
        len: usize,
    },
    /// Bytes left after the last sub-block.
    #[error("{extra} bytes after the last of {blocks} sub-blocks")]
    Trailing {
        /// Extra bytes.
        extra: usize,
        /// Sub-blocks declared.
        blocks: usize,
    },
}

impl Frame {
    /// A request of `kind` from `sender` to `receiver` with `options` and the
    /// INT32 arguments `args` (no sub-block when empty).
    pub fn request(
        kind: u16,
        sender: u16,
        receiver: u16,
        message_id: u16,
        options: u32,
        args: &[i32],
    ) -> Self {
        Frame {
            extra: 0,
            receiver,
            sender,
            message_id,
            options: options | opt::REQ,
            kind,
            blocks: if args.is_empty() {
                Vec::new()
            } else {
                vec![SubBlock::i32s(args)]
            },
        }
    }

    /// Whether the frame is a request.
    pub fn is_request(&self) -> bool {
        self.options & opt::REQ != 0
    }

    /// The elements of sub-block `k` as i32 (those that fit), empty if absent.
    pub fn ints(&self, k: usize) -> Vec<i32> {
        self.blocks
            .get(k)
            .map(|b| b.values.iter().map(|&v| v as i32).collect())
            .unwrap_or_default()
    }

    /// Every sub-block's integer elements, in order (the arguments of a command
    /// whose optional arguments may come in separate sub-blocks).
    pub fn all_ints(&self) -> Vec<i32> {
        self.blocks
            .iter()
            .filter(|b| b.data_type != DataType::Text)
            .flat_map(|b| b.values.iter().map(|&v| v as i32))
            .collect()
    }

    /// The frame's bytes.
    pub fn encode(&self) -> Vec<u8> {
        let len = HEADER + self.blocks.iter().map(SubBlock::wire_len).sum::<usize>();
        let mut out = Vec::with_capacity(len);
        out.push(VERSION);
        out.push(self.extra);
        out.extend_from_slice(&self.receiver.to_be_bytes());
        out.extend_from_slice(&self.sender.to_be_bytes());
        out.extend_from_slice(&self.message_id.to_be_bytes());
        out.extend_from_slice(&self.options.to_be_bytes());
        out.extend_from_slice(&self.kind.to_be_bytes());
        out.extend_from_slice(&(self.blocks.len() as u16).to_be_bytes());
        for b in &self.blocks {
            out.extend_from_slice(&b.data_type.code().to_be_bytes());
            out.extend_from_slice(&(b.values.len() as u16).to_be_bytes());
            let start = out.len();
            for &v in &b.values {
                let bytes = v.to_be_bytes();
                out.extend_from_slice(&bytes[8 - b.data_type.width()..]);
            }
            while (out.len() - start) % 4 != 0 {
                out.push(0);
            }
        }
        out
    }

    /// Parses a datagram.
    pub fn decode(bytes: &[u8]) -> Result<Frame, FrameError> {
        if bytes.len() < HEADER {
            return Err(FrameError::Short { len: bytes.len() });
        }
        if bytes[0] != VERSION {
            return Err(FrameError::Version { found: bytes[0] });
        }
        let u16_at = |i: usize| u16::from_be_bytes([bytes[i], bytes[i + 1]]);
        let count = u16_at(14) as usize;
        let mut blocks = Vec::with_capacity(count.min(64));
        let mut at = HEADER;
        for index in 0..count {
            if at + 4 > bytes.len() {
                return Err(FrameError::Truncated {
                    index,
                    len: bytes.len(),
                });
            }
            let code = u16_at(at);
            let n = u16_at(at + 2) as usize;
            let data_type =
                DataType::from_code(code).ok_or(FrameError::DataType { index, code })?;
            let w = data_type.width();
            let body = (n * w).next_multiple_of(4);
            if at + 4 + body > bytes.len() {
                return Err(FrameError::Truncated {
                    index,
                    len: bytes.len(),
                });
            }
            let values = (0..n)
                .map(|k| {
                    let s = &bytes[at + 4 + k * w..at + 4 + (k + 1) * w];
                    let mut v: i64 = 0;
                    for &b in s {
                        v = (v << 8) | i64::from(b);
                    }
                    if data_type.signed() && w < 8 && s[0] & 0x80 != 0 {
                        v -= 1i64 << (8 * w);
                    }
                    v
                })
                .collect();
            blocks.push(SubBlock { data_type, values });
            at += 4 + body;
        }
        if at != bytes.len() {
            return Err(FrameError::Trailing {
                extra: bytes.len() - at,
                blocks: count,
            });
        }
        Ok(Frame {
            extra: bytes[1],
            receiver: u16_at(2),
            sender: u16_at(4),
            message_id: u16_at(6),
            options: u32::from_be_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]),
            kind: u16_at(12),
            blocks,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The header's layout, byte by byte, as `inc/smcp1.h` draws it: a GET_POSITIONS
    /// request from PC 0x0201 to device 1, message 7, asking for a response.
    #[test]
    fn the_header_is_big_endian_in_the_documented_order() {
        let f = Frame::request(cmd::GET_POSITIONS, 0x0201, 1, 7, opt::REQ_RESP, &[]);
        assert_eq!(
            f.encode(),
            [0x10, 0, 0, 1, 0x02, 0x01, 0, 7, 0, 0, 0, 0x21, 0, 14, 0, 0]
        );
        let g = Frame::request(cmd::GOTO_POS, 0x0201, 1, 8, 0, &[-1, 2]);
        let b = g.encode();
        assert_eq!(&b[12..16], &[0, 33, 0, 1]);
        assert_eq!(&b[16..20], &[0, 6, 0, 2], "INT32, two of them");
        assert_eq!(&b[20..28], &[0xff, 0xff, 0xff, 0xff, 0, 0, 0, 2]);
    }

    #[test]
    fn short_odd_and_trailing_datagrams_are_refused_with_their_reason() {
        assert_eq!(Frame::decode(&[0x10; 5]), Err(FrameError::Short { len: 5 }));
        let mut b = Frame::request(cmd::PING, 1, 2, 3, 0, &[5]).encode();
        b[0] = 0x02;
        assert_eq!(Frame::decode(&b), Err(FrameError::Version { found: 2 }));
        let b = Frame::request(cmd::PING, 1, 2, 3, 0, &[5]).encode();
        assert!(matches!(
            Frame::decode(&b[..b.len() - 1]),
            Err(FrameError::Truncated { index: 0, .. })
        ));
        let mut long = b.clone();
        long.extend_from_slice(&[0, 0, 0, 0]);
        assert_eq!(
            Frame::decode(&long),
            Err(FrameError::Trailing {
                extra: 4,
                blocks: 1
            })
        );
        let mut bad = b;
        bad[17] = 42;
        assert_eq!(
            Frame::decode(&bad),
            Err(FrameError::DataType { index: 0, code: 42 })
        );
    }

    /// Text and narrow types are padded to 4 bytes.
    #[test]
    fn text_is_padded_to_a_word() {
        let f = Frame {
            extra: 0,
            receiver: 1,
            sender: 2,
            message_id: 3,
            options: 0,
            kind: cmd::GET_VERSION,
            blocks: vec![SubBlock::text("1.2.3"), SubBlock::u32s(&[7])],
        };
        let b = f.encode();
        assert_eq!(b.len(), 16 + 4 + 8 + 4 + 4);
        assert_eq!(Frame::decode(&b).unwrap(), f);
    }

    fn block() -> impl Strategy<Value = SubBlock> {
        (0u16..10, proptest::collection::vec(any::<i64>(), 0..6)).prop_map(|(code, raw)| {
            let data_type = DataType::from_code(code).unwrap();
            let w = data_type.width();
            let values = if w == 0 {
                Vec::new()
            } else {
                raw.into_iter()
                    .map(|v| {
                        if w == 8 {
                            v
                        } else if data_type.signed() {
                            let shift = 64 - 8 * w;
                            (v << shift) >> shift
                        } else {
                            v & ((1i64 << (8 * w)) - 1)
                        }
                    })
                    .collect()
            };
            SubBlock { data_type, values }
        })
    }

    proptest! {
        #[test]
        fn decode_inverts_encode(
            receiver in any::<u16>(), sender in any::<u16>(), id in any::<u16>(),
            options in any::<u32>(), kind in any::<u16>(), extra in any::<u8>(),
            blocks in proptest::collection::vec(block(), 0..4),
        ) {
            let f = Frame { extra, receiver, sender, message_id: id, options, kind, blocks };
            prop_assert_eq!(Frame::decode(&f.encode()).unwrap(), f);
        }

        #[test]
        fn no_datagram_panics_the_decoder(bytes in proptest::collection::vec(any::<u8>(), 0..80)) {
            let _ = Frame::decode(&bytes);
        }
    }
}
