//! The calibrations' text (`cellinject calibrate pixels|jacobian|hysteresis`).

use std::fmt::Write as _;

use cellinject_core::calibrate::{HysteresisCalibration, JacobianCalibration, PixelCalibration};

/// Each camera's pixel size against the nominal, rotation, shear and residual.
pub fn pixels_text(c: &PixelCalibration) -> String {
    let mut out = String::new();
    for m in &c.maps {
        let _ = writeln!(
            out,
            "{} camera: {:.5} x {:.5} µm per pixel (nominal {:.5}), rotation {:.3} mrad, shear {:.3} mrad, residual {:.3} px over {} positions",
            m.camera.name(),
            m.metres_per_pixel[0] * 1e6,
            m.metres_per_pixel[1] * 1e6,
            m.nominal_pixel * 1e6,
            m.rotation * 1e3,
            m.skew * 1e3,
            m.rms_px,
            m.moves
        );
    }
    out.pop();
    out
}

/// Each tilt stack's Preisach fit, range and creep.
pub fn hysteresis_text(c: &HysteresisCalibration) -> String {
    let mut out = String::new();
    for i in 0..2 {
        let _ = writeln!(
            out,
            "A{}: Preisach fit RMS {:.1} nm ({:.2} % of the span) up to {:.1} V; creep {:.2} % per decade",
            i + 1,
            c.fit_rms[i] * 1e9,
            c.fit_rms_relative[i] * 100.0,
            c.v_max[i],
            c.creep[i].gamma * 100.0
        );
    }
    out.pop();
    out
}

/// The measured Jacobian of the tip against the model's, its deviation and spread.
pub fn jacobian_text(c: &JacobianCalibration) -> String {
    let mut out = String::new();
    let j = c.jacobian;
    let _ = writeln!(
        out,
        "tip per stack extension (m/m): [[{:.4}, {:.4}], [{:.4}, {:.4}]]; model [[{:.4}, {:.4}], [{:.4}, {:.4}]]",
        j[0][0],
        j[0][1],
        j[1][0],
        j[1][1],
        c.model[0][0],
        c.model[0][1],
        c.model[1][0],
        c.model[1][1]
    );
    let _ = writeln!(
        out,
        "deviation from the model {:.2} %, spread over {} steps {:.2} %",
        c.deviation * 100.0,
        c.repeats,
        c.spread * 100.0
    );
    out.pop();
    out
}
