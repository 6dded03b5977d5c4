//! The emulated controller: three axes on the twin's stacks A1, A2, A3, the GCS 2.0
//! command set, sticky errors, and a servo per axis on the stack's sensor. Pure state:
//! time passes only through [`Controller::step_to`] (the server calls it with the wall
//! clock).

use cellinject_hw::{HwError, PiezoChannel, PositionSensor};
use cellinject_model::ACTUATOR_NAMES;
use cellinject_rig::Rig;
use cellinject_twin::{SharedTwin, Twin, TwinBackend};

/// The emulator's identification (`*IDN?`): vendor, model, serial number, firmware.
pub const IDN: &str = "Physik Instrumente (PI) GmbH & Co. KG (emulated by cellinject), E-727, 0000000001, cellinject 0.1.0";

/// The closed-loop range, fraction of the stack's travel: the amplifier's 0..V_max has
/// no headroom, and a stack's hysteresis and creep leave it up to a few per cent short
/// of (or beyond) its nominal travel at the ends.
pub const CLOSED_LOOP_RANGE: [f64; 2] = [0.02, 0.98];

/// Highest velocity `VEL` accepts, travels per second.
pub const MAX_VELOCITY: f64 = 1000.0;

/// PI's error codes the emulator raises.
pub mod code {
    /// Parameter syntax error.
    pub const SYNTAX: i32 = 1;
    /// Unknown command.
    pub const UNKNOWN: i32 = 2;
    /// Move with the servo off.
    pub const SERVO_OFF: i32 = 5;
    /// Position out of limits (also: the safety envelope stopped a closed-loop move).
    pub const OUT_OF_LIMITS: i32 = 7;
    /// Stopped by `#24`, `HLT` or `STP`.
    pub const STOPPED: i32 = 10;
    /// Invalid axis identifier.
    pub const AXIS: i32 = 15;
    /// Parameter out of range (also: an `SVA` the safety envelope refuses, or `SVA`
    /// with the servo on).
    pub const RANGE: i32 = 17;
}

/// One axis's closed-loop state (µm of stack extension, as its sensor reads it).
#[derive(Debug, Clone, Copy)]
struct Axis {
    servo: bool,
    target: f64,
    setpoint: f64,
    velocity: f64,
    integral: f64,
    settled: u32,
    position: f64,
}

/// `HLP?`: the commands, one per line.
const HELP: [&str; 24] = [
    "*IDN? - identification",
    "CSV? - GCS syntax version",
    "SAI? [ALL] - axes",
    "ERR? - last error (cleared)",
    "SVO {axis 0|1} - servo",
    "SVO? [axes]",
    "MOV {axis um} - absolute move (servo on)",
    "MOV? [axes] - targets",
    "MVR {axis um} - relative move",
    "POS? [axes] - sensor positions, um",
    "ONT? [axes] - on target",
    "VEL {axis um/s}",
    "VEL? [axes]",
    "TMN? [axes] - closed-loop minimum, um",
    "TMX? [axes] - closed-loop maximum, um",
    "SVA {axis V} - open-loop voltage (servo off)",
    "SVA? [axes]",
    "VOL? [axes] - output voltage",
    "VMN? [axes]",
    "VMX? [axes]",
    "HLT [axes] - halt (error 10)",
    "STP - stop all (error 10)",
    "CST? [axes] - stack names; ONL? - online; VER? - versions",
    "#5 moving mask (hex); #7 ready (0xB1); #24 stop all",
];

/// Servo step, s.
const DT: f64 = 1e-3;
/// Steps within the tolerance before `ONT?` reports on target.
const SETTLE_STEPS: u32 = 10;
/// µm, on-target tolerance.
const TOLERANCE: f64 = 0.02;
/// Proportional gain (µm of command per µm of error).
const KP: f64 = 0.3;
/// Integral gain, 1/s.
const KI: f64 = 150.0;

/// The emulated controller.
pub struct Controller {
    twin: SharedTwin,
    rig: Rig<TwinBackend>,
    axes: [Axis; 3],
    travel: [f64; 3],
    v_max: [f64; 3],
    error: i32,
}

