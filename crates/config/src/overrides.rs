//! Description keys overridden by value: how a design study or a batch of designs
//! names its variables (`geometry.b2`, `structure.throat_J3`, `tension.preload[0]`).

use crate::ConfigError;

/// One overridden key: a dotted path into the description (`section.key`, with
/// `[i]` for one element of an array key) and its value in SI units. A plain number
/// given for an array key sets every element (`tension.preload = -80` loads both
/// stacks alike).
#[derive(Debug, Clone, PartialEq)]
pub struct Override {
    /// The dotted key.
    pub key: String,
    /// The value.
    pub value: f64,
}

/// The description `text` with `overrides` applied, as TOML text (comments dropped),
/// validated by [`crate::parse`] so that a key the description does not know, or a value
/// out of its domain, is refused naming the key. Numbers round-trip exactly.
pub fn apply(text: &str, overrides: &[Override]) -> Result<String, ConfigError> {
    let mut root = crate::toml_table(text)?;
    for o in overrides {
        set(&mut root, o)?;
    }
    let out = toml::to_string(&root).map_err(|e| ConfigError::Syntax {
        message: format!("writing the description with its overrides: {e}"),
    })?;
    crate::parse(&out)?;
    Ok(out)
}

fn bad(key: &str, reason: impl Into<String>) -> ConfigError {
    ConfigError::Invalid {
        key: key.to_string(),
        reason: reason.into(),
    }
}

/// Splits `a.b[2]` into (["a", "b"], Some(2)).
fn parse_key(key: &str) -> Result<(Vec<&str>, Option<usize>), ConfigError> {
    let (path, index) = match key.find('[') {
        None => (key, None),
        Some(open) => {
            let rest = &key[open + 1..];
            let close = rest.strip_suffix(']').ok_or_else(|| {
                bad(
                    key,
                    "an element is written `key[i]`, e.g. `tension.preload[0]`",
                )
            })?;
            let i = close
                .parse::<usize>()
                .map_err(|_| bad(key, format!("`{close}` is not an element index")))?;
            (&key[..open], Some(i))
        }
    };
    let parts: Vec<&str> = path.split('.').collect();
    if parts.len() < 2 || parts.iter().any(|p| p.is_empty()) {
        return Err(bad(
            key,
            "a description key is written `section.key`, e.g. `geometry.b2` or `structure.throat_J3`",
        ));
    }
    Ok((parts, index))
}

fn set(root: &mut toml::Table, o: &Override) -> Result<(), ConfigError> {
    if !o.value.is_finite() {
        return Err(bad(&o.key, format!("{} is not a finite number", o.value)));
    }
    let (parts, index) = parse_key(&o.key)?;
    let (last, tables) = parts.split_last().unwrap_or((&"", &[]));
    let mut table = root;
    for (n, part) in tables.iter().enumerate() {
        let entry = table
            .entry(part.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        table = match entry {
            toml::Value::Table(t) => t,
            _ => {
                return Err(bad(
                    &o.key,
                    format!("`{}` is not a section", parts[..=n].join(".")),
                ));
            }
        };
    }
    let value = toml::Value::Float(o.value);
    match (table.get_mut(*last), index) {
        (Some(toml::Value::Array(items)), Some(i)) => {
            let len = items.len();
            let slot = items.get_mut(i).ok_or_else(|| {
                bad(
                    &o.key,
                    format!("index {i} is past the array's {len} elements"),
                )
            })?;
            *slot = value;
        }
        (Some(toml::Value::Array(items)), None) => {
            for item in items.iter_mut() {
                *item = value.clone();
            }
        }
        (Some(toml::Value::Float(_) | toml::Value::Integer(_)), None) | (None, None) => {
            table.insert(last.to_string(), value);
        }
        (None, Some(_)) => {
            return Err(bad(
                &o.key,
                "the description does not set this array; give the whole key",
            ));
        }
        (Some(_), Some(_)) => return Err(bad(&o.key, "is not an array")),
        (Some(_), None) => return Err(bad(&o.key, "is not a number")),
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::PROTOTYPE_TOML;

    fn o(key: &str, value: f64) -> Override {
        Override {
            key: key.into(),
            value,
        }
    }

    #[test]
    fn overrides_reach_the_parsed_description() {
        let text = apply(
            PROTOTYPE_TOML,
            &[
                o("geometry.b2", 0.2),
                o("structure.throat_J3", 1.8e-3),
                o("tension.preload", -80.0),
                o("tension.work_shift[1]", -20e-6),
            ],
        )
        .unwrap();
        let d = crate::parse(&text).unwrap();
        assert_eq!(d.design.geometry.b2, 0.2);
        assert_eq!(d.structure.throat_j3, 1.8e-3);
        assert_eq!(d.design.tension.preload, [-80.0, -80.0]);
        assert_eq!(d.design.tension.work_shift, [-30e-6, -20e-6]);
        // Unchanged keys keep their exact values.
        assert_eq!(d.design, {
            let mut p = crate::prototype().design;
            p.geometry.b2 = 0.2;
            p.tension.preload = [-80.0, -80.0];
            p.tension.work_shift = [-30e-6, -20e-6];
            p
        });
    }

    #[test]
    fn unknown_keys_and_bad_values_are_refused_by_name() {
        for (key, value, says) in [
            ("geometry.b3", 0.1, "geometry.b3"),
            ("nosuch.key", 0.1, "nosuch"),
            ("geometry.b2", -0.1, "geometry.b2"),
            ("tension.preload[5]", 1.0, "tension.preload[5]"),
            ("b2", 0.1, "b2"),
            ("geometry.b2", f64::NAN, "geometry.b2"),
            ("name.x", 1.0, "name"),
        ] {
            let e = apply(PROTOTYPE_TOML, &[o(key, value)])
                .unwrap_err()
                .to_string();
            assert!(e.contains(says), "{key}: {e}");
        }
    }
}
