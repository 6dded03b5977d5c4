//! A study: the points of a search turned into descriptions, figures into the search's
//! members, and the front into records (`front.json`).

use cellinject_config::overrides::apply;
use cellinject_fea::JointStore;
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use crate::DesignError;
use crate::evaluate::{EvalOptions, Fidelity, Figures, evaluate};
use crate::nsga2::{Member, Search};
use crate::space::Space;

/// Constraint violation given to a design whose evaluation failed.
pub const FAILED: f64 = 1e12;

/// One design of a study: its variables and what its evaluation gave.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Record {
    /// Description key → value.
    pub variables: Map<String, Value>,
    /// The figures, when the evaluation succeeded.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub figures: Option<Figures>,
    /// Why the evaluation failed, when it did.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub error: Option<String>,
}

/// The variables of a point as a JSON object (key → value).
pub fn variables(space: &Space, x: &[f64]) -> Map<String, Value> {
    space
        .variables
        .iter()
        .zip(x)
        .map(|(v, &value)| (v.key.clone(), Value::from(value)))
        .collect()
}

/// The description text of a point: `base` with the point's variables set.
pub fn description(space: &Space, base: &str, x: &[f64]) -> Result<String, DesignError> {
    Ok(apply(base, &space.overrides(x))?)
}

/// Evaluates one point of `space` on the description `base`.
pub fn evaluate_point(
    space: &Space,
    base: &str,
    x: &[f64],
    options: &EvalOptions,
    store: &dyn JointStore,
) -> Record {
    let figures = description(space, base, x)
        .and_then(|text| Ok(cellinject_config::parse(&text)?))
        .and_then(|desc| evaluate(&desc, options, store));
    match figures {
        Ok(f) => Record {
            variables: variables(space, x),
            figures: Some(f),
            error: None,
        },
        Err(e) => Record {
            variables: variables(space, x),
            figures: None,
            error: Some(e.to_string()),
        },
    }
}

/// How far a design is from the safety envelope, summed over its violated margins,
/// each in a unit's worth: 100 N of push capacity, 10 N of compression, 1 µm of travel,
/// 0.01 N·m of torque, 1 of a safety factor below 1.
pub fn envelope_violation(f: &Figures) -> f64 {
    let m = &f.stack_margins;
    let short = |v: f64, unit: f64| (-v).max(0.0) / unit;
    let mut cv = 0.0;
    for i in 0..2 {
        cv += short(m.push_capacity_n[i], 100.0);
        cv += short(m.compression_n[i], 10.0);
        if m.compression_n[i] == 0.0 {
            cv += 1e-3;
        }
        cv += short(m.travel_m[i], 1e-6);
        cv += short(m.torque_nm[i], 0.01);
    }
    for sf in [
        f.safety_factors.j1,
        f.safety_factors.j2,
        f.safety_factors.j3,
    ] {
        cv += (1.0 - sf).max(0.0);
    }
    cv
}

/// The space's constraints a design misses, by name, and their summed relative
/// shortfall.
pub fn constraint_violation(space: &Space, f: &Figures) -> (Vec<String>, f64) {
    let mut names = Vec::new();
    let mut cv = 0.0;
    for c in &space.constraints {
        let v = f.get(&c.figure).unwrap_or(f64::NAN);
        if v.is_nan() || v < c.min {
            names.push(format!("{} >= {}", c.figure, c.min));
            let scale = c.min.abs().max(f64::MIN_POSITIVE);
            cv += if v.is_finite() {
                (c.min - v) / scale
            } else {
                1.0
            };
        }
    }
    (names, cv)
}

