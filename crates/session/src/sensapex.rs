//! The Sensapex devices a rig names (`sensapex://`, `sensapex-ums://`,
//! `sensapex-pressure://`, and a uMs's lens changer as the optics): one SMCP1 link per address and group, shared by its
//! devices, and each device asked one question when it is opened, so that a device
//! that does not answer is found before anything moves (within the link's three
//! sends, 0.6 s).

use std::net::IpAddr;
use std::sync::{Arc, Mutex};

use cellinject_config::rigfile::{SensapexDevice, SensapexKind};
use cellinject_hw::{Injector, Optics, Stage};
use cellinject_sensapex::{LensChanger, Link, Model, Positioner, PressureChannel, SharedLink};

use crate::{SessionError, device};

/// The links opened so far.
#[derive(Default)]
pub(crate) struct Links(Vec<((IpAddr, u16), SharedLink)>);

impl Links {
    fn link(&mut self, s: &SensapexDevice) -> Result<SharedLink, SessionError> {
        let at = (s.address, s.group);
        if let Some((_, l)) = self.0.iter().find(|(a, _)| *a == at) {
            return Ok(l.clone());
        }
        let l = Arc::new(Mutex::new(
            Link::open(s.address, s.group).map_err(|e| device(s.url(), e))?,
        ));
        self.0.push((at, l.clone()));
        Ok(l)
    }

    /// A uMp or uMs as a stage.
    pub(crate) fn stage(&mut self, s: &SensapexDevice) -> Result<Box<dyn Stage>, SessionError> {
        let model = match s.kind {
            SensapexKind::Manipulator => Model::Manipulator,
            SensapexKind::Stage => Model::Stage,
            SensapexKind::Pressure => {
                return Err(crate::refused(
                    "the rig",
                    format!("{}: a pressure controller is not a stage", s.url()),
                ));
            }
        };
        let link = self.link(s)?;
        let p = Positioner::open(&link, s.dev, model, &s.origin, s.speed)
            .map_err(|e| device(s.url(), e))?;
        Ok(Box::new(p))
    }

    /// A uMv / uMc channel as the injector, refusing pressures above `max` (Pa).
    pub(crate) fn injector(
        &mut self,
        s: &SensapexDevice,
        max: f64,
    ) -> Result<Box<dyn Injector>, SessionError> {
        let link = self.link(s)?;
        let channel = s.channel.unwrap_or(1);
        let c =
            PressureChannel::open(&link, s.dev, channel, max).map_err(|e| device(s.url(), e))?;
        Ok(Box::new(c))
    }

    /// A uMs's lens changer as the optics (its lenses' magnifications from the rig).
    pub(crate) fn optics(&mut self, s: &SensapexDevice) -> Result<Box<dyn Optics>, SessionError> {
        if s.kind != SensapexKind::Stage {
            return Err(crate::refused(
                "the rig",
                format!("{}: only a uMs has a lens changer", s.url()),
            ));
        }
        let link = self.link(s)?;
        let l = LensChanger::open(&link, s.dev, &s.lenses).map_err(|e| device(s.url(), e))?;
        Ok(Box::new(l))
    }
}