fn lock(t: &SharedTwin) -> std::sync::MutexGuard<'_, Twin> {
    t.lock().unwrap_or_else(|e| e.into_inner())
}

fn reply(lines: &[String]) -> String {
    let mut s = lines.join(" \n");
    s.push('\n');
    s
}

impl Controller {
    /// A controller on `twin`'s stacks, behind the twin's own safety envelope (`rig`,
    /// built from the same twin).
    pub fn new(twin: SharedTwin, mut rig: Rig<TwinBackend>) -> Self {
        let (travel, v_max) = {
            let t = lock(&twin);
            let d = t.world.mechanism().design();
            let p = t.world.params().rig;
            (
                [0, 1, 2].map(|k| d.actuators[k].travel * 1e6),
                [0, 1, 2].map(|k| p.amplifiers[k].v_max),
            )
        };
        let axes = [0, 1, 2].map(|k| Axis {
            servo: false,
            target: 0.0,
            setpoint: 0.0,
            velocity: 100.0 * travel[k],
            integral: 0.0,
            settled: SETTLE_STEPS,
            position: rig.sensors[k].read().unwrap_or(0.0) * 1e6,
        });
        Controller {
            twin,
            rig,
            axes,
            travel,
            v_max,
            error: 0,
        }
    }

    /// The twin.
    pub fn twin(&self) -> &SharedTwin {
        &self.twin
    }

    /// The twin's time, s.
    pub fn time(&self) -> f64 {
        lock(&self.twin).world.time()
    }

    fn raise(&mut self, code: i32) {
        self.error = code;
    }

    /// Raises error 1 (a command line the server dropped: longer than it accepts).
    pub fn raise_syntax(&mut self) {
        self.raise(code::SYNTAX);
    }

    fn limits(&self, k: usize) -> (f64, f64) {
        (
            CLOSED_LOOP_RANGE[0] * self.travel[k],
            CLOSED_LOOP_RANGE[1] * self.travel[k],
        )
    }

    fn gain(&self, k: usize) -> f64 {
        self.travel[k] / self.v_max[k]
    }

    fn read(&mut self, k: usize) -> f64 {
        if let Ok(p) = self.rig.sensors[k].read() {
            self.axes[k].position = p * 1e6;
        }
        self.axes[k].position
    }

    fn moving(&self, k: usize) -> bool {
        let a = &self.axes[k];
        a.servo && (a.setpoint != a.target || a.settled < SETTLE_STEPS)
    }

    /// Lets the twin run to time `t` in servo steps of 1 ms.
    pub fn step_to(&mut self, t: f64) {
        loop {
            let now = self.time();
            if now >= t - 1e-9 {
                return;
            }
            let dt = DT.min(t - now);
            for k in 0..3 {
                if self.axes[k].servo {
                    self.servo_step(k, dt);
                }
            }
            let mut t = lock(&self.twin);
            t.advance_to(now + dt);
            if t.world.time() == now {
                // Less than one integration step left: the rest waits for the next call.
                return;
            }
        }
    }

    fn servo_step(&mut self, k: usize, dt: f64) {
        let pos = self.read(k);
        let gain = self.gain(k);
        let a = &mut self.axes[k];
        let max = a.velocity * dt;
        a.setpoint += (a.target - a.setpoint).clamp(-max, max);
        let e = a.setpoint - pos;
        let di = KI * e * dt;
        let u = (a.setpoint + KP * e + a.integral + di) / gain;
        let clamped = u.clamp(0.0, self.v_max[k]);
        // Anti-windup: integrate unless saturated and the error pushes further out.
        if clamped == u || (u > clamped && e < 0.0) || (u < clamped && e > 0.0) {
            a.integral += di;
        }
        a.settled = if a.setpoint == a.target && e.abs() < TOLERANCE {
            a.settled.saturating_add(1)
        } else {
            0
        };
        if self.rig.piezo[k].set_voltage(clamped).is_err() {
            // The envelope refuses: the move ends where the stack is, as safe as it
            // gets, and the client learns why.
            let safe = self.rig.max_safe_voltage(k).map(|m| m.min(clamped));
            if let Some(v) = safe {
                let _ = self.rig.piezo[k].set_voltage(v);
            }
            let a = &mut self.axes[k];
            a.target = pos;
            a.setpoint = pos;
            a.integral = self.rig.piezo[k].commanded_voltage() * gain - pos;
            self.error = code::OUT_OF_LIMITS;
        }
    }

