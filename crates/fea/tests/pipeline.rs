//! The pipeline end to end on the prototype at mesh level 1: the binary's golden JSON,
//! the joint cache (hit, miss, corrupt entries), the consistency warnings and the input
//! checks. Level-1 joint solves cost about half a second each, so one warm-up solves
//! both joints once and every other test starts from a copy of its cache entries.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::fs;
use std::path::PathBuf;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use cellinject_fea::{
    Approach, CacheStatus, DirCache, FeaError, FeaModel, FeaOptions, JointKey, JointStore, NoCache,
    PreloadKind, StructureParams, UNLOADED, joint_geometry, joints, material,
};
use cellinject_model::{Design, prototype};
use serde_json::Value;

const GOLDEN_TABLES: &str = include_str!("../../cellinject/tests/golden/json/fea-tables.json");
const GOLDEN_SOLVE: &str = include_str!("../../cellinject/tests/golden/json/fea-solve.json");

fn design() -> Design {
    prototype()
}

fn params() -> StructureParams {
    StructureParams::default()
}

/// A fresh directory for one test (removed first if a previous run left it).
fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("cellinject-fea-test-{}-{name}", std::process::id()));
    let _ = fs::remove_dir_all(&d);
    d
}

/// The two joints solved once: their cache entries and the reports of that build.
struct Warm {
    entries: Vec<(String, Vec<u8>)>,
    tables: Value,
    solve: Value,
    build: Duration,
}

fn warm() -> &'static Warm {
    static WARM: OnceLock<Warm> = OnceLock::new();
    WARM.get_or_init(|| {
        let dir = temp_dir("warm");
        let cache = DirCache::new(&dir);
        let t = Instant::now();
        let model = FeaModel::build(&design(), &params(), FeaOptions::default(), &cache).unwrap();
        let build = t.elapsed();
        let c = model.joint_convergence();
        assert_eq!(
            (c.j1_j2.cache, c.j3.cache),
            (CacheStatus::Miss, CacheStatus::Miss)
        );
        let tables = serde_json::to_value(model.tables().unwrap()).unwrap();
        let solve = serde_json::to_value(
            model
                .solve(Approach::DriveTranslation, [-100.0, -100.0])
                .unwrap(),
        )
        .unwrap();
        let mut entries: Vec<(String, Vec<u8>)> = fs::read_dir(&dir)
            .unwrap()
            .map(|e| {
                let e = e.unwrap();
                (
                    e.file_name().to_string_lossy().into_owned(),
                    fs::read(e.path()).unwrap(),
                )
            })
            .collect();
        entries.sort();
        assert_eq!(
            entries.len(),
            2,
            "{:?}",
            entries.iter().map(|e| &e.0).collect::<Vec<_>>()
        );
        fs::remove_dir_all(&dir).unwrap();
        Warm {
            entries,
            tables,
            solve,
            build,
        }
    })
}

/// A cache directory holding the warm entries.
fn seeded(name: &str) -> (PathBuf, DirCache) {
    let dir = temp_dir(name);
    fs::create_dir_all(&dir).unwrap();
    for (file, bytes) in &warm().entries {
        fs::write(dir.join(file), bytes).unwrap();
    }
    let cache = DirCache::new(&dir);
    (dir, cache)
}

/// The cache entry file of one of the prototype's joints at level 1.
fn entry_of(cache: &DirCache, throat: f64) -> PathBuf {
    let p = params();
    let key = JointKey::new(
        &joint_geometry(&p, throat),
        &material(&p).unwrap(),
        &Default::default(),
        1,
    );
    cache.path_of(&key)
}

