//! The twin's stages and injector as Sensapex devices (`emulate gcs --sensapex`): a
//! uMp is the macro stage, a uMs the feeder stage, a uMv channel the injector, served
//! over SMCP1 by `cellinject_sensapex::emulator` from the same world the GCS
//! controller and the cameras' endpoint serve, so the cameras see where a Sensapex
//! client moved the stages.
//!
//! The device's coordinates (nm) are the twin stage's (m) shifted so that the middle
//! of the device's travel is the twin's 0 (the driver's default `origin`). The twin's
//! stages move at their own speed and acceleration (a goto's speed is not used);
//! a stop holds each axis where it is. A valve's opening is the injector's pulse at
//! the channel's set point, for as long as it stayed open, given to the twin when it
//! closes. A uMs's lens changer is the twin's zoom lens: lens 1 its lowest zoom, lens
//! 2 its highest (the centre position, no lens, leaves the zoom as it was); the twin
//! starts at lens 1's.

use cellinject_hw::{Injector, Optics, Stage};
use cellinject_rig::Backend;
use cellinject_sensapex::emulator::{Backing, DeviceSpec, Emulated, Kind};
use cellinject_twin::{SharedTwin, TwinBackend};

type TwinStage = <TwinBackend as Backend>::Stage;
type TwinInjector = <TwinBackend as Backend>::Injector;
type TwinOptics = <TwinBackend as Backend>::Optics;

/// A twin stage as a Sensapex positioner.
struct StageBacking {
    stage: TwinStage,
    /// The device's coordinate of the twin's 0 on each axis, nm.
    centre: Vec<f64>,
    /// A uMs's lens changer: the twin's zoom lens, with lens 1's and lens 2's zoom.
    lenses: Option<(TwinOptics, [f64; 2])>,
}

impl Backing for StageBacking {
    fn positions(&mut self) -> Vec<f64> {
        (0..self.centre.len())
            .map(|k| self.stage.position(k).unwrap_or(f64::NAN) * 1e9 + self.centre[k])
            .collect()
    }

    fn start(&mut self, targets: &[Option<f64>]) -> bool {
        targets.iter().enumerate().all(|(k, t)| match t {
            Some(t) if k < self.centre.len() => {
                self.stage.move_to(k, (t - self.centre[k]) * 1e-9).is_ok()
            }
            Some(_) => false,
            None => true,
        })
    }

    fn stop(&mut self) {
        for k in 0..self.centre.len() {
            if let Ok(p) = self.stage.position(k) {
                let _ = self.stage.move_to(k, p);
            }
        }
    }

    fn busy(&mut self) -> bool {
        self.stage.is_busy().unwrap_or(false)
    }

    fn lens(&mut self, position: i32) {
        if let (Some((optics, zoom)), 1..=2) = (self.lenses.as_mut(), position) {
            let _ = optics.set_zoom(zoom[position as usize - 1]);
        }
    }
}

/// The twin's injector as a uMv's channels.
struct InjectorBacking {
    injector: TwinInjector,
}

impl Backing for InjectorBacking {
    fn pulse(&mut self, pressure: f64, duration: f64) {
        // The twin's limits apply (a refused pulse does not happen).
        let _ = self.injector.pulse(pressure.max(0.0), duration.min(10.0));
    }
}

/// The Sensapex devices `specs` on `twin`: each kind at most once (a `ump` is the
/// macro stage, a `ums` the feeder stage, a `umv` the injector; a 4-axis uMp has no
/// stage of the twin to stand for).
pub fn backed(twin: &SharedTwin, specs: &[DeviceSpec]) -> Result<Vec<Emulated>, String> {
    let devices = cellinject_twin::devices(twin);
    let (mut stage, mut feeder, mut injector) = (
        Some(devices.stage),
        Some(devices.feeder),
        Some(devices.injector),
    );
    let mut optics = Some(devices.optics);
    let centre = |kind: Kind| -> Vec<f64> {
        kind.travel()
            .iter()
            .map(|&(lo, hi)| 0.5 * (lo + hi) as f64)
            .collect()
    };
    let mut out: Vec<Emulated> = Vec::new();
    for &s in specs {
        let taken = |what: &str| {
            format!(
                "{} {}: the twin has one {what}, and it is taken",
                s.kind.name(),
                s.id
            )
        };
        let backing: Box<dyn Backing> = match s.kind {
            Kind::Manipulator { axes: 3 } => Box::new(StageBacking {
                stage: stage.take().ok_or_else(|| taken("macro stage"))?,
                centre: centre(s.kind),
                lenses: None,
            }),
            Kind::Manipulator { .. } => {
                return Err(format!(
                    "ump4 {}: the twin's macro stage has 3 axes (use ump)",
                    s.id
                ));
            }
            Kind::Stage => {
                let mut b = StageBacking {
                    stage: feeder.take().ok_or_else(|| taken("feeder stage"))?,
                    centre: centre(s.kind),
                    lenses: optics.take().map(|o| {
                        let (lo, hi) = o.zoom_range();
                        (o, [lo, hi])
                    }),
                };
                // The emulated uMs starts at lens 1.
                b.lens(1);
                Box::new(b)
            }
            Kind::Pressure => Box::new(InjectorBacking {
                injector: injector.take().ok_or_else(|| taken("injector"))?,
            }),
        };
        out.push((s, Some(backing)));
    }
    Ok(out)
}
