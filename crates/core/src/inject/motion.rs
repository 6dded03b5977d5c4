//! The bench's motions: A3 and the stacks held by their servo ([`Servo`]), the pipette
//! parked, rested and raised, the stages moved (checked against their travel and the
//! plate's walls) and the ways out of a field.

use super::*;

/// The closed loops that hold the stacks: A1/A2 in the control crate's sensor loop
/// (inverse hysteresis model plus PI on the strain gauges), A3 by feedforward plus an
/// integrator on its gauge. Stepped at 1 kHz whenever time passes.
pub(super) struct Servo {
    pub(super) ctl: SensorLoop,
    pub(super) refs: [f64; 2],
    pub(super) a3_ref: f64,
    pub(super) a3_int: f64,
    pub(super) a3_gain: f64,
    pub(super) a3_vmax: f64,
    pub(super) zero: [f64; 3],
    pub(super) t: f64,
}

impl Servo {
    pub(super) fn step<B: Backend>(&mut self, rig: &mut Rig<B>) -> Result<(), WorkflowError> {
        let mut e = [0.0; 3];
        for (k, e) in e.iter_mut().enumerate() {
            *e = rig.sensors[k].read().map_err(dev("stack sensor"))? - self.zero[k];
        }
        let m = Measurement {
            stacks: Some([e[0], e[1]]),
            ..Measurement::default()
        };
        let v = self.ctl.step(self.t, self.refs, &m);
        let applied = rig.command_tilt(v).map_err(dev("A1/A2"))?;
        self.ctl.applied(applied);
        let err = self.a3_ref - e[2];
        self.a3_int = (self.a3_int + 0.05 * err / self.a3_gain)
            .clamp(-0.3 * self.a3_vmax, 0.3 * self.a3_vmax);
        let v3 = (self.a3_ref / self.a3_gain + self.a3_int).clamp(0.0, self.a3_vmax);
        rig.piezo[2].set_voltage(v3).map_err(dev("A3"))?;
        Ok(())
    }

    /// Lets `seconds` pass, stepping the loops; `ramp` moves A3's reference towards
    /// `(target, speed)` meanwhile.
    pub(super) fn wait<B: Backend>(
        &mut self,
        rig: &mut Rig<B>,
        seconds: f64,
        ramp: Option<(f64, f64)>,
    ) -> Result<(), WorkflowError> {
        let end = rig.clock.now() + seconds;
        // The ramp moves with the time that passed since the last step (at least one
        // step's DT): a bench whose clock is the wall clock (a GCS controller on a
        // loaded host) steps less often than every DT, and a ramp counted in steps
        // fell behind there (A3 left 6 um out after a withdrawal of 0.08 s).
        let mut last = rig.clock.now() - DT;
        loop {
            let now = rig.clock.now();
            if now >= end - 1e-9 {
                return Ok(());
            }
            if let Some((target, speed)) = ramp {
                let step = speed * (now - last).max(DT);
                self.a3_ref += (target - self.a3_ref).clamp(-step, step);
            }
            last = now;
            self.step(rig)?;
            let dt = DT.min(end - now);
            rig.clock.sleep(dt).map_err(dev("clock"))?;
            self.t += dt;
        }
    }

    pub(super) fn a3(&mut self, rig: &mut Rig<impl Backend>) -> Result<f64, WorkflowError> {
        Ok(rig.sensors[2].read().map_err(dev("A3 sensor"))? - self.zero[2])
    }
}

