//! The devices a rig names besides its stacks, opened through their drivers: bench
//! endpoints (`bench://`) and Sensapex links (`sensapex...://`), each connected once
//! and shared by the devices on it. `run`, the calibrations and `rig check` open
//! their stages, injector and optics here, so every front end opens a driver the
//! same way.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use cellinject_config::rigfile::{CameraDriver, DeviceDriver, RigFile};
use cellinject_gcs_emulator::bench::Bench;
use cellinject_hw::{HwError, Injector, Optics, Stage};

use crate::{SessionError, device, refused, sensapex};

/// Which stage of the rig.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum StageRole {
    /// `[stage.macro]`.
    Macro,
    /// `[stage.feeder]`.
    Feeder,
}

/// The endpoints and links opened so far.
#[derive(Default)]
pub(crate) struct Drivers {
    endpoints: Vec<(String, Bench)>,
    sensapex: sensapex::Links,
}

impl Drivers {
    /// The bench endpoint at `addr`.
    pub(crate) fn endpoint(&mut self, addr: &str) -> Result<Bench, SessionError> {
        if let Some((_, b)) = self.endpoints.iter().find(|(a, _)| a == addr) {
            return Ok(b.clone());
        }
        let b = Bench::connect(addr, Duration::from_secs(5))
            .map_err(|e| device("the bench endpoint", e))?;
        self.endpoints.push((addr.to_string(), b.clone()));
        Ok(b)
    }

    /// The bench endpoint of the first device that has one (the clock and the
    /// cameras' zoom come from it).
    pub(crate) fn first(&mut self, rig: &RigFile) -> Result<Bench, SessionError> {
        let addr = [
            &rig.stage_macro,
            &rig.stage_feeder,
            &rig.injector,
            &rig.optics,
        ]
        .into_iter()
        .find_map(|d| match d {
            DeviceDriver::Bench(a) => Some(a.clone()),
            DeviceDriver::Twin | DeviceDriver::Sensapex(_) => None,
        })
        .or_else(|| {
            [&rig.camera_top, &rig.camera_side]
                .into_iter()
                .find_map(|c| match c {
                    CameraDriver::Bench(a) => Some(a.clone()),
                    _ => None,
                })
        })
        .ok_or_else(|| {
            refused(
                "the rig",
                "a real bench needs a bench:// endpoint (for its clock and zoom) on one of its devices",
            )
        })?;
        self.endpoint(&addr)
    }

    /// A device's bench endpoint, with its name for errors.
    fn bench(&mut self, driver: &DeviceDriver) -> Result<(Bench, String), SessionError> {
        match driver {
            DeviceDriver::Bench(a) => Ok((self.endpoint(a)?, format!("bench://{a}"))),
            DeviceDriver::Twin => Err(refused(
                "the rig",
                "the twin's devices exist only with the twin's stacks",
            )),
            DeviceDriver::Sensapex(s) => Err(refused(
                "the rig",
                format!("{} is not a bench endpoint", s.url()),
            )),
        }
    }

    /// The stage `driver` names: a bench endpoint's macro or feeder stage, or a
    /// Sensapex uMp or uMs.
    pub(crate) fn stage(
        &mut self,
        driver: &DeviceDriver,
        role: StageRole,
    ) -> Result<Box<dyn Stage>, SessionError> {
        if let DeviceDriver::Sensapex(s) = driver {
            return self.sensapex.stage(s);
        }
        let (b, name) = self.bench(driver)?;
        Ok(match role {
            StageRole::Macro => Box::new(b.stage().map_err(|e| device(name, e))?),
            StageRole::Feeder => Box::new(b.feeder().map_err(|e| device(name, e))?),
        })
    }

    /// The injector `driver` names, refusing pressures above `max` (Pa): a bench
    /// endpoint's, or a Sensapex pressure channel.
    pub(crate) fn injector(
        &mut self,
        driver: &DeviceDriver,
        max: f64,
    ) -> Result<Box<dyn Injector>, SessionError> {
        if let DeviceDriver::Sensapex(s) = driver {
            return self.sensapex.injector(s, max);
        }
        let (b, name) = self.bench(driver)?;
        Ok(Box::new(b.injector().map_err(|e| device(name, e))?))
    }

    /// The optics `driver` names: a bench endpoint's zoom lens, or a Sensapex uMs's
    /// lens changer.
    pub(crate) fn optics(
        &mut self,
        driver: &DeviceDriver,
    ) -> Result<Box<dyn Optics>, SessionError> {
        if let DeviceDriver::Sensapex(s) = driver {
            return self.sensapex.optics(s);
        }
        let (b, name) = self.bench(driver)?;
        Ok(Box::new(b.optics().map_err(|e| device(name, e))?))
    }
}

/// The rig's optics, shared by the devices and the cameras of their own, whose pixel
/// size follows its zoom.
#[derive(Clone)]
pub(crate) struct SharedOptics(Arc<Mutex<Box<dyn Optics>>>);

impl SharedOptics {
    pub(crate) fn new(optics: Box<dyn Optics>) -> Self {
        SharedOptics(Arc::new(Mutex::new(optics)))
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Box<dyn Optics>> {
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The size of a pixel of pitch `pitch` (m) in the object plane at the zoom now.
    pub(crate) fn pixel_size(&self, pitch: f64) -> Box<dyn Fn() -> f64 + Send> {
        let lens = self.clone();
        Box::new(move || pitch / lens.zoom())
    }
}

impl Optics for SharedOptics {
    fn zoom(&self) -> f64 {
        self.lock().zoom()
    }
    fn zoom_range(&self) -> (f64, f64) {
        self.lock().zoom_range()
    }
    fn set_zoom(&mut self, zoom: f64) -> Result<(), HwError> {
        self.lock().set_zoom(zoom)
    }
}
