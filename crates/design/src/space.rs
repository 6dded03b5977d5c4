//! The space file of a design study: free variables (description keys with bounds),
//! objectives and constraints (figures of [`crate::Figures`]).
//!
//! ```toml
//! [variables]            # description keys and their bounds, SI units
//! "geometry.b2" = [0.10, 0.25]
//! "structure.throat_J3" = [1.2e-3, 2.4e-3]
//! [objectives]           # names of `design evaluate` figures
//! maximise = ["range_min_m", "first_mode_hz"]
//! minimise = ["coupling_m"]
//! [constraints]          # lower bounds on figures
//! min_safety_factor = 1.5
//! ```

use cellinject_config::overrides::{Override, apply};
use serde::{Deserialize, Serialize};

use crate::DesignError;
use crate::evaluate::FIGURES;

/// One free variable.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Variable {
    /// Description key (`geometry.b2`, `tension.preload[0]`).
    pub key: String,
    /// Lower bound.
    pub lo: f64,
    /// Upper bound.
    pub hi: f64,
}

/// One objective: a figure to maximise or minimise.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Objective {
    /// Figure name.
    pub figure: String,
    /// Larger is better.
    pub maximise: bool,
}

/// One constraint: a figure's lower bound.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Constraint {
    /// Figure name.
    pub figure: String,
    /// Lower bound, in the figure's unit.
    pub min: f64,
}

/// A parsed, checked space.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Space {
    /// The free variables, in file order.
    pub variables: Vec<Variable>,
    /// The objectives.
    pub objectives: Vec<Objective>,
    /// The constraints.
    pub constraints: Vec<Constraint>,
}

fn bad(key: impl Into<String>, reason: impl Into<String>) -> DesignError {
    DesignError::Input {
        key: key.into(),
        reason: reason.into(),
    }
}

fn figure_names() -> String {
    FIGURES
        .iter()
        .map(|(n, _)| *n)
        .collect::<Vec<_>>()
        .join(", ")
}

fn check_figure(key: &str, name: &str) -> Result<(), DesignError> {
    if FIGURES.iter().any(|(n, _)| *n == name) {
        Ok(())
    } else {
        Err(bad(
            key,
            format!(
                "`{name}` is not a figure of `design evaluate` (one of: {})",
                figure_names()
            ),
        ))
    }
}

fn number(key: &str, v: &toml::Value) -> Result<f64, DesignError> {
    match v {
        toml::Value::Float(x) => Ok(*x),
        toml::Value::Integer(i) => Ok(*i as f64),
        _ => Err(bad(key, "must be a number")),
    }
}

impl Space {
    /// Parses a space file's text and checks it against the description `base`
    /// (the variables must be keys it accepts, within their domain at both bounds).
    pub fn parse(text: &str, base: &str) -> Result<Space, DesignError> {
        let root: toml::Table = text
            .parse()
            .map_err(|e: toml::de::Error| bad("space", e.to_string().trim_end().to_string()))?;
        for k in root.keys() {
            if !["variables", "objectives", "constraints"].contains(&k.as_str()) {
                return Err(bad(
                    k.as_str(),
                    "unknown section (expected variables, objectives, constraints)",
                ));
            }
        }
        let table = |name: &str| -> Result<toml::Table, DesignError> {
            match root.get(name) {
                None => Ok(toml::Table::new()),
                Some(toml::Value::Table(t)) => Ok(t.clone()),
                Some(_) => Err(bad(name, "must be a table")),
            }
        };
        let mut variables = Vec::new();
        for (key, v) in &table("variables")? {
            let full = format!("variables.\"{key}\"");
            let bounds = match v {
                toml::Value::Array(a) if a.len() == 2 => {
                    [number(&full, &a[0])?, number(&full, &a[1])?]
                }
                _ => return Err(bad(&full, "bounds are written [low, high]")),
            };
            let [lo, hi] = bounds;
            if !(lo.is_finite() && hi.is_finite()) {
                return Err(bad(&full, "bounds must be finite"));
            }
            if lo >= hi {
                return Err(bad(
                    &full,
                    format!(
                        "empty or inverted bounds [{lo}, {hi}]: the low bound must be below the high one"
                    ),
                ));
            }
            if key.starts_with("flexures.") {
                return Err(bad(
                    &full,
                    "the joints' stiffness follows `[structure]`'s dimensions in a design study: vary structure.throat_J12, structure.throat_J3, structure.joint_radius, ... instead",
                ));
            }
            for x in [lo, hi] {
                apply(
                    base,
                    &[Override {
                        key: key.clone(),
                        value: x,
                    }],
                )
                .map_err(|e| bad(&full, format!("at {x}: {e}")))?;
            }
            variables.push(Variable {
                key: key.clone(),
                lo,
                hi,
            });
        }
        if variables.is_empty() {
            return Err(bad("variables", "names no free variable"));
        }
        let mut objectives = Vec::new();
        let obj = table("objectives")?;
        for (k, v) in &obj {
            let maximise = match k.as_str() {
                "maximise" | "maximize" => true,
                "minimise" | "minimize" => false,
                _ => {
                    return Err(bad(
                        format!("objectives.{k}"),
                        "unknown key (expected maximise, minimise)",
                    ));
                }
            };
            let list = match v {
                toml::Value::Array(a) => a,
                _ => {
                    return Err(bad(
                        format!("objectives.{k}"),
                        "must be a list of figure names",
                    ));
                }
            };
            for item in list {
                let name = item.as_str().ok_or_else(|| {
                    bad(format!("objectives.{k}"), "must be a list of figure names")
                })?;
                check_figure(&format!("objectives.{k}"), name)?;
                if objectives.iter().any(|o: &Objective| o.figure == name) {
                    return Err(bad(
                        format!("objectives.{k}"),
                        format!("`{name}` is named twice"),
                    ));
                }
                objectives.push(Objective {
                    figure: name.to_string(),
                    maximise,
                });
            }
        }
        if objectives.is_empty() {
            return Err(bad(
                "objectives",
                "names no objective (maximise = [...] or minimise = [...])",
            ));
        }
        // `safety_factors.J3 = 1.2` unquoted is a dotted TOML key: a nested table.
        let mut flat: Vec<(String, toml::Value)> = Vec::new();
        fn flatten(prefix: &str, t: &toml::Table, out: &mut Vec<(String, toml::Value)>) {
            for (k, v) in t {
                let name = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                match v {
                    toml::Value::Table(inner) => flatten(&name, inner, out),
                    other => out.push((name, other.clone())),
                }
            }
        }
        flatten("", &table("constraints")?, &mut flat);
        let mut constraints = Vec::new();
        for (k, v) in &flat {
            let key = format!("constraints.{k}");
            check_figure(&key, k)?;
            let min = number(&key, v)?;
            if !min.is_finite() {
                return Err(bad(&key, "must be a finite number"));
            }
            constraints.push(Constraint {
                figure: k.clone(),
                min,
            });
        }
        Ok(Space {
            variables,
            objectives,
            constraints,
        })
    }