    fn axis(&self, id: &str) -> Option<usize> {
        match id {
            "1" => Some(0),
            "2" => Some(1),
            "3" => Some(2),
            _ => None,
        }
    }

    /// The axes a query names (all when none; `ALL` too), or error 15.
    fn query_axes(&mut self, args: &[&str]) -> Option<Vec<usize>> {
        if args.is_empty() || (args.len() == 1 && args[0].eq_ignore_ascii_case("ALL")) {
            return Some(vec![0, 1, 2]);
        }
        let mut out = Vec::with_capacity(args.len());
        for a in args {
            match self.axis(a) {
                Some(k) => out.push(k),
                None => {
                    self.raise(code::AXIS);
                    return None;
                }
            }
        }
        Some(out)
    }

    /// Axis/value pairs, all checked before any is used (error 1 or 15 otherwise).
    fn pairs(&mut self, args: &[&str]) -> Option<Vec<(usize, f64)>> {
        if args.is_empty() || args.len() % 2 != 0 {
            self.raise(code::SYNTAX);
            return None;
        }
        let mut out = Vec::with_capacity(args.len() / 2);
        for p in args.chunks(2) {
            let Some(k) = self.axis(p[0]) else {
                self.raise(code::AXIS);
                return None;
            };
            match p[1].parse::<f64>() {
                Ok(v)
                    if v.is_finite()
                        && p[1]
                            .bytes()
                            .all(|b| b.is_ascii_digit() || b"+-.eE".contains(&b)) =>
                {
                    out.push((k, v))
                }
                _ => {
                    self.raise(code::SYNTAX);
                    return None;
                }
            }
        }
        Some(out)
    }

    fn per_axis(
        &mut self,
        args: &[&str],
        value: impl Fn(&mut Self, usize) -> String,
    ) -> Option<String> {
        let axes = self.query_axes(args)?;
        let lines: Vec<String> = axes
            .iter()
            .map(|&k| format!("{}={}", k + 1, value(self, k)))
            .collect();
        Some(reply(&lines))
    }

    /// `#5`: bit k set while axis k+1 moves (hexadecimal, no prefix).
    pub fn moving_mask(&self) -> u32 {
        (0..3)
            .filter(|&k| self.moving(k))
            .fold(0, |m, k| m | 1 << k)
    }

    /// Stops every axis where its sensor is (`#24`, `STP`, `HLT`): error 10.
    pub fn stop(&mut self, axes: &[usize]) {
        for &k in axes {
            let pos = self.read(k);
            let a = &mut self.axes[k];
            if a.servo {
                a.target = pos;
                a.setpoint = pos;
            }
        }
        self.raise(code::STOPPED);
    }

