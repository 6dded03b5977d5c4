//! The stacks of a GCS controller behind cellinject's hardware traits: an amplifier
//! channel per axis (open loop, `SVA`/`SVA?`/`VOL?`) and its position sensor (`POS?`,
//! µm on the wire, m here).

use std::sync::{Arc, Mutex, MutexGuard};

use cellinject_hw::{HwError, PiezoChannel, PositionSensor, check_range};

use crate::controller::{Gcs, GcsError};

/// A controller shared by its axes' device handles.
pub type SharedGcs = Arc<Mutex<Gcs>>;

fn lock(g: &SharedGcs) -> MutexGuard<'_, Gcs> {
    g.lock().unwrap_or_else(|e| e.into_inner())
}

/// A GCS error as a device error (a timeout stays a timeout).
pub fn hw_error(device: &str, e: GcsError) -> HwError {
    match e {
        GcsError::Timeout { seconds, .. } => HwError::Timeout {
            device: format!("{device} ({e})"),
            seconds,
        },
        other => HwError::Device {
            device: device.to_string(),
            message: other.to_string(),
        },
    }
}

/// One amplifier channel of a GCS controller, driven open loop with `SVA`.
pub struct GcsPiezo {
    gcs: SharedGcs,
    axis: String,
    name: &'static str,
    /// The parameter's name in range errors (`A1 voltage`).
    what: &'static str,
    range: (f64, f64),
    commanded: f64,
}

/// One stack's sensor as the controller reads it (`POS?`).
pub struct GcsSensor {
    gcs: SharedGcs,
    axis: String,
    name: &'static str,
    noise: f64,
}

/// The channels and sensors of `axes` (named `names`), with the amplifiers' voltage
/// ranges (the controller's `SVA` limits, from the rig description: GCS 2.0 has no
/// standard query for them) and the sensors' noise (m, 1 sigma). Each channel starts
/// at the voltage the controller reports (`SVA?`).
pub fn stacks(
    gcs: &SharedGcs,
    axes: [&str; 3],
    names: [&'static str; 3],
    ranges: [(f64, f64); 3],
    noise: [f64; 3],
) -> Result<([GcsPiezo; 3], [GcsSensor; 3]), GcsError> {
    let commanded = lock(gcs).voltage_command(&axes)?;
    let piezo = [0, 1, 2].map(|k| GcsPiezo {
        gcs: gcs.clone(),
        axis: axes[k].to_string(),
        name: names[k],
        what: ["A1 voltage", "A2 voltage", "A3 voltage"][k],
        range: ranges[k],
        commanded: commanded[k],
    });
    let sensors = [0, 1, 2].map(|k| GcsSensor {
        gcs: gcs.clone(),
        axis: axes[k].to_string(),
        name: names[k],
        noise: noise[k],
    });
    Ok((piezo, sensors))
}

impl PiezoChannel for GcsPiezo {
    fn name(&self) -> &str {
        self.name
    }
    fn voltage_range(&self) -> (f64, f64) {
        self.range
    }
    fn set_voltage(&mut self, volts: f64) -> Result<(), HwError> {
        check_range(self.what, volts, self.range.0, self.range.1)?;
        let mut g = lock(&self.gcs);
        match g.set_voltage(&[(&self.axis, volts)]) {
            Ok(()) => {
                self.commanded = volts;
                Ok(())
            }
            Err(e) => {
                // After a lost link the controller's command is unknown: read it back
                // when the link works again.
                if e.link_lost()
                    && let Ok(v) = g.voltage_command(&[&self.axis])
                {
                    self.commanded = v[0];
                }
                Err(hw_error(self.name, e))
            }
        }
    }
    fn commanded_voltage(&self) -> f64 {
        self.commanded
    }
    fn read_voltage(&mut self) -> Result<f64, HwError> {
        lock(&self.gcs)
            .output_voltage(&[&self.axis])
            .map(|v| v[0])
            .map_err(|e| hw_error(self.name, e))
    }
}

impl PositionSensor for GcsSensor {
    fn name(&self) -> &str {
        self.name
    }
    fn read(&mut self) -> Result<f64, HwError> {
        lock(&self.gcs)
            .position(&[&self.axis])
            .map(|v| v[0] * 1e-6)
            .map_err(|e| hw_error(self.name, e))
    }
    fn noise(&self) -> f64 {
        self.noise
    }
}
