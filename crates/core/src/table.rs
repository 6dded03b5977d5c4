//! Numeric CSV tables read by their header, as loggers write them: the columns a
//! command needs are found by name, in any order; other columns are ignored (and
//! listed, so the front end can say so); every cell read must be a finite number,
//! and an error names the line and the column. The text is given: this module opens
//! no file.

use thiserror::Error;

/// Why a table could not be read. Lines count from 1, the header being line 1.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum TableError {
    /// No header line.
    #[error("empty: no header line (expected {expected})")]
    Empty {
        /// The columns needed, comma-separated.
        expected: String,
    },
    /// A needed column is not in the header.
    #[error("no column `{column}` in the header `{header}` (needs {expected})")]
    MissingColumn {
        /// The column.
        column: &'static str,
        /// The header as read.
        header: String,
        /// The columns needed, comma-separated.
        expected: String,
    },
    /// A name appears twice in the header.
    #[error("column `{column}` appears twice in the header (fields {first} and {second})")]
    DuplicateColumn {
        /// The name.
        column: String,
        /// Its first field, from 1.
        first: usize,
        /// Its second field, from 1.
        second: usize,
    },
    /// A row with another number of fields than the header.
    #[error("line {line}: {fields} fields, but the header has {header}")]
    Fields {
        /// Line.
        line: usize,
        /// Fields in the row.
        fields: usize,
        /// Fields in the header.
        header: usize,
    },
    /// A cell that is not a number.
    #[error("line {line}, column `{column}`: `{text}` is not a number")]
    NotANumber {
        /// Line.
        line: usize,
        /// Column.
        column: &'static str,
        /// The cell.
        text: String,
    },
    /// A cell that is NaN or infinite.
    #[error("line {line}, column `{column}`: `{text}` is not a finite number")]
    NotFinite {
        /// Line.
        line: usize,
        /// Column.
        column: &'static str,
        /// The cell.
        text: String,
    },
    /// A column that must not decrease (time) does.
    #[error(
        "line {line}, column `{column}`: {value} comes after {previous}: the rows must be in time order"
    )]
    Decreasing {
        /// Line.
        line: usize,
        /// Column.
        column: &'static str,
        /// The value.
        value: f64,
        /// The row before's.
        previous: f64,
    },
}

/// The columns read from a table.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    /// The needed columns then the optional ones present, each with its values.
    columns: Vec<(&'static str, Vec<f64>)>,
    /// The line of each row (blank lines are skipped).
    lines: Vec<usize>,
    /// The header's other columns, in the file's order.
    pub ignored: Vec<String>,
}

fn unquote(s: &str) -> &str {
    let s = s.trim();
    s.strip_prefix('"')
        .and_then(|s| s.strip_suffix('"'))
        .map_or(s, str::trim)
}

impl Table {
    /// What a command reading `needed` and `optional` columns says of the others, when
    /// there are any: "columns `a`, `b` ignored (this command reads `x`, `y`)".
    pub fn ignored_note(&self, needed: &[&str], optional: &[&str]) -> Option<String> {
        let quoted = |v: &mut dyn Iterator<Item = &str>| {
            v.map(|c| format!("`{c}`")).collect::<Vec<_>>().join(", ")
        };
        (!self.ignored.is_empty()).then(|| {
            format!(
                "column{} {} ignored (this command reads {})",
                if self.ignored.len() == 1 { "" } else { "s" },
                quoted(&mut self.ignored.iter().map(String::as_str)),
                quoted(&mut needed.iter().chain(optional).copied())
            )
        })
    }

