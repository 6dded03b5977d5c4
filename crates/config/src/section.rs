//! Reading TOML tables key by key, remembering what was read so that the rest can be
//! reported as unknown.

use std::collections::BTreeSet;

use crate::ConfigError;

/// A table being read: remembers which keys were consumed so that the rest can be
/// reported as unknown.
pub(crate) struct Section<'a> {
    path: String,
    table: &'a toml::Table,
    used: BTreeSet<String>,
}

fn type_name(v: &toml::Value) -> &'static str {
    match v {
        toml::Value::String(_) => "a string",
        toml::Value::Integer(_) => "an integer",
        toml::Value::Float(_) => "a float",
        toml::Value::Boolean(_) => "a boolean",
        toml::Value::Datetime(_) => "a date",
        toml::Value::Array(_) => "an array",
        toml::Value::Table(_) => "a table",
    }
}

impl<'a> Section<'a> {
    pub(crate) fn root(table: &'a toml::Table) -> Self {
        Section {
            path: String::new(),
            table,
            used: BTreeSet::new(),
        }
    }

    pub(crate) fn key(&self, k: &str) -> String {
        if self.path.is_empty() {
            k.to_string()
        } else {
            format!("{}.{k}", self.path)
        }
    }

    pub(crate) fn get(&mut self, k: &str) -> Option<&'a toml::Value> {
        self.used.insert(k.to_string());
        self.table.get(k)
    }

    /// Whether the table sets `k` (without consuming it).
    pub(crate) fn has(&self, k: &str) -> bool {
        self.table.contains_key(k)
    }

    pub(crate) fn require(&mut self, k: &str) -> Result<&'a toml::Value, ConfigError> {
        self.get(k)
            .ok_or_else(|| ConfigError::Missing { key: self.key(k) })
    }

    pub(crate) fn to_number(&self, key: String, v: &toml::Value) -> Result<f64, ConfigError> {
        match v {
            toml::Value::Float(x) => Ok(*x),
            toml::Value::Integer(i) => Ok(*i as f64),
            other => Err(ConfigError::Type {
                key,
                expected: "a number".into(),
                found: type_name(other).into(),
            }),
        }
    }

    pub(crate) fn number(&mut self, k: &str) -> Result<f64, ConfigError> {
        let v = self.require(k)?;
        self.to_number(self.key(k), v)
    }

    pub(crate) fn opt_number(&mut self, k: &str) -> Result<Option<f64>, ConfigError> {
        match self.get(k) {
            None => Ok(None),
            Some(v) => self.to_number(self.key(k), v).map(Some),
        }
    }

    pub(crate) fn to_array<const N: usize>(
        &self,
        k: &str,
        v: &toml::Value,
    ) -> Result<[f64; N], ConfigError> {
        let key = self.key(k);
        let expected = format!("an array of {N} numbers");
        let toml::Value::Array(items) = v else {
            return Err(ConfigError::Type {
                key,
                expected,
                found: type_name(v).into(),
            });
        };
        if items.len() != N {
            return Err(ConfigError::Type {
                key,
                expected,
                found: format!("{} elements", items.len()),
            });
        }
        let mut out = [0.0; N];
        for (i, item) in items.iter().enumerate() {
            out[i] = self.to_number(format!("{key}[{i}]"), item)?;
        }
        Ok(out)
    }

    pub(crate) fn array<const N: usize>(&mut self, k: &str) -> Result<[f64; N], ConfigError> {
        let v = self.require(k)?;
        self.to_array(k, v)
    }

    pub(crate) fn opt_array<const N: usize>(
        &mut self,
        k: &str,
    ) -> Result<Option<[f64; N]>, ConfigError> {
        match self.get(k) {
            None => Ok(None),
            Some(v) => self.to_array(k, v).map(Some),
        }
    }

    pub(crate) fn string(&mut self, k: &str) -> Result<String, ConfigError> {
        match self.require(k)? {
            toml::Value::String(s) => Ok(s.clone()),
            other => Err(ConfigError::Type {
                key: self.key(k),
                expected: "a string".into(),
                found: type_name(other).into(),
            }),
        }
    }

    pub(crate) fn table(&mut self, k: &str) -> Result<Section<'a>, ConfigError> {
        match self.require(k)? {
            toml::Value::Table(t) => Ok(Section {
                path: self.key(k),
                table: t,
                used: BTreeSet::new(),
            }),
            other => Err(ConfigError::Type {
                key: self.key(k),
                expected: "a table".into(),
                found: type_name(other).into(),
            }),
        }
    }

    /// Refuses keys that were not read.
    pub(crate) fn finish(self) -> Result<(), ConfigError> {
        match self.unknown().into_iter().next() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// Every key of the table that was not read, as [`Section::finish`] refuses the
    /// first.
    pub(crate) fn unknown(&self) -> Vec<ConfigError> {
        self.table
            .keys()
            .filter(|k| !self.used.contains(k.as_str()))
            .map(|unknown| ConfigError::Unknown {
                key: self.key(unknown),
                expected: self.used.iter().cloned().collect::<Vec<_>>().join(", "),
            })
            .collect()
    }
}

/// The domain a number must lie in.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Check {
    /// Finite and > 0.
    Positive,
    /// Finite and ≥ 0.
    NonNegative,
    /// Finite and within [lo, hi].
    Between(f64, f64),
    /// An angle in radians within [lo, hi]; a value that reads as degrees is refused
    /// with the radians it would be.
    Angle(f64, f64),
}