/// The search's view of a record: objectives to minimise (maximised ones negated) and
/// the total violation (envelope and constraints; [`FAILED`] for a failed evaluation).
pub fn member(space: &Space, x: &[f64], r: &Record) -> Member {
    match &r.figures {
        Some(f) => {
            let objectives = space
                .objectives
                .iter()
                .map(|o| {
                    let v = f.get(&o.figure).unwrap_or(f64::NAN);
                    let v = if o.maximise { -v } else { v };
                    if v.is_finite() { v } else { 0.0 }
                })
                .collect();
            let cv = envelope_violation(f) + constraint_violation(space, f).1;
            Member {
                x: x.to_vec(),
                f: objectives,
                cv: if cv.is_finite() { cv } else { FAILED },
                data: Value::Null,
            }
        }
        None => Member {
            x: x.to_vec(),
            f: vec![0.0; space.objectives.len()],
            cv: FAILED,
            data: Value::Null,
        },
    }
}

/// The point of the description `base` itself, when every variable is a plain key it
/// sets within the bounds (the prototype's place on the front).
pub fn base_point(space: &Space, base: &str) -> Option<Vec<f64>> {
    let root: toml::Table = base.parse().ok()?;
    space
        .variables
        .iter()
        .map(|v| {
            let (path, index) = match v.key.find('[') {
                Some(i) => (
                    &v.key[..i],
                    v.key[i + 1..v.key.len() - 1].parse::<usize>().ok(),
                ),
                None => (v.key.as_str(), None),
            };
            let mut node = &toml::Value::Table(root.clone());
            for part in path.split('.') {
                node = node.get(part)?;
            }
            let node = match (node, index) {
                (toml::Value::Array(a), Some(i)) => a.get(i)?,
                (toml::Value::Array(a), None) => a.first()?,
                (n, None) => n,
                _ => return None,
            };
            let x = node
                .as_float()
                .or_else(|| node.as_integer().map(|i| i as f64))?;
            (x >= v.lo && x <= v.hi).then_some(x)
        })
        .collect()
}

/// A design study: the space on a base description, the search, and how designs are
/// evaluated. Plain data: `state.json` of `design optimise` is this, so a study
/// resumes where it stopped.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Study {
    /// The space.
    pub space: Space,
    /// The base description's text.
    pub base: String,
    /// Pre-tensioning approach (1, 2), or the description's.
    pub approach: Option<u8>,
    /// The fidelity of the front: `beam`, or `fea` (the search screens with the beam
    /// formulas, then the front is evaluated again with the FEA).
    pub fidelity: Fidelity,
    /// The FEM mesh level of the FEA step.
    pub level: usize,
    /// Generations to run.
    pub generations: usize,
    /// The search.
    pub search: Search,
}

/// How a study runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    /// Pre-tensioning approach (1, 2), or the description's.
    pub approach: Option<u8>,
    /// The front's fidelity.
    pub fidelity: Fidelity,
    /// The FEM mesh level of the `fea` step.
    pub level: usize,
    /// Designs per generation.
    pub population: usize,
    /// Generations.
    pub generations: usize,
    /// Seed of the search.
    pub seed: u64,
}

/// One design of the front (`front.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrontEntry {
    /// Description key → value.
    pub variables: Map<String, Value>,
    /// Its figures.
    pub figures: Figures,
}

impl Study {
    /// A new study of `space` on the description text `base`.
    pub fn new(space: Space, base: String, settings: &Settings) -> Result<Study, DesignError> {
        let Settings {
            approach,
            fidelity,
            level,
            population,
            generations,
            seed,
        } = *settings;
        if let Some(a) = approach
            && !(1..=2).contains(&a)
        {
            return Err(DesignError::Input {
                key: "--approach".into(),
                reason: format!("must be 1 or 2, got {a}"),
            });
        }
        if fidelity == Fidelity::Fea && !(1..=2).contains(&level) {
            return Err(DesignError::Input {
                key: "--level".into(),
                reason: format!("must be 1 or 2, got {level}"),
            });
        }
        cellinject_config::parse(&base)?;
        let bounds = space.variables.iter().map(|v| [v.lo, v.hi]).collect();
        Ok(Study {
            search: Search::new(bounds, population, seed),
            space,
            base,
            approach,
            fidelity,
            level,
            generations,
        })
    }

    /// How the search evaluates its points: the beam formulas.
    pub fn screening(&self) -> EvalOptions {
        EvalOptions {
            approach: self
                .approach
                .and_then(cellinject_model::Approach::from_number),
            fidelity: Fidelity::Beam,
            level: self.level,
        }
    }