/// Every field of `golden` is in `mine` with the same value (numbers within relative
/// 1e-9); `mine` may hold more.
fn assert_contains(golden: &Value, mine: &Value, path: &str) {
    match (golden, mine) {
        (Value::Object(g), Value::Object(m)) => {
            for (k, gv) in g {
                let mv = m
                    .get(k)
                    .unwrap_or_else(|| panic!("{path}.{k} missing from the report"));
                assert_contains(gv, mv, &format!("{path}.{k}"));
            }
        }
        (Value::Array(g), Value::Array(m)) => {
            assert_eq!(g.len(), m.len(), "{path}: lengths");
            for (i, (gv, mv)) in g.iter().zip(m).enumerate() {
                assert_contains(gv, mv, &format!("{path}[{i}]"));
            }
        }
        (Value::Number(g), Value::Number(m)) => {
            let (g, m) = (g.as_f64().unwrap(), m.as_f64().unwrap());
            assert!(
                (g - m).abs() <= 1e-9 * g.abs().max(m.abs()),
                "{path}: golden {g:e}, report {m:e}"
            );
        }
        (g, m) => assert_eq!(g, m, "{path}"),
    }
}

/// The report with the cache's fields taken out (they say how, not what).
fn without_cache(v: &Value) -> Value {
    let mut v = v.clone();
    if let Some(c) = v
        .get_mut("joint_convergence")
        .and_then(Value::as_object_mut)
    {
        for j in c.values_mut() {
            if let Some(o) = j.as_object_mut() {
                o.remove("cache");
                o.remove("cache_detail");
            }
        }
    }
    v
}

fn cache_of(v: &Value) -> [String; 2] {
    let c = &v["joint_convergence"];
    [
        c["J1_J2"]["cache"].as_str().unwrap().to_string(),
        c["J3"]["cache"].as_str().unwrap().to_string(),
    ]
}

#[test]
fn reports_match_the_binarys_golden_json() {
    let w = warm();
    let golden: Value = serde_json::from_str(GOLDEN_TABLES).unwrap();
    assert_contains(&golden, &w.tables, "tables");
    let golden: Value = serde_json::from_str(GOLDEN_SOLVE).unwrap();
    assert_contains(&golden, &w.solve, "solve");
    // The new fields: the FEM's convergence, served from the cache or not.
    for j in ["J1_J2", "J3"] {
        let c = &w.solve["joint_convergence"][j];
        assert!(c["residual"].as_f64().unwrap() < 1e-13, "{c}");
        assert!(c["dofs"].as_u64().unwrap() > 10_000, "{c}");
    }
    assert_eq!(cache_of(&w.solve), ["miss", "miss"]);
    assert_eq!(w.solve["warnings"], Value::Array(vec![]));
}

