//! # cellinject-gcs-emulator
//!
//! An emulated PI GCS 2.0 piezo controller backed by the digital twin, so that the GCS
//! driver, cellinject's commands and any third-party GCS client can be exercised
//! without hardware. Three axes, `1`, `2`, `3` = the twin's stacks A1, A2, A3;
//! positions are µm of stack extension as the stack's own sensor reads it, voltages
//! are V. It runs in wall-clock time: a ticker brings the twin up to the wall clock
//! every millisecond and before every command. The closed loops run on the twin's
//! clock, one servo tick per millisecond of twin time, so however the wall clock
//! slices time they are the same discrete-time system (see [`controller`]).
//!
//! On target (`ONT?` 1): the axis's trajectory has reached the target and its position
//! (the sensor low-passed over 5 ms) has stayed within the settling window, ±0.02 µm
//! of the target, for the settling time, 20 ms; `#5` reports an axis moving exactly
//! while its servo is on and it is not on target.
//!
//! Commands: `*IDN?`, `CSV?` (2.0), `SAI?` and `SAI? ALL`, `ERR?`, `SVO`/`SVO?`,
//! `MOV`/`MOV?`, `MVR`, `POS?`, `ONT?`, `VEL`/`VEL?`, `TMN?`/`TMX?` (the closed-loop
//! range: 2 % to 98 % of the stack's travel), `SVA`/`SVA?`, `VOL?`, `VMN?`/`VMX?`,
//! `HLT`, `STP`, `HLP?`, `VER?`, `CST?`, `ONL?`, and the single bytes `#5` (moving
//! mask, hexadecimal), `#7` (0xB1 + LF: always ready) and `#24` (stop all). Mnemonics
//! are accepted in either case. One client at a time: a second connection waits until
//! the first closes. Errors are sticky until `ERR?` reads them (the last one raised is kept): 1
//! syntax (odd argument count, a value that is not a number, a line over 4096 bytes),
//! 2 unknown command, 5 `MOV`/`MVR` with the servo off, 7 a target outside
//! `TMN?`..`TMX?` (or a closed-loop move the twin's safety envelope stopped), 10
//! stopped by `#24`/`HLT`/`STP`, 15 an unknown axis, 17 a value out of range (an `SVA`
//! outside 0..V_max, refused by the safety envelope, or sent with the servo on). A
//! command that raises an error does nothing; a query that raises one is not
//! answered.
//!
//! **Architecture invariant:** the emulator drives the twin only through the guarded
//! rig (`cellinject_rig::Rig`), so no GCS client can push the mechanism past the
//! limits the workflow itself respects.

pub mod bench;
pub mod controller;
pub mod sensapex;
pub mod server;

pub use controller::{Controller, IDN};
pub use server::{Running, serve};

/// `#5`.
pub const MOVING: u8 = 5;
/// `#7`.
pub const READY: u8 = 7;
/// `#24`.
pub const STOP_ALL: u8 = 24;
/// The answer of `#7` (ready).
pub const READY_BYTE: u8 = 0xB1;

/// Starts an emulator on `twin` (its devices behind their guards for the GCS axes;
/// the cameras, stage, injector and zoom on the bench endpoint).
pub fn start(
    twin: &cellinject_twin::SharedTwin,
    gcs: std::net::TcpListener,
    bench: Option<std::net::TcpListener>,
    log: bool,
) -> Result<Running, String> {
    let rig = cellinject_twin::rig(twin).map_err(|e| e.to_string())?;
    let ctl = Controller::new(twin.clone(), rig);
    let devices = bench.as_ref().map(|_| cellinject_twin::devices(twin));
    serve(ctl, devices, gcs, bench, log).map_err(|e| e.to_string())
}