    /// How the front is evaluated at the end.
    pub fn final_options(&self) -> EvalOptions {
        EvalOptions {
            fidelity: self.fidelity,
            ..self.screening()
        }
    }

    /// Whether every generation has been told.
    pub fn done(&self) -> bool {
        self.search.generation >= self.generations
    }

    /// The points of the next generation.
    pub fn ask(&self) -> Vec<Vec<f64>> {
        let start = base_point(&self.space, &self.base);
        self.search.ask(start.as_deref())
    }

    /// Hands back the records of the points of the last [`Study::ask`], in order.
    pub fn tell(&mut self, points: &[Vec<f64>], records: Vec<Record>) -> Result<(), DesignError> {
        if points.len() != records.len() {
            return Err(DesignError::Input {
                key: "tell".into(),
                reason: format!("{} points but {} records", points.len(), records.len()),
            });
        }
        let members = points
            .iter()
            .zip(records)
            .map(|(x, r)| {
                let mut m = member(&self.space, x, &r);
                m.data = serde_json::to_value(&r).unwrap_or(Value::Null);
                m
            })
            .collect();
        self.search.tell(members);
        Ok(())
    }

    /// The search's front: its points and their screening records.
    pub fn screened_front(&self) -> Vec<(Vec<f64>, Record)> {
        let mut front = self.search.front();
        front.sort_by(crate::nsga2::order);
        front
            .into_iter()
            .filter_map(|m| {
                let r: Record = serde_json::from_value(m.data).ok()?;
                Some((m.x, r))
            })
            .collect()
    }

    /// The final front from the front's records at the final fidelity (for `beam`, the
    /// screening records themselves): the feasible, non-dominated ones, ordered by the
    /// first objective.
    pub fn front(&self, points: &[Vec<f64>], records: &[Record]) -> Vec<FrontEntry> {
        let members: Vec<Member> = points
            .iter()
            .zip(records)
            .map(|(x, r)| {
                let mut m = member(&self.space, x, r);
                m.data = serde_json::to_value(r).unwrap_or(Value::Null);
                m
            })
            .collect();
        let mut out: Vec<Member> = match crate::nsga2::fronts(&members).first() {
            Some(first) => first
                .iter()
                .map(|&i| members[i].clone())
                .filter(|m| m.cv == 0.0)
                .collect(),
            None => Vec::new(),
        };
        out.sort_by(crate::nsga2::order);
        out.into_iter()
            .filter_map(|m| {
                let r: Record = serde_json::from_value(m.data).ok()?;
                Some(FrontEntry {
                    variables: r.variables,
                    figures: r.figures?,
                })
            })
            .collect()
    }
}

/// Everything a worker needs to evaluate points of a study, as plain data: a Dask
/// worker receives this (as JSON) and a point, and returns the point's [`Record`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Task {
    /// The space.
    pub space: Space,
    /// The base description's text.
    pub base: String,
    /// Pre-tensioning approach, or the description's.
    pub approach: Option<u8>,
    /// Fidelity of these evaluations.
    pub fidelity: Fidelity,
    /// FEM mesh level.
    pub level: usize,
}

impl Task {
    /// Evaluates one point.
    pub fn evaluate(&self, x: &[f64], store: &dyn JointStore) -> Record {
        let options = EvalOptions {
            approach: self
                .approach
                .and_then(cellinject_model::Approach::from_number),
            fidelity: self.fidelity,
            level: self.level,
        };
        evaluate_point(&self.space, &self.base, x, &options, store)
    }
}

impl Study {
    /// The task of the search's screening (`final_step = false`) or of the front's
    /// final evaluation.
    pub fn task(&self, final_step: bool) -> Task {
        Task {
            space: self.space.clone(),
            base: self.base.clone(),
            approach: self.approach,
            fidelity: if final_step {
                self.fidelity
            } else {
                Fidelity::Beam
            },
            level: self.level,
        }
    }
}