#[test]
fn a_second_build_is_a_cache_hit_with_bit_identical_reports() {
    let w = warm();
    let (dir, cache) = seeded("hit");
    let t = Instant::now();
    let model = FeaModel::build(&design(), &params(), FeaOptions::default(), &cache).unwrap();
    let hit = t.elapsed();
    eprintln!(
        "build with both joints solved (miss): {:.3} s; from the cache (hit): {:.3} s",
        w.build.as_secs_f64(),
        hit.as_secs_f64()
    );
    let tables = serde_json::to_value(model.tables().unwrap()).unwrap();
    let solve = serde_json::to_value(
        model
            .solve(Approach::DriveTranslation, [-100.0, -100.0])
            .unwrap(),
    )
    .unwrap();
    assert_eq!(cache_of(&solve), ["hit", "hit"]);
    assert_eq!(cache_of(&tables), ["hit", "hit"]);
    // Bit-identical: the JSON texts (shortest round-trip decimals) are equal.
    for (a, b) in [(&tables, &w.tables), (&solve, &w.solve)] {
        assert_eq!(
            serde_json::to_string(&without_cache(a)).unwrap(),
            serde_json::to_string(&without_cache(b)).unwrap()
        );
    }
    assert!(hit < w.build, "hit {hit:?}, miss {:?}", w.build);
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn another_throat_is_a_miss_never_served_the_other_entry_and_warned_about() {
    let w = warm();
    let (dir, cache) = seeded("throat");
    let mut p = params();
    p.throat_j3 = 2.2e-3;
    let model = FeaModel::build(&design(), &p, FeaOptions::default(), &cache).unwrap();
    let c = model.joint_convergence();
    assert_eq!(
        (c.j1_j2.cache, c.j3.cache),
        (CacheStatus::Hit, CacheStatus::Miss)
    );
    // A thicker throat is stiffer: not the 2.0 mm joint's entry.
    let old = w.solve["joint_k_bend"]["J3"][0].as_f64().unwrap();
    let k3 = model.joint_j3().k_bend;
    assert!(k3[0] > 1.1 * old, "{} vs {old}", k3[0]);
    assert_eq!(fs::read_dir(&dir).unwrap().count(), 3);
    // [flexures] still says 340.3 N·m/rad for J3: both axes are named, J1/J2 are not.
    let warnings = model.consistency_warnings();
    assert_eq!(warnings.len(), 2, "{warnings:#?}");
    for (axis, w) in warnings.iter().enumerate() {
        eprintln!("warning: {w}");
        assert!(
            w.starts_with(&format!("flexures.J3[{axis}] = 340.3 N·m/rad but the [structure] joint (structure.throat_J3 = 0.0022 m) gives ")),
            "{w}"
        );
        assert!(
            w.ends_with(" %)") && w.contains("at mesh level 1 (+"),
            "{w}"
        );
    }
    let report = model.modes(Approach::JointDeflection, 2).unwrap();
    assert_eq!(report.warnings, warnings);
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn corrupt_entries_are_recomputed_reported_and_repaired() {
    let w = warm();
    let (dir, cache) = seeded("corrupt");
    let p = params();
    // J1/J2: one payload byte flipped; J3: the file cut short.
    let e12 = entry_of(&cache, p.throat_j12);
    let mut bytes = fs::read(&e12).unwrap();
    let at = bytes.len() - 1000;
    bytes[at] ^= 0x10;
    fs::write(&e12, &bytes).unwrap();
    let e3 = entry_of(&cache, p.throat_j3);
    let bytes = fs::read(&e3).unwrap();
    fs::write(&e3, &bytes[..bytes.len() / 2]).unwrap();
    let model = FeaModel::build(&design(), &p, FeaOptions::default(), &cache).unwrap();
    let solve = serde_json::to_value(
        model
            .solve(Approach::DriveTranslation, [-100.0, -100.0])
            .unwrap(),
    )
    .unwrap();
    let recomputed = "recomputed (corrupt entry)".to_string();
    assert_eq!(cache_of(&solve), [recomputed.clone(), recomputed]);
    let detail = |j: &str| solve["joint_convergence"][j]["cache_detail"].to_string();
    assert!(detail("J1_J2").contains("checksum"), "{}", detail("J1_J2"));
    assert!(detail("J3").contains("truncated"), "{}", detail("J3"));
    assert_eq!(
        serde_json::to_string(&without_cache(&solve)).unwrap(),
        serde_json::to_string(&without_cache(&w.solve)).unwrap()
    );
    // Overwritten with good entries: the next build is served.
    let again = FeaModel::build(&design(), &p, FeaOptions::default(), &cache).unwrap();
    let c = again.joint_convergence();
    assert_eq!(
        (c.j1_j2.cache, c.j3.cache),
        (CacheStatus::Hit, CacheStatus::Hit)
    );
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn inputs_are_refused_with_their_numbers_and_keys() {
    let (dir, cache) = seeded("inputs");
    let d = design();
    let model = FeaModel::build(&d, &params(), FeaOptions::default(), &cache).unwrap();
    let e = model
        .solve(Approach::JointDeflection, [50.0, -100.0])
        .unwrap_err();
    assert_eq!(
        e,
        FeaError::PullingForce {
            index: 1,
            force: 50.0
        }
    );
    assert!(
        e.is_input() && e.to_string().contains("would pull on A1"),
        "{e}"
    );
    let e = model
        .solve(Approach::DriveTranslation, [-100.0, -2000.0])
        .unwrap_err();
    assert!(
        matches!(e, FeaError::PushCapacity { index: 2, force, capacity } if force == -2000.0 && capacity == d.actuators[1].push_capacity)
    );
    assert!(e.to_string().contains("actuators.A2.push_capacity"), "{e}");
    let e = model
        .solve(Approach::DriveTranslation, [f64::NAN, -100.0])
        .unwrap_err();
    assert!(
        matches!(e, FeaError::NonFinite { ref key, .. } if key == "F11"),
        "{e}"
    );
    for level in [0, 4] {
        let options = FeaOptions {
            level,
            preload: PreloadKind::Deflection,
        };
        let e = FeaModel::build(&d, &params(), options, &NoCache).unwrap_err();
        assert_eq!(e, FeaError::Level { level });
        assert!(e.is_input());
    }
    let bad = |f: fn(&mut StructureParams)| {
        let mut p = params();
        f(&mut p);
        FeaModel::build(&d, &p, FeaOptions::default(), &cache).unwrap_err()
    };
    let e = bad(|p| p.youngs = -1.0);
    assert!(
        matches!(e, FeaError::Invalid { ref key, value, .. } if key == "structure.youngs" && value == -1.0),
        "{e}"
    );
    let e = bad(|p| p.poisson = 0.5);
    assert!(
        matches!(e, FeaError::Invalid { ref key, .. } if key == "structure.poisson"),
        "{e}"
    );
    let e = bad(|p| p.yield_strength = f64::INFINITY);
    assert!(
        matches!(e, FeaError::NonFinite { ref key, .. } if key == "structure.yield_strength"),
        "{e}"
    );
    // A throat as thick as the rod: the FEM refuses J3, named by its key (J1/J2 is
    // served from the cache first).
    let e = bad(|p| p.throat_j3 = p.joint.side);
    assert!(
        matches!(
            e,
            FeaError::JointFem {
                key: "structure.throat_J3",
                ..
            }
        ),
        "{e}"
    );
    assert!(
        e.is_input()
            && e.to_string()
                .starts_with("structure.throat_J3: joint FEM failed"),
        "{e}"
    );
    for levels in [&[][..], &[1, 4][..]] {
        let e = joints(&params(), levels, &NoCache).unwrap_err();
        assert!(matches!(e, FeaError::Levels { .. }) && e.is_input(), "{e}");
    }
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn modes_joints_and_the_material_come_from_the_same_joints() {
    let w = warm();
    let (dir, cache) = seeded("modes");
    let model = FeaModel::build(&design(), &params(), FeaOptions::default(), &cache).unwrap();
    let m = model.modes(Approach::JointDeflection, 3).unwrap();
    assert_eq!(m.modes.len(), 3);
    assert!(m.modes.windows(2).all(|p| p[0].frequency <= p[1].frequency));
    for mode in &m.modes[..2] {
        assert!(
            mode.description.starts_with("body 1 tilt"),
            "{}",
            mode.description
        );
    }
    let v = serde_json::to_value(&m).unwrap();
    for k in ["approach", "preload", "modes"] {
        assert!(v.get(k).is_some(), "{k}");
    }
    assert!(v["modes"][0].get("tip_shape").is_some());
    // `fea joints` at level 1 is served by the same entries.
    let store: &dyn JointStore = &cache;
    let j = joints(&params(), &[1, 1], store).unwrap();
    let v = serde_json::to_value(&j).unwrap();
    for (row, name) in v["joints"].as_array().unwrap().iter().zip(["J1_J2", "J3"]) {
        let level = &row["levels"][0];
        assert_eq!(level["cache"], "hit");
        assert_eq!(row["k_bend"], w.solve["joint_k_bend"][name]);
        for k in [
            "level",
            "k_bend",
            "k_axial",
            "k_torsion",
            "max_stress_per_rad",
            "dofs",
            "residual",
        ] {
            assert!(level.get(k).is_some(), "{k}");
        }
        let rel = row["relative_to_paper"][0].as_f64().unwrap();
        assert!(rel.abs() < 0.03, "{rel}");
    }
    for k in ["side", "radius", "flat", "gap"] {
        assert!(v["geometry"].get(k).is_some(), "{k}");
    }
    // The yield strength is the description's: twice as strong, twice as safe, and the
    // FEM (which does not depend on it) still served from the cache.
    let mut p = params();
    p.yield_strength *= 2.0;
    let strong = FeaModel::build(&design(), &p, FeaOptions::default(), &cache).unwrap();
    assert_eq!(strong.joint_convergence().j3.cache, CacheStatus::Hit);
    let s = strong
        .solve(Approach::DriveTranslation, [-100.0, -100.0])
        .unwrap();
    assert_eq!(s.yield_strength, 930e6);
    let base = &w.solve["joints"];
    for (i, js) in s.joints.iter().enumerate() {
        let f = base[i]["safety_factor"].as_f64().unwrap();
        assert!((js.safety_factor.unwrap() / f - 2.0).abs() < 1e-12);
    }
    // The paper's torque set-up for approach 2 is named in the tables report.
    let torque = FeaModel::build(
        &design(),
        &params(),
        FeaOptions {
            level: 1,
            preload: PreloadKind::Torque,
        },
        &cache,
    )
    .unwrap();
    let t = serde_json::to_value(torque.tables().unwrap()).unwrap();
    assert_eq!(t["approach2_preload"], "torque");
    assert_eq!(t["tables"][0], w.tables["tables"][0]);
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_unloaded_joint_has_no_safety_factor() {
    // Approach 1 with both forces at zero: the structure is free of load, every stress
    // is rounding, and no safety factor (1e29 before) is reported.
    let (dir, cache) = seeded("unloaded");
    let m = FeaModel::build(&design(), &params(), FeaOptions::default(), &cache).unwrap();
    let r = m.solve(Approach::DriveTranslation, [0.0, 0.0]).unwrap();
    for j in &r.joints {
        assert!(
            j.max_von_mises < UNLOADED * r.yield_strength,
            "{}: {}",
            j.name,
            j.max_von_mises
        );
        assert_eq!(j.safety_factor, None, "{}", j.name);
    }
    let v = serde_json::to_value(&r).unwrap();
    assert!(v["joints"][0]["safety_factor"].is_null());
    // Under load, every joint has one.
    let loaded = m
        .solve(Approach::DriveTranslation, [-100.0, -100.0])
        .unwrap();
    assert!(
        loaded
            .joints
            .iter()
            .all(|j| j.safety_factor.is_some_and(|f| f > 1.0))
    );
    let _ = fs::remove_dir_all(dir);
}

#[test]
fn the_j3_yield_map_reproduces_the_structural_model_it_reduces() {
    // The envelope's J3 check is a handful of affine stress points: at forces off the
    // linearisation point it must give the full model's peak stress (solve's J3 row).
    let (dir, cache) = seeded("yield-map");
    let m = FeaModel::build(&design(), &params(), FeaOptions::default(), &cache).unwrap();
    for approach in [Approach::DriveTranslation, Approach::JointDeflection] {
        let map = m.j3_yield_map(approach, 16).unwrap();
        assert_eq!(map.points.len(), 16);
        assert_eq!(map.yield_strength, 465e6);
        // The map's own worst error over its grid is small against the yield strength.
        assert!(
            map.fit_error < 0.01 * map.yield_strength,
            "{}",
            map.fit_error
        );
        for f in [[-100.0, -100.0], [-111.686, -100.0], [-120.0, -120.0]] {
            let exact = m.solve(approach, f).unwrap().joints[0].max_von_mises;
            let reduced = map.von_mises(f);
            println!(
                "approach {}: F = {f:?} N: J3 {:.1} MPa (full model {:.1} MPa)",
                approach.number(),
                reduced / 1e6,
                exact / 1e6
            );
            assert!(
                (reduced - exact).abs() <= map.fit_error.max(1e-3 * exact),
                "{reduced} vs {exact}"
            );
        }
        println!("fit error {:.3} MPa", map.fit_error / 1e6);
    }
    let _ = fs::remove_dir_all(dir);
}
