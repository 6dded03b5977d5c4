//! Batches of designs split into shards (`design evaluate --batch B --out R --shard I/N`)
//! and the shards' results joined again (`design merge`).
//!
//! A batch file has one `{"variables": {key: value}}` per line. Shard `I` of `N`
//! evaluates the contiguous lines `[I·M/N, (I+1)·M/N)` of the batch's `M` lines and
//! writes one `{"index": k, "variables": ..., "figures": ...}` per line (`"error"`
//! instead of `"figures"` when the evaluation failed), `k` the line's position in the
//! batch: nothing in a line depends on the shard, so the merged file equals the
//! unsharded one byte for byte.

use std::ops::Range;

use cellinject_config::overrides::Override;
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use crate::DesignError;
use crate::evaluate::{EvalOptions, Figures, evaluate};
use cellinject_fea::JointStore;

/// One design of a batch.
#[derive(Debug, Clone, PartialEq)]
pub struct Line {
    /// The line's variables as written.
    pub variables: Map<String, Value>,
    /// The same as overrides.
    pub overrides: Vec<Override>,
}

/// One result line.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResultLine {
    /// Position of the design in its batch (0-based).
    pub index: usize,
    /// The design's variables.
    pub variables: Map<String, Value>,
    /// Its figures.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub figures: Option<Figures>,
    /// Why it could not be evaluated.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub error: Option<String>,
}

/// A shard `I/N`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// Which, from 0.
    pub index: usize,
    /// Of how many.
    pub count: usize,
}

impl Shard {
    /// Parses `I/N` (0 ≤ I < N).
    pub fn parse(s: &str) -> Result<Shard, DesignError> {
        let bad = |reason: String| DesignError::Input {
            key: "--shard".into(),
            reason,
        };
        let (i, n) = s
            .split_once('/')
            .ok_or_else(|| bad(format!("`{s}` is not I/N (e.g. 0/4)")))?;
        let index: usize = i
            .trim()
            .parse()
            .map_err(|_| bad(format!("`{i}` is not a shard number")))?;
        let count: usize = n
            .trim()
            .parse()
            .map_err(|_| bad(format!("`{n}` is not a shard count")))?;
        if count == 0 || index >= count {
            return Err(bad(format!(
                "shard {index} of {count}: I runs from 0 to N-1 and N is at least 1"
            )));
        }
        Ok(Shard { index, count })
    }

    /// The lines of a batch of `m` this shard evaluates.
    pub fn range(&self, m: usize) -> Range<usize> {
        (self.index * m / self.count)..((self.index + 1) * m / self.count)
    }
}

/// Parses a batch file's text (`name` names it in errors).
pub fn parse(name: &str, text: &str) -> Result<Vec<Line>, DesignError> {
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let at = format!("{name} line {}", n + 1);
        if line.trim().is_empty() {
            continue;
        }
        let v: Value = serde_json::from_str(line).map_err(|e| DesignError::Input {
            key: at.clone(),
            reason: format!("not JSON: {e}"),
        })?;
        let vars = v
            .get("variables")
            .and_then(Value::as_object)
            .ok_or_else(|| DesignError::Input {
                key: at.clone(),
                reason: "expected {\"variables\": {key: value, ...}}".into(),
            })?;
        let mut overrides = Vec::new();
        for (k, x) in vars {
            let value = x.as_f64().ok_or_else(|| DesignError::Input {
                key: format!("{at}: {k}"),
                reason: format!("{x} is not a number"),
            })?;
            overrides.push(Override {
                key: k.clone(),
                value,
            });
        }
        out.push(Line {
            variables: vars.clone(),
            overrides,
        });
    }
    Ok(out)
}