impl<B: Backend> Workflow<'_, B> {
    /// Retracts A3, relaxes A1/A2 and lifts the pipette: the safe state.
    pub(super) fn park(&mut self) -> Result<(), WorkflowError> {
        if let Some(mut s) = self.servo.take() {
            // A3 out first (straight back along its axis), then A1/A2 relaxed: never
            // sideways inside a cell.
            let r = s.wait(self.rig, 0.15, Some((0.0, 500e-6))).and_then(|()| {
                s.refs = [0.0; 2];
                s.wait(self.rig, 0.05, None)
            });
            self.servo = Some(s);
            if let Err(e) = r {
                // The loops lost a device (a link that broke, a reply that never
                // came): straight commands, retried while the link comes back, A3
                // first.
                self.park_direct().map_err(|_| e)?;
            }
        } else {
            // No loops running (calibrating, or they were never started).
            self.park_direct()?;
        }
        let lift = self.home[1].max(self.options.focus + self.options.lift);
        self.rig.stage.move_to(1, lift).map_err(dev("stage lift"))?;
        Ok(())
    }

    /// The end of a run, however it ends: parked, and A3 at 0 V (the loop held the
    /// withdrawn tip with a small offset; the stack rests at 0 V, the same whether the
    /// loops or straight commands parked it).
    pub(super) fn rest(&mut self) -> Result<(), WorkflowError> {
        self.park()?;
        if let Some(s) = self.servo.as_mut() {
            s.a3_ref = 0.0;
            s.a3_int = 0.0;
        }
        self.rig.piezo[2].set_voltage(0.0).map_err(dev("A3"))
    }

    /// A3 to 0 V, then A1/A2 to 0 V, each retried for up to a second.
    pub(super) fn park_direct(&mut self) -> Result<(), WorkflowError> {
        let mut last = None;
        for step in 0..2 {
            for _ in 0..10 {
                let r = if step == 0 {
                    self.rig.piezo[2].set_voltage(0.0)
                } else {
                    self.rig.command_tilt([0.0, 0.0]).map(|_| ())
                };
                match r {
                    Ok(()) => {
                        last = None;
                        break;
                    }
                    Err(e) => {
                        last = Some(e);
                        let _ = self.rig.clock.sleep(0.1);
                    }
                }
            }
            if let Some(e) = last.take() {
                return Err(WorkflowError::Device {
                    what: if step == 0 {
                        "A3 (safe state)"
                    } else {
                        "A1/A2 (safe state)"
                    },
                    source: e,
                });
            }
        }
        Ok(())
    }

    /// Lets `seconds` pass with the loops running; `ramp`: A3's reference moves
    /// towards (target, speed) meanwhile.
    pub(super) fn servo_wait(
        &mut self,
        seconds: f64,
        ramp: Option<(f64, f64)>,
    ) -> Result<(), WorkflowError> {
        let mut s = self.servo.take().expect("servo");
        let r = s.wait(self.rig, seconds, ramp);
        self.servo = Some(s);
        r
    }

    pub(super) fn wait(&mut self, seconds: f64) -> Result<(), WorkflowError> {
        self.servo_wait(seconds, None)
    }

    pub(super) fn ramp_a3(
        &mut self,
        target: f64,
        speed: f64,
        seconds: f64,
    ) -> Result<(), WorkflowError> {
        self.servo_wait(seconds, Some((target, speed)))
    }

    /// Moves the stage's height to `y` before the servo runs (no stack is driven):
    /// waits until it is there.
    pub(super) fn raise_to(&mut self, y: f64) -> Result<(), WorkflowError> {
        self.rig.stage.move_to(1, y).map_err(dev("stage lift"))?;
        let deadline = self.options.stage_deadline;
        self.rig
            .wait_stage(deadline, 0.005, "stage (missed its deadline)")
            .map_err(dev("stage"))
    }

    /// Moves the stage, servoing the stacks while it goes; the deadline is the
    /// option's for moves of up to 1 mm, plus 1 s per further mm (the calibration's
    /// long moves).
    pub(super) fn stage_to(
        &mut self,
        p: [Option<f64>; 3],
    ) -> Result<Result<(), String>, WorkflowError> {
        let far = match self.stage_start(p)? {
            Ok(far) => far,
            Err(e) => return Ok(Err(e)),
        };
        let deadline = self.options.stage_deadline + (far - 1e-3).max(0.0) * 1e3;
        let t0 = self.now();
        while self.rig.stage.is_busy().map_err(dev("stage"))? {
            if self.now() - t0 > deadline {
                return Err(WorkflowError::Device {
                    what: "stage",
                    source: HwError::Timeout {
                        device: "stage (missed its deadline)".into(),
                        seconds: deadline,
                    },
                });
            }
            self.wait(0.005)?;
        }
        Ok(Ok(()))
    }

    /// Starts the stage's move to `p` (per axis; `None` stays) without waiting; returns
    /// the longest distance an axis has to go (m).
    pub(super) fn stage_start(
        &mut self,
        p: [Option<f64>; 3],
    ) -> Result<Result<f64, String>, WorkflowError> {
        let mut far = 0.0f64;
        for (axis, v) in p.iter().enumerate() {
            if let Some(v) = v {
                let now = self.rig.stage.position(axis).map_err(dev("stage"))?;
                far = far.max((v - now).abs());
            }
        }
        for (axis, v) in p.iter().enumerate() {
            if let Some(v) = v
                && let Err(e) = self.rig.stage.move_to(axis, *v)
            {
                return Ok(Err(format!("stage move refused: {e}")));
            }
        }
        Ok(Ok(far))
    }

    /// The stage positions (lifted to `lift`) that take the pipette out of the
    /// camera's view for a background, the first tried first: for a field served again
    /// once the survey is done (its focus known), the two shortest ways sideways out of
    /// the frame that the image map gives ([`ImageMap::out_of_view`]); then, and in the
    /// survey, a whole view to the left of the field's left edge (with the shorter way
    /// in the survey, field 2 of a strip plate could not be focused: its sweep swung
    /// between two heights that each saw the peak at an end).
    pub(super) fn ways_out(
        &mut self,
        lift: f64,
        pixel: f64,
    ) -> Result<Vec<[Option<f64>; 3]>, WorkflowError> {
        let full = self.settings_full.expect("full settings");
        let fov = full.roi.width as f64 * pixel;
        let x0 = self.field.expect("field").rect[0] + self.feeder_at[0];
        let mut ways = Vec::new();
        // Only for a field served again once the survey is done: the survey keeps the
        // way its focus and its backgrounds were measured with.
        if let Some(map) = self
            .map
            .filter(|_| self.field_focus.is_some() && !self.survey_cells.is_empty())
        {
            let now = [
                self.rig.stage.position(0).map_err(dev("stage"))?,
                self.rig.stage.position(2).map_err(dev("stage"))?,
            ];
            let frame = [full.roi.width as f64, full.roi.height as f64];
            if let Some(two) = map.out_of_view(now, frame, OUT_OF_VIEW_MARGIN) {
                ways.extend(two.map(|p| [Some(p[0]), Some(lift), Some(p[1])]));
            }
        }
        ways.push([Some(x0 - fov - OUT_OF_VIEW_MARGIN), Some(lift), None]);
        Ok(ways)
    }
}