    /// The overrides of a point.
    pub fn overrides(&self, x: &[f64]) -> Vec<Override> {
        self.variables
            .iter()
            .zip(x)
            .map(|(v, &value)| Override {
                key: v.key.clone(),
                value,
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cellinject_config::PROTOTYPE_TOML;

    #[test]
    fn the_issue_example_parses() {
        let s = Space::parse(
            "[variables]\n\"geometry.b2\" = [0.10, 0.25]\n\"structure.throat_J3\" = [1.2e-3, 2.4e-3]\n[objectives]\nmaximise = [\"range_min_m\", \"first_mode_hz\"]\n[constraints]\nmin_safety_factor = 1.5\n",
            PROTOTYPE_TOML,
        )
        .unwrap();
        assert_eq!(s.variables.len(), 2);
        assert_eq!(s.objectives.len(), 2);
        assert_eq!(s.constraints[0].min, 1.5);
    }

    #[test]
    fn bad_spaces_name_the_key() {
        let base = "[objectives]\nmaximise = [\"range_min_m\"]\n";
        for (text, says) in [
            ("[variables]\n\"geometry.b9\" = [0.1, 0.2]\n", "geometry.b9"),
            ("[variables]\n\"geometry.b2\" = [0.2, 0.1]\n", "inverted"),
            ("[variables]\n\"geometry.b2\" = [0.2, 0.2]\n", "geometry.b2"),
            ("[variables]\n\"geometry.b2\" = [0.2]\n", "[low, high]"),
            (
                "[variables]\n\"geometry.b2\" = [-0.2, 0.2]\n",
                "geometry.b2",
            ),
            ("[variables]\n\"flexures.J3\" = [100, 200]\n", "flexures.J3"),
            (
                "[variables]\n\"geometry.b2\" = [0.1, 0.2]\n[constraints]\nnosuch = 1\n",
                "constraints.nosuch",
            ),
            (
                "[variables]\n\"geometry.b2\" = [0.1, 0.2]\n[extra]\n",
                "extra",
            ),
        ] {
            let text = if text.contains("[objectives]") {
                text.to_string()
            } else {
                format!("{text}\n{base}")
            };
            let e = Space::parse(&text, PROTOTYPE_TOML).unwrap_err().to_string();
            assert!(e.contains(says), "{text}: {e}");
        }
        let e = Space::parse(
            "[variables]\n\"geometry.b2\" = [0.1, 0.2]\n[objectives]\nmaximise = [\"speed\"]\n",
            PROTOTYPE_TOML,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("objectives.maximise") && e.contains("speed"),
            "{e}"
        );
    }
}