    /// Reads `text`: a header line naming the columns, then one row per line (blank
    /// lines skipped), fields separated by commas (surrounding spaces and double quotes
    /// are dropped). `needed` columns must be present, `optional` ones may be.
    pub fn parse(
        text: &str,
        needed: &[&'static str],
        optional: &[&'static str],
    ) -> Result<Table, TableError> {
        let expected = needed.join(",");
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let mut lines = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty());
        let Some((_, header)) = lines.next() else {
            return Err(TableError::Empty { expected });
        };
        let names: Vec<&str> = header.split(',').map(unquote).collect();
        for (i, n) in names.iter().enumerate() {
            if let Some(j) = names[i + 1..].iter().position(|m| m == n) {
                return Err(TableError::DuplicateColumn {
                    column: n.to_string(),
                    first: i + 1,
                    second: i + j + 2,
                });
            }
        }
        let mut wanted = Vec::new();
        for &c in needed {
            let i =
                names
                    .iter()
                    .position(|n| *n == c)
                    .ok_or_else(|| TableError::MissingColumn {
                        column: c,
                        header: header.trim().to_string(),
                        expected: expected.clone(),
                    })?;
            wanted.push((c, i));
        }
        for &c in optional {
            if let Some(i) = names.iter().position(|n| *n == c) {
                wanted.push((c, i));
            }
        }
        let ignored = names
            .iter()
            .enumerate()
            .filter(|(i, _)| !wanted.iter().any(|(_, j)| j == i))
            .map(|(_, n)| n.to_string())
            .collect();
        let mut columns: Vec<(&'static str, Vec<f64>)> =
            wanted.iter().map(|(c, _)| (*c, Vec::new())).collect();
        let mut rows = Vec::new();
        for (k, line) in lines {
            let line_no = k + 1;
            let cells: Vec<&str> = line.split(',').collect();
            if cells.len() != names.len() {
                return Err(TableError::Fields {
                    line: line_no,
                    fields: cells.len(),
                    header: names.len(),
                });
            }
            for ((c, i), (_, col)) in wanted.iter().zip(columns.iter_mut()) {
                let text = unquote(cells[*i]);
                let v: f64 = text.parse().map_err(|_| TableError::NotANumber {
                    line: line_no,
                    column: c,
                    text: text.to_string(),
                })?;
                if !v.is_finite() {
                    return Err(TableError::NotFinite {
                        line: line_no,
                        column: c,
                        text: text.to_string(),
                    });
                }
                col.push(v);
            }
            rows.push(line_no);
        }
        Ok(Table {
            columns,
            lines: rows,
            ignored,
        })
    }

    /// The values of a column read (needed, or optional and present).
    pub fn column(&self, name: &str) -> Option<&[f64]> {
        self.columns
            .iter()
            .find(|(c, _)| *c == name)
            .map(|(_, v)| v.as_slice())
    }

    /// Rows.
    pub fn len(&self) -> usize {
        self.lines.len()
    }

    /// No rows.
    pub fn is_empty(&self) -> bool {
        self.lines.is_empty()
    }

    /// The line (from 1, the header's included) of row `row` (from 0).
    pub fn line(&self, row: usize) -> usize {
        self.lines.get(row).copied().unwrap_or(0)
    }

    /// Refuses a column (if present) whose values ever decrease, naming the line.
    pub fn non_decreasing(&self, name: &'static str) -> Result<(), TableError> {
        let Some(v) = self.column(name) else {
            return Ok(());
        };
        match v.windows(2).position(|w| w[1] < w[0]) {
            None => Ok(()),
            Some(k) => Err(TableError::Decreasing {
                line: self.line(k + 1),
                column: name,
                value: v[k + 1],
                previous: v[k],
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    #[test]
    fn the_ignored_columns_are_named_with_what_is_read() {
        let t = Table::parse("t,a,b,c\n0,1,2,3\n", &["a"], &["t", "z"]).unwrap();
        assert_eq!(
            t.ignored_note(&["a"], &["t", "z"]).as_deref(),
            Some("columns `b`, `c` ignored (this command reads `a`, `t`, `z`)")
        );
        let t = Table::parse("a,b\n1,2\n", &["a"], &[]).unwrap();
        assert_eq!(
            t.ignored_note(&["a"], &[]).as_deref(),
            Some("column `b` ignored (this command reads `a`)")
        );
        let t = Table::parse("a\n1\n", &["a"], &[]).unwrap();
        assert_eq!(t.ignored_note(&["a"], &[]), None);
    }

    const NEEDED: &[&str] = &["voltage_v", "displacement_m"];

    #[test]
    fn columns_are_found_by_name_in_any_order_and_the_others_listed() {
        let documented = "time_s,voltage_v,displacement_m\n0,1.5,2e-6\n0.001,2.5,3e-6\n\n";
        let swapped = "\u{feff}\"displacement_m\", temp_c ,time_s,\"voltage_v\",status\r\n2e-6,21.5,0,1.5,ok\r\n3e-6,21.6,0.001,\"2.5\",ok\r\n";
        let a = Table::parse(documented, NEEDED, &["time_s"]).unwrap();
        let b = Table::parse(swapped, NEEDED, &["time_s"]).unwrap();
        for c in ["time_s", "voltage_v", "displacement_m"] {
            assert_eq!(a.column(c), b.column(c), "{c}");
        }
        assert_eq!(a.len(), 2);
        assert!(a.ignored.is_empty());
        assert_eq!(b.ignored, ["temp_c", "status"]);
        assert_eq!(b.line(1), 3);
    }

    #[test]
    fn bad_cells_are_named_by_line_and_column() {
        let t = "time_s,voltage_v,displacement_m,note\n0,1,2e-6,a\n0.1,NaN,3e-6,b\n";
        let e = Table::parse(t, NEEDED, &[]).unwrap_err();
        assert_eq!(
            e,
            TableError::NotFinite {
                line: 3,
                column: "voltage_v",
                text: "NaN".into()
            }
        );
        assert!(e.to_string().contains("line 3, column `voltage_v`"), "{e}");
        let t = "voltage_v,displacement_m\n1,2e-6\n\n2,inf\n";
        let e = Table::parse(t, NEEDED, &[]).unwrap_err();
        assert!(
            e.to_string().starts_with("line 4, column `displacement_m`"),
            "{e}"
        );
        let e = Table::parse("voltage_v,displacement_m\n1,x\n", NEEDED, &[]).unwrap_err();
        assert!(matches!(e, TableError::NotANumber { line: 2, .. }), "{e}");
        let e = Table::parse("voltage_v\n1\n", NEEDED, &[]).unwrap_err();
        assert!(
            matches!(
                e,
                TableError::MissingColumn {
                    column: "displacement_m",
                    ..
                }
            ),
            "{e}"
        );
        let e = Table::parse("voltage_v,displacement_m\n1,2,3\n", NEEDED, &[]).unwrap_err();
        assert!(
            matches!(
                e,
                TableError::Fields {
                    line: 2,
                    fields: 3,
                    header: 2
                }
            ),
            "{e}"
        );
        let e = Table::parse("voltage_v,voltage_v,displacement_m\n", NEEDED, &[]).unwrap_err();
        assert!(
            matches!(
                e,
                TableError::DuplicateColumn {
                    first: 1,
                    second: 2,
                    ..
                }
            ),
            "{e}"
        );
        assert!(matches!(
            Table::parse("\n\n", NEEDED, &[]).unwrap_err(),
            TableError::Empty { .. }
        ));
        // Time may repeat (a coarse logger clock) but not go back.
        let t = Table::parse(
            "time_s,voltage_v,displacement_m\n0,1,0\n0,2,0\n0.5,3,0\n0.4,4,0\n",
            NEEDED,
            &["time_s"],
        )
        .unwrap();
        let e = t.non_decreasing("time_s").unwrap_err();
        assert!(matches!(e, TableError::Decreasing { line: 5, .. }), "{e}");
    }
}