impl Check {
    fn verify(self, key: &str, v: f64) -> Result<(), ConfigError> {
        let bad = |reason: String| {
            Err(ConfigError::Invalid {
                key: key.to_string(),
                reason: format!("{v} {reason}"),
            })
        };
        if !v.is_finite() {
            return bad("must be a finite number".into());
        }
        match self {
            Check::Positive if v <= 0.0 => bad("must be positive".into()),
            Check::NonNegative if v < 0.0 => bad("must not be negative".into()),
            Check::Between(lo, hi) if v < lo || v > hi => bad(format!("must lie in [{lo}, {hi}]")),
            Check::Angle(lo, hi) if v < lo || v > hi => {
                let degrees = if (1.0..=360.0).contains(&v.abs()) {
                    format!(" (radians, in SI: {v}° would be {:.4})", v.to_radians())
                } else {
                    String::new()
                };
                bad(format!("must lie in [{lo}, {hi}] rad{degrees}"))
            }
            _ => Ok(()),
        }
    }
}

impl<'a> Section<'a> {
    /// An optional number with a default, checked.
    pub(crate) fn num(&mut self, k: &str, default: f64, check: Check) -> Result<f64, ConfigError> {
        let v = self.opt_number(k)?.unwrap_or(default);
        check.verify(&self.key(k), v)?;
        Ok(v)
    }

    /// An optional array of numbers with a default, each checked.
    pub(crate) fn arr<const N: usize>(
        &mut self,
        k: &str,
        default: [f64; N],
        check: Check,
    ) -> Result<[f64; N], ConfigError> {
        let v = self.opt_array::<N>(k)?.unwrap_or(default);
        for (i, x) in v.iter().enumerate() {
            check.verify(&format!("{}[{i}]", self.key(k)), *x)?;
        }
        Ok(v)
    }

    /// An optional array of numbers without a default, each checked.
    pub(crate) fn opt_arr<const N: usize>(
        &mut self,
        k: &str,
        check: Check,
    ) -> Result<Option<[f64; N]>, ConfigError> {
        let Some(v) = self.opt_array::<N>(k)? else {
            return Ok(None);
        };
        for (i, x) in v.iter().enumerate() {
            check.verify(&format!("{}[{i}]", self.key(k)), *x)?;
        }
        Ok(Some(v))
    }

    /// An optional whole number with a default, within [min, max].
    pub(crate) fn int(
        &mut self,
        k: &str,
        default: u64,
        min: u64,
        max: u64,
    ) -> Result<u64, ConfigError> {
        let key = self.key(k);
        let v = match self.get(k) {
            None => default,
            Some(toml::Value::Integer(i)) if *i >= 0 => *i as u64,
            Some(other) => {
                return Err(ConfigError::Type {
                    key,
                    expected: "a whole number".into(),
                    found: match other {
                        toml::Value::Integer(i) => i.to_string(),
                        o => type_name(o).into(),
                    },
                });
            }
        };
        if v < min || v > max {
            return Err(ConfigError::Invalid {
                key,
                reason: format!("{v} must lie in [{min}, {max}]"),
            });
        }
        Ok(v)
    }

    /// An optional array of tables (`[[name]]`), each read as `name[i]`; empty if absent.
    pub(crate) fn tables(&mut self, k: &str) -> Result<Vec<Section<'a>>, ConfigError> {
        match self.get(k) {
            None => Ok(Vec::new()),
            Some(toml::Value::Array(items)) => items
                .iter()
                .enumerate()
                .map(|(i, v)| match v {
                    toml::Value::Table(t) => Ok(Section {
                        path: format!("{}[{i}]", self.key(k)),
                        table: t,
                        used: BTreeSet::new(),
                    }),
                    other => Err(ConfigError::Type {
                        key: format!("{}[{i}]", self.key(k)),
                        expected: "a table".into(),
                        found: type_name(other).into(),
                    }),
                })
                .collect(),
            Some(other) => Err(ConfigError::Type {
                key: self.key(k),
                expected: "an array of tables ([[...]])".into(),
                found: type_name(other).into(),
            }),
        }
    }

    /// A pair of whole numbers, each within `[0, max]`.
    pub(crate) fn index_pair(&mut self, k: &str) -> Result<[u32; 2], ConfigError> {
        let key = self.key(k);
        let v = self.require(k)?;
        let bad = |found: String| ConfigError::Type {
            key: key.clone(),
            expected: "an array of 2 whole numbers [row, col]".into(),
            found,
        };
        let toml::Value::Array(items) = v else {
            return Err(bad(type_name(v).into()));
        };
        if items.len() != 2 {
            return Err(bad(format!("{} elements", items.len())));
        }
        let mut out = [0u32; 2];
        for (i, item) in items.iter().enumerate() {
            match item {
                toml::Value::Integer(n) if (0..=i64::from(u32::MAX)).contains(n) => {
                    out[i] = *n as u32;
                }
                toml::Value::Integer(n) => return Err(bad(n.to_string())),
                other => return Err(bad(type_name(other).into())),
            }
        }
        Ok(out)
    }

    /// An optional sub-table.
    pub(crate) fn opt_table(&mut self, k: &str) -> Result<Option<Section<'a>>, ConfigError> {
        if self.table.contains_key(k) {
            self.table(k).map(Some)
        } else {
            self.used.insert(k.to_string());
            Ok(None)
        }
    }
}