    /// Executes one command line (without its LF); returns the reply, if the command
    /// answers.
    pub fn execute(&mut self, line: &str) -> Option<String> {
        let mut words = line.split_ascii_whitespace();
        let cmd = words.next()?.to_ascii_uppercase();
        let args: Vec<&str> = words.collect();
        let no_args = ["*IDN?", "CSV?", "ERR?", "ONL?", "HLP?", "VER?", "STP"];
        if no_args.contains(&cmd.as_str()) && !args.is_empty() {
            self.raise(code::SYNTAX);
            return None;
        }
        match cmd.as_str() {
            "*IDN?" => Some(reply(&[IDN.to_string()])),
            "CSV?" => Some(reply(&["2.0".to_string()])),
            "ERR?" => {
                let e = std::mem::take(&mut self.error);
                Some(reply(&[e.to_string()]))
            }
            "SAI?" => {
                if args.is_empty() || (args.len() == 1 && args[0].eq_ignore_ascii_case("ALL")) {
                    Some(reply(&["1".into(), "2".into(), "3".into()]))
                } else {
                    self.raise(code::SYNTAX);
                    None
                }
            }
            "SVO" => {
                let pairs = self.pairs(&args)?;
                if pairs.iter().any(|&(_, v)| v != 0.0 && v != 1.0) {
                    self.raise(code::RANGE);
                    return None;
                }
                for (k, v) in pairs {
                    let on = v == 1.0;
                    if on && !self.axes[k].servo {
                        let pos = self.read(k);
                        let v = self.rig.piezo[k].commanded_voltage();
                        let gain = self.gain(k);
                        let a = &mut self.axes[k];
                        a.target = pos;
                        a.setpoint = pos;
                        // Bumpless: the servo starts from the voltage applied now.
                        a.integral = v * gain - pos;
                        a.settled = 0;
                    }
                    self.axes[k].servo = on;
                }
                None
            }
            "SVO?" => self.per_axis(&args, |s, k| u8::from(s.axes[k].servo).to_string()),
            "MOV" | "MVR" => {
                let pairs = self.pairs(&args)?;
                let mut targets = Vec::with_capacity(pairs.len());
                for (k, v) in pairs {
                    if !self.axes[k].servo {
                        self.raise(code::SERVO_OFF);
                        return None;
                    }
                    let t = if cmd == "MVR" {
                        self.axes[k].target + v
                    } else {
                        v
                    };
                    if !(0.0..=self.travel[k]).contains(&t) {
                        self.raise(code::OUT_OF_LIMITS);
                        return None;
                    }
                    targets.push((k, t));
                }
                for (k, t) in targets {
                    self.axes[k].target = t;
                    self.axes[k].settled = 0;
                }
                None
            }
            "MOV?" => self.per_axis(&args, |s, k| s.axes[k].target.to_string()),
            "POS?" => self.per_axis(&args, |s, k| s.read(k).to_string()),
            "ONT?" => self.per_axis(&args, |s, k| u8::from(!s.moving(k)).to_string()),
            "VEL" => {
                let pairs = self.pairs(&args)?;
                if pairs
                    .iter()
                    .any(|&(k, v)| v <= 0.0 || v > MAX_VELOCITY * self.travel[k])
                {
                    self.raise(code::RANGE);
                    return None;
                }
                for (k, v) in pairs {
                    self.axes[k].velocity = v;
                }
                None
            }
            "VEL?" => self.per_axis(&args, |s, k| s.axes[k].velocity.to_string()),
            "TMN?" => self.per_axis(&args, |s, k| s.limits(k).0.to_string()),
            "TMX?" => self.per_axis(&args, |s, k| s.limits(k).1.to_string()),
            "VMN?" => self.per_axis(&args, |_, _| "0".to_string()),
            "VMX?" => self.per_axis(&args, |s, k| s.v_max[k].to_string()),
            "CST?" => self.per_axis(&args, |_, k| ACTUATOR_NAMES[k].to_string()),
            "ONL?" => Some(reply(&["1".into()])),
            "HLP?" => Some(reply(
                &HELP.iter().map(|h| h.to_string()).collect::<Vec<_>>(),
            )),
            "VER?" => Some(reply(&[format!(
                "cellinject GCS emulator {}",
                env!("CARGO_PKG_VERSION")
            )])),
            "SVA" => {
                let pairs = self.pairs(&args)?;
                for &(k, v) in &pairs {
                    if self.axes[k].servo || !(0.0..=self.v_max[k]).contains(&v) {
                        self.raise(code::RANGE);
                        return None;
                    }
                }
                for (k, v) in pairs {
                    if let Err(
                        HwError::Refused(_)
                        | HwError::OutOfRange { .. }
                        | HwError::NotFinite { .. },
                    ) = self.rig.piezo[k].set_voltage(v)
                    {
                        self.raise(code::RANGE);
                        return None;
                    }
                }
                None
            }
            "SVA?" => self.per_axis(&args, |s, k| s.rig.piezo[k].commanded_voltage().to_string()),
            "VOL?" => self.per_axis(&args, |s, k| {
                s.rig.piezo[k].read_voltage().unwrap_or(0.0).to_string()
            }),
            "HLT" => {
                let axes = self.query_axes(&args)?;
                self.stop(&axes);
                None
            }
            "STP" => {
                self.stop(&[0, 1, 2]);
                None
            }
            _ => {
                self.raise(code::UNKNOWN);
                None
            }
        }
    }
}