/// Joins result files' texts (`(name, text)`), refusing a doubled index, a gap, or
/// (with `count`) a batch of another size; returns the lines sorted by index, each
/// as written.
pub fn merge(files: &[(String, String)], count: Option<usize>) -> Result<String, DesignError> {
    let mut lines: Vec<(usize, String, String)> = Vec::new();
    for (name, text) in files {
        for (n, line) in text.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            let at = format!("{name} line {}", n + 1);
            let r: ResultLine = serde_json::from_str(line).map_err(|e| DesignError::Input {
                key: at.clone(),
                reason: format!("not a result line of `design evaluate --batch`: {e}"),
            })?;
            lines.push((r.index, at, line.to_string()));
        }
    }
    lines.sort_by_key(|l| l.0);
    for w in lines.windows(2) {
        if w[0].0 == w[1].0 {
            return Err(DesignError::Input {
                key: w[1].1.clone(),
                reason: format!(
                    "index {} is also at {}: a shard was merged twice",
                    w[0].0, w[0].1
                ),
            });
        }
    }
    for (k, l) in lines.iter().enumerate() {
        if l.0 != k {
            return Err(DesignError::Input {
                key: "design merge".into(),
                reason: format!(
                    "index {k} is missing (the next is {} at {}): a shard is missing",
                    l.0, l.1
                ),
            });
        }
    }
    if let Some(m) = count
        && lines.len() != m
    {
        return Err(DesignError::Input {
            key: "--count".into(),
            reason: format!(
                "the batch has {m} designs, the results {}: a shard is missing",
                lines.len()
            ),
        });
    }
    let mut out = String::new();
    for (_, _, l) in lines {
        out.push_str(&l);
        out.push('\n');
    }
    Ok(out)
}

/// The descriptions of a batch's `lines` (from the file `name`): `base` with each line's
/// overrides, every line's keys checked before anything is computed; the error names
/// the line.
pub fn descriptions(base: &str, name: &str, lines: &[Line]) -> Result<Vec<String>, DesignError> {
    lines
        .iter()
        .enumerate()
        .map(|(k, l)| {
            cellinject_config::overrides::apply(base, &l.overrides).map_err(|e| {
                DesignError::Input {
                    key: format!("{name} design {k}"),
                    reason: e.to_string(),
                }
            })
        })
        .collect()
}

/// Evaluates the lines `range` of a batch (their descriptions `descs`), calling `done`
/// after each: a result line each, with the figures or why the design could not be
/// evaluated, and how many could not.
pub fn evaluate_lines(
    lines: &[Line],
    descs: &[String],
    range: Range<usize>,
    opts: &EvalOptions,
    store: &dyn JointStore,
    done: &dyn Fn(),
) -> (Vec<ResultLine>, usize) {
    let mut failed = 0;
    let out = range
        .map(|k| {
            let r = cellinject_config::parse(&descs[k])
                .map_err(DesignError::from)
                .and_then(|d| evaluate(&d, opts, store));
            let (figures, error) = match r {
                Ok(f) => (Some(f), None),
                Err(e) => {
                    failed += 1;
                    (None, Some(e.to_string()))
                }
            };
            done();
            ResultLine {
                index: k,
                variables: lines[k].variables.clone(),
                figures,
                error,
            }
        })
        .collect();
    (out, failed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_cover_a_batch_exactly_once() {
        for m in [0usize, 1, 5, 7, 100] {
            for n in 1..9 {
                let mut seen = vec![0; m];
                for i in 0..n {
                    for k in (Shard { index: i, count: n }).range(m) {
                        seen[k] += 1;
                    }
                }
                assert!(seen.iter().all(|&c| c == 1), "m {m} n {n}");
            }
        }
        assert!(Shard::parse("4/4").is_err());
        assert!(Shard::parse("0/0").is_err());
        assert!(Shard::parse("x").is_err());
        assert_eq!(Shard::parse("2/5").unwrap(), Shard { index: 2, count: 5 });
    }

    #[test]
    fn merge_refuses_gaps_and_doubles() {
        let l = |i: usize| format!("{{\"index\":{i},\"variables\":{{}},\"error\":\"x\"}}\n");
        let a = ("a".to_string(), l(0) + &l(1));
        let b = ("b".to_string(), l(2));
        let merged = merge(&[b.clone(), a.clone()], Some(3)).unwrap();
        assert_eq!(merged, l(0) + &l(1) + &l(2));
        assert!(
            merge(&[a.clone(), a.clone()], None)
                .unwrap_err()
                .to_string()
                .contains("twice")
        );
        assert!(
            merge(std::slice::from_ref(&b), None)
                .unwrap_err()
                .to_string()
                .contains("missing")
        );
        assert!(
            merge(&[a], Some(3))
                .unwrap_err()
                .to_string()
                .contains("missing")
        );
    }
}
