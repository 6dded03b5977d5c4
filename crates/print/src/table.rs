//! Numbers and tables for people: SI values in display units (µm, mrad, mN·m), fixed
//! decimals without a negative zero, and [`Table`], aligned text or Markdown.

/// How a quantity in an SI unit is shown to a person: (unit label, scale, decimals).
pub fn display_unit(si: &str) -> (&'static str, f64, usize) {
    match si {
        "m" => ("µm", 1e6, 3),
        "rad" => ("mrad", 1e3, 3),
        "N" => ("N", 1.0, 3),
        "N*m" => ("mN·m", 1e3, 1),
        "m/N" => ("µm/N", 1e6, 4),
        _ => (" ", 1.0, 6),
    }
}

/// `x` with `digits` decimals and no negative zero.
pub fn fixed(x: f64, digits: usize) -> String {
    let s = format!("{x:.digits$}");
    if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
        s[1..].to_string()
    } else {
        s
    }
}

/// A number in display units, with no negative zero.
pub fn number(x: f64, si: &str) -> String {
    let (_, scale, digits) = display_unit(si);
    let y = x * scale;
    let y = if y.abs() < 0.5 * 10f64.powi(-(digits as i32)) {
        0.0
    } else {
        y
    };
    format!("{y:.digits$}")
}

/// A vector in display units, `[a, b, c]`.
pub fn vector(v: &[f64], si: &str) -> String {
    let items: Vec<String> = v.iter().map(|x| number(*x, si)).collect();
    format!("[{}]", items.join(", "))
}

/// A simple table that renders as aligned text or as Markdown.
pub struct Table {
    header: Vec<String>,
    rows: Vec<Vec<String>>,
    right: Vec<bool>,
}

impl Table {
    /// A table with these column titles; `right[i]` right-aligns column i in text.
    pub fn new(header: &[&str], right: &[bool]) -> Self {
        Table {
            header: header.iter().map(|s| s.to_string()).collect(),
            rows: Vec::new(),
            right: right.to_vec(),
        }
    }

    /// Appends a row.
    pub fn row(&mut self, cells: Vec<String>) {
        self.rows.push(cells);
    }

    /// Aligned plain text with a rule under the header.
    pub fn text(&self) -> String {
        let n = self.header.len();
        let mut width: Vec<usize> = self.header.iter().map(|h| h.chars().count()).collect();
        for r in &self.rows {
            for (w, c) in width.iter_mut().zip(r) {
                *w = (*w).max(c.chars().count());
            }
        }
        let line = |cells: &[String]| {
            let mut s = String::new();
            for (i, c) in cells.iter().enumerate().take(n) {
                let pad = " ".repeat(width[i] - c.chars().count());
                if self.right.get(i).copied().unwrap_or(false) {
                    s.push_str(&pad);
                    s.push_str(c);
                } else {
                    s.push_str(c);
                    s.push_str(&pad);
                }
                s.push_str("  ");
            }
            s.trim_end().to_string() + "\n"
        };
        let mut out = line(&self.header);
        out.push_str(&"-".repeat(width.iter().sum::<usize>() + 2 * n.saturating_sub(1)));
        out.push('\n');
        for r in &self.rows {
            out.push_str(&line(r));
        }
        out
    }

    /// A GitHub-flavoured Markdown table.
    pub fn markdown(&self) -> String {
        let mut out = format!("| {} |\n", self.header.join(" | "));
        out.push_str(&format!("|{}\n", "---|".repeat(self.header.len())));
        for r in &self.rows {
            out.push_str(&format!("| {} |\n", r.join(" | ")));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_are_shown_in_display_units_without_negative_zero() {
        assert_eq!(number(-256.704e-6, "m"), "-256.704");
        assert_eq!(number(-1e-12, "m"), "0.000");
        assert_eq!(number(0.3164, "N*m"), "316.4");
        assert_eq!(vector(&[1e-3, -8.944e-3], "rad"), "[1.000, -8.944]");
    }

    #[test]
    fn tables_align_and_render_markdown() {
        let mut t = Table::new(&["a", "value"], &[false, true]);
        t.row(vec!["long name".into(), "1".into()]);
        assert_eq!(
            t.text(),
            "a          value\n----------------\nlong name      1\n"
        );
        assert_eq!(
            t.markdown(),
            "| a | value |\n|---|---|\n| long name | 1 |\n"
        );
    }
}
