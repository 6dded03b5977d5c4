//! The run's set-up, the `Calibrating` state of [`super::machine`]: the bench brought
//! to a safe start ([`Workflow::safe_start`]), the stacks' hysteresis checked or
//! identified ([`Workflow::stacks_calibrated`]), their sensor loops closed
//! ([`Workflow::close_loops`]), the focus height measured ([`Workflow::focus_height`])
//! and the image mapped to the stage on the first field ([`Workflow::first_map`]).

use super::*;

impl<B: Backend> Workflow<'_, B> {
    /// The run's set-up: the bench brought to a safe start, the stacks' hysteresis
    /// checked or identified, their loops closed, the focus height measured, and the
    /// image mapped to the stage on the first field. Returns the hysteresis calibration
    /// in force and what was found, for the log.
    pub(super) fn calibrate(
        &mut self,
        hysteresis: Option<HysteresisCalibration>,
    ) -> Result<(HysteresisCalibration, String), WorkflowError> {
        let mut why = Vec::new();
        let (start, lift, boot) = self.safe_start(&mut why)?;
        let cal = self.stacks_calibrated(hysteresis, lift, &mut why)?;
        let zero = self.close_loops(&cal)?;
        self.focus_height(start, zero, &mut why)?;
        self.first_map(&boot, &mut why)?;
        Ok((cal, why.join("; ")))
    }

    /// A3 and the tilt stacks at 0 V, the pipette lifted, the zoom set; the fields over
    /// the plate planned (a plate the feeder cannot present is refused here) and the
    /// session's side reference of the tip's height taken. Returns the stacks'
    /// readings as the run starts, the lift's height and the plan.
    fn safe_start(
        &mut self,
        why: &mut Vec<String>,
    ) -> Result<([f64; 2], f64, FieldPlan), WorkflowError> {
        // Safe start: A3 and the tilt stacks at 0 V, the pipette lifted.
        self.rig.piezo[2].set_voltage(0.0).map_err(dev("A3"))?;
        self.rig.command_tilt([0.0, 0.0]).map_err(dev("A1/A2"))?;
        for axis in 0..3 {
            self.home[axis] = self.rig.stage.position(axis).map_err(dev("stage"))?;
        }
        // Where the stacks stand as the run starts (the optics focused on the tip).
        let mut start = [0.0; 2];
        for (k, z) in start.iter_mut().enumerate() {
            let mut s = 0.0;
            for _ in 0..20 {
                s += self.rig.sensors[k].read().map_err(dev("stack sensor"))?;
            }
            *z = s / 20.0;
        }
        let lift = self.options.focus + self.options.lift;
        self.rig.stage.move_to(1, lift).map_err(dev("stage lift"))?;
        self.rig.clock.sleep(0.3).map_err(dev("clock"))?;
        self.home[1] = lift;
        self.rig
            .optics
            .set_zoom(self.options.zoom)
            .map_err(dev("zoom"))?;
        // The fields over the plate for the view the set-up gives: a plate the feeder
        // cannot present is refused here, before anything else moves.
        let boot = self.bootstrap_plan()?;
        // The session's side reference of the tip's height, with the stacks at rest
        // as the session starts (the stage arrived and settled at the lift first).
        if self.side.is_none() {
            self.raise_to(lift)?;
            self.rig.clock.sleep(0.3).map_err(dev("clock"))?;
            match self.side_reference()? {
                Ok(r) => self.side = Some(r),
                Err(e) => why.push(format!(
                    "the side camera cannot measure the tip's height ({e}): the focus follows the stack sensors"
                )),
            }
        }
        Ok((start, lift, boot))
    }

    /// A loaded hysteresis calibration checked (and used if it holds), else the
    /// stacks identified, with the pipette raised out of the way.
    fn stacks_calibrated(
        &mut self,
        hysteresis: Option<HysteresisCalibration>,
        lift: f64,
        why: &mut Vec<String>,
    ) -> Result<HysteresisCalibration, WorkflowError> {
        // The identification (and the check of a loaded calibration) sweeps the
        // stacks over their travel, A3 down the pipette's axis: the pipette goes that
        // much higher first, so that the tip stays clear of the cells and the floor.
        let drop = crate::calibrate::drop_over_travel(
            self.gain_a3 * self.rig.piezo[2].voltage_range().1,
            self.pipette.angle,
            self.jacobian[1],
            self.travel_a12,
        );
        let loaded = match hysteresis {
            Some(c) if c.problem().is_none() => {
                self.raise_to(lift + drop)?;
                let check = crate::calibrate::check_response(self.rig, &c).map_err(|e| {
                    WorkflowError::Calibration {
                        what: "hysteresis check",
                        reason: e.to_string(),
                    }
                })?;
                self.raise_to(lift)?;
                let holds = check.holds();
                why.push(format!(
                    "hysteresis calibration loaded: {}{}",
                    check.summary(),
                    if holds {
                        ""
                    } else {
                        ": it no longer holds, identified again"
                    }
                ));
                self.response_check = Some(check);
                holds.then_some(c)
            }
            Some(c) => {
                why.push(format!(
                    "hysteresis calibration failed its check ({}): identified again",
                    c.problem().unwrap_or_default()
                ));
                None
            }
            None => None,
        };
        let cal = match loaded {
            Some(c) => c,
            None => {
                self.raise_to(lift + drop)?;
                let (n, size) = (self.options.hysteresis_samples, HYSTERESIS_SIZE);
                let c = crate::calibrate::hysteresis(self.rig, n, size).map_err(|e| match e {
                    // Not the calibration's fault: the operator stopped it.
                    crate::bench::BenchError::Device {
                        source: source @ HwError::Interrupted { .. },
                        ..
                    } => WorkflowError::Device {
                        what: "hysteresis calibration",
                        source,
                    },
                    e => WorkflowError::Calibration {
                        what: "hysteresis",
                        reason: e.to_string(),
                    },
                })?;
                self.rig.piezo[2].set_voltage(0.0).map_err(dev("A3"))?;
                self.rig.clock.sleep(0.1).map_err(dev("clock"))?;
                self.raise_to(lift)?;
                if let Some(p) = c.problem() {
                    return Err(WorkflowError::Calibration {
                        what: "hysteresis",
                        reason: p,
                    });
                }
                why.push(format!(
                    "stacks identified: fit rms {:.2}/{:.2} %",
                    100.0 * c.fit_rms_relative[0],
                    100.0 * c.fit_rms_relative[1]
                ));
                c
            }
        };
        Ok(cal)
    }

    /// The tilt stacks' sensor loops closed on `cal`, the stacks at rest; returns
    /// their zero readings.
    fn close_loops(&mut self, cal: &HysteresisCalibration) -> Result<[f64; 3], WorkflowError> {
        let ff = Feedforward::new(self.stacks, cal.models.clone(), [None, None]).map_err(|e| {
            WorkflowError::Calibration {
                what: "hysteresis",
                reason: e.to_string(),
            }
        })?;
        let ctl = SensorLoop::new(ff, SensorGains::default()).map_err(|e| {
            WorkflowError::Calibration {
                what: "sensor loop",
                reason: e.to_string(),
            }
        })?;
        self.rig.command_tilt([0.0, 0.0]).map_err(dev("A1/A2"))?;
        self.rig.piezo[2].set_voltage(0.0).map_err(dev("A3"))?;
        self.rig.clock.sleep(0.3).map_err(dev("clock"))?;
        let mut zero = [0.0; 3];
        for (k, z) in zero.iter_mut().enumerate() {
            let mut s = 0.0;
            for _ in 0..20 {
                s += self.rig.sensors[k].read().map_err(dev("stack sensor"))?;
            }
            *z = s / 20.0;
        }
        let a3_vmax = self.rig.piezo[2].voltage_range().1;
        self.servo = Some(Servo {
            ctl,
            refs: [0.0; 2],
            a3_ref: 0.0,
            a3_int: 0.0,
            a3_gain: self.gain_a3,
            a3_vmax,
            zero,
            t: 0.0,
        });
        Ok(zero)
    }

    /// The focus height, from the side camera's view of the tip (else the stack
    /// sensors' creep since `start`, with the loops at `zero`).
    fn focus_height(
        &mut self,
        start: [f64; 2],
        zero: [f64; 3],
        why: &mut Vec<String>,
    ) -> Result<(), WorkflowError> {
        // The stacks now rest where the identification (or a previous run of the
        // session) left them, creeping back, and the drives have grown with the lab's
        // temperature: the tip stands higher or lower than where the option's focus
        // puts it in focus, and the stage makes up for it. The side camera sees that
        // height; the stacks' sensors see the creep only (through the model's
        // Jacobian), so they are the fallback. It is measured with the loops holding
        // the stacks at their zero, as they will through the run (the zero's own noise,
        // some 0.7 nm a stack, is 0.1-0.2 um of tip height).
        let seen = match self.side.clone() {
            Some(r) => match self.side_height(&r)? {
                Ok(h) => Some(h),
                Err(e) => {
                    why.push(format!(
                        "the side camera could not measure the tip's height ({e}): the focus follows the stack sensors"
                    ));
                    None
                }
            },
            None => None,
        };
        let rest = *self.rest.get_or_insert(start);
        let j = self.jacobian;
        let sensed = j[1][0] * (zero[0] - rest[0]) + j[1][1] * (zero[1] - rest[1]);
        let drop = match seen {
            Some(h) => {
                self.focus_by = "side camera";
                why.push(format!(
                    "the side camera sees the tip {:.2} µm {} than at the session's start (± {:.3} µm; magnification {:+.2e}; the stack sensors say {:+.2} µm): focus height {:.2} µm",
                    h.above.abs() * 1e6,
                    if h.above < 0.0 { "lower" } else { "higher" },
                    h.sigma * 1e6,
                    h.scale,
                    sensed * 1e6,
                    (self.options.focus - h.above) * 1e6
                ));
                h.above
            }
            None => {
                self.focus_by = "stack sensors";
                if sensed.abs() > 0.05e-6 {
                    why.push(format!(
                        "the tip rests {:.2} µm {} than at the session's start: focus height {:.2} µm",
                        sensed.abs() * 1e6,
                        if sensed < 0.0 { "lower" } else { "higher" },
                        (self.options.focus - sensed) * 1e6
                    ));
                }
                sensed
            }
        };
        self.focus = self.options.focus - drop;
        Ok(())
    }

    /// Full frames; the first field under the objective, its background, and the
    /// image mapped to the stage (a second try before giving up).
    fn first_map(&mut self, boot: &FieldPlan, why: &mut Vec<String>) -> Result<(), WorkflowError> {
        // Full frames for the map and the survey.
        let (sw, sh) = self.rig.camera.sensor_size();
        self.settings_full = Some(CameraSettings {
            roi: Roi {
                x: 0,
                y: 0,
                width: sw,
                height: sh,
            },
            binning: 1,
            ..self.rig.camera.settings()
        });
        if let Err(reason) = self.goto_field(boot.fields[0])? {
            return Err(WorkflowError::Calibration {
                what: "first field",
                reason,
            });
        }
        if let Err(reason) = self.take_background()? {
            return Err(WorkflowError::Calibration {
                what: "background",
                reason,
            });
        }
        let mut last = String::new();
        for attempt in 0..2 {
            match self.map_image()? {
                Ok(map) => {
                    self.last_check = self.now();
                    why.push(format!(
                        "image mapped to the stage (4 points, rms {:.2} px; the tip's blur in focus {:.2} px){}",
                        map.residual_px,
                        self.blur().unwrap_or(f64::NAN),
                        if attempt > 0 {
                            " on the second try"
                        } else {
                            ""
                        }
                    ));
                    self.map = Some(map);
                    if let Some(said) = self.refocus()? {
                        why.push(format!("after the map, {said}"));
                    }
                    return Ok(());
                }
                Err(reason) => last = reason,
            }
        }
        Err(WorkflowError::Calibration {
            what: "image-to-stage",
            reason: last,
        })
    }
}
