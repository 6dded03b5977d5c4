//! The prototype's pre-tension reproduces every figure of eqs. (38)-(58) within the
//! paper's rounding (0.1 %).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use cellinject_model::{Approach, Mechanism, prototype};
use cellinject_paper::{compare, figures, tolerance};

#[test]
fn every_figure_of_eqs_38_to_58_within_tolerance() {
    let m = Mechanism::new(&prototype()).unwrap();
    let t1 = m.tension(Approach::DriveTranslation).unwrap();
    let t2 = m.tension(Approach::JointDeflection).unwrap();
    let rows = compare(|a, k| {
        if a == 1 {
            t1.quantity(k)
        } else {
            t2.quantity(k)
        }
    })
    .unwrap();
    assert_eq!(rows.len(), figures().len());
    for r in &rows {
        assert!(
            r.pass(),
            "eq. ({}) {}: paper {:?}, computed {:?}, rel. diff {:.3e}",
            r.figure.eq,
            r.figure.key,
            r.figure.value,
            r.computed,
            r.rel_diff
        );
        if r.figure.truncated_decimals.is_none() {
            assert!(r.rel_diff <= tolerance());
        }
    }
}

#[test]
fn eq_55_as_printed_has_the_wrong_sign() {
    let m = Mechanism::new(&prototype()).unwrap();
    let t2 = m.tension(Approach::JointDeflection).unwrap();
    let f = figures().iter().find(|f| f.eq == 55).unwrap();
    let printed = f.printed.as_ref().unwrap();
    let computed = t2.quantity("dl1_work").unwrap();
    assert!(cellinject_paper::relative_difference(printed, &computed) > 1.0);
    // Eq. (56) = dl2 - dl1 holds with the computed sign.
    let dl_work = t2.quantity("dl_work").unwrap();
    assert!((dl_work[0] - (-30e-6 - computed[0])).abs() < 1e-18);
}
