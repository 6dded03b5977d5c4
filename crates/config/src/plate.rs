//! The plate description file (TOML, SI units): the matrix feeder's grid, where it
//! sits on the stage, and (for the twin) the cells and debris in its wells.
//!
//! ```toml
//! [plate]                 # a well is the pitch x pitch square around its centre
//! rows = 4
//! cols = 6
//! pitch = 150e-6          # m between well centres
//! origin = [0.0, 0.0]     # m, stage coordinates of well [0, 0]
//! [[cell]]                # the twin's ground truth; the workflow never reads these
//! well = [0, 0]           # [row, col]
//! offset = [3e-6, -2e-6]  # m from the well centre (plate x along columns, y along rows)
//! diameter = 18e-6        # m
//! [[debris]]              # not cells (< 10 µm): never injected
//! well = [1, 2]
//! offset = [0.0, 4e-6]
//! diameter = 6e-6
//! ```

use std::fmt::Write as _;

use cellinject_plate::{Object, Plate, PlateError};

use crate::ConfigError;
use crate::section::Section;

/// Parses and validates a plate file's text ([`Plate::check`]): the first of
/// [`parse_all`]'s problems.
pub fn parse(text: &str) -> Result<Plate, ConfigError> {
    parse_all(text).map_err(|mut all| all.swap_remove(0))
}

/// `r`'s value, or `None` with its error added to `errors`.
fn keep<T>(r: Result<T, ConfigError>, errors: &mut Vec<ConfigError>) -> Option<T> {
    r.map_err(|e| errors.push(e)).ok()
}

/// [`parse`], with every problem of the file (`plate check`): each key that cannot be
/// read or is unknown, then, if the grid could be read, each object's and every
/// overlap ([`Plate::problems`]). Never an empty list.
pub fn parse_all(text: &str) -> Result<Plate, Vec<ConfigError>> {
    let root = crate::toml_table(text).map_err(|e| vec![e])?;
    let mut errors = Vec::new();
    let mut top = Section::root(&root);
    let grid = keep(top.table("plate"), &mut errors).and_then(|mut p| {
        let max = u64::from(cellinject_plate::MAX_SIDE);
        let rows = keep(p.int("rows", 0, 1, max), &mut errors);
        let cols = keep(p.int("cols", 0, 1, max), &mut errors);
        let pitch = keep(p.number("pitch"), &mut errors);
        let origin = keep(p.opt_array::<2>("origin"), &mut errors);
        errors.extend(p.unknown());
        Some((
            rows? as u32,
            cols? as u32,
            pitch?,
            origin?.unwrap_or([0.0, 0.0]),
        ))
    });
    // Each list's objects, and whether every one of them could be read.
    let mut objects = |name: &str, errors: &mut Vec<ConfigError>| -> (Vec<Object>, bool) {
        let Some(tables) = keep(top.tables(name), errors) else {
            return (Vec::new(), false);
        };
        let n = tables.len();
        let read: Vec<Object> = tables
            .into_iter()
            .filter_map(|mut t| {
                let well = keep(t.index_pair("well"), errors);
                let offset = keep(t.array::<2>("offset"), errors);
                let diameter = keep(t.number("diameter"), errors);
                errors.extend(t.unknown());
                Some(Object {
                    well: well?,
                    offset: offset?,
                    diameter: diameter?,
                })
            })
            .collect();
        let all = read.len() == n;
        (read, all)
    };
    let (cells, cells_read) = objects("cell", &mut errors);
    let (debris, debris_read) = objects("debris", &mut errors);
    // An object left unread shifts the indices of those after it: their own checks
    // wait until the file reads (the grid's are made either way).
    let all_read = cells_read && debris_read;
    errors.extend(top.unknown());
    let plate = grid.map(|(rows, cols, pitch, origin)| Plate {
        rows,
        cols,
        pitch,
        origin,
        cells,
        debris,
    });
    if let Some(p) = &plate {
        let checked = if all_read {
            p.clone()
        } else {
            Plate {
                cells: Vec::new(),
                debris: Vec::new(),
                ..p.clone()
            }
        };
        errors.extend(
            checked
                .problems()
                .into_iter()
                .map(|PlateError::Invalid { key, reason }| ConfigError::Invalid { key, reason }),
        );
    }
    match plate {
        Some(p) if errors.is_empty() => Ok(p),
        _ => Err(errors),
    }
}

/// A number as TOML: shortest round-trip form, `0.0` for zero.
fn num(x: f64) -> String {
    if x == 0.0 {
        "0.0".into()
    } else {
        format!("{x:e}")
    }
}

/// The plate as a description file that [`parse`] reads back exactly (numbers in
/// shortest round-trip form), headed by `comment` (one `#` line each).
pub fn to_toml(plate: &Plate, comment: &str) -> String {
    let mut s = String::new();
    for line in comment.lines() {
        let _ = writeln!(s, "# {line}");
    }
    let _ = writeln!(
        s,
        "# {} cells and {} pieces of debris in {} wells; SI units (m).",
        plate.cells.len(),
        plate.debris.len(),
        plate.wells()
    );
    let _ = writeln!(
        s,
        "\n[plate]                 # a well is the pitch x pitch square around its centre"
    );
    let _ = writeln!(s, "rows = {}", plate.rows);
    let _ = writeln!(s, "cols = {}", plate.cols);
    let _ = writeln!(
        s,
        "pitch = {}          # m between well centres",
        num(plate.pitch)
    );
    let _ = writeln!(
        s,
        "origin = [{}, {}]     # m, stage coordinates of well [0, 0]",
        num(plate.origin[0]),
        num(plate.origin[1])
    );
    for (name, list) in [("cell", &plate.cells), ("debris", &plate.debris)] {
        for o in list {
            let _ = writeln!(s, "\n[[{name}]]");
            let _ = writeln!(s, "well = [{}, {}]", o.well[0], o.well[1]);
            let _ = writeln!(s, "offset = [{}, {}]", num(o.offset[0]), num(o.offset[1]));
            let _ = writeln!(s, "diameter = {}", num(o.diameter));
        }
    }
    s
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use cellinject_plate::{GenerateOptions, generate};

    const EXAMPLE: &str = include_str!("../../../configs/example-plate.toml");

    fn key(text: &str) -> String {
        match parse(text) {
            Ok(_) => "ok".into(),
            Err(e) => e.key().unwrap_or("syntax").to_string(),
        }
    }

    #[test]
    fn the_issues_example_reads() {
        let p = parse(EXAMPLE).unwrap();
        assert_eq!(
            (p.rows, p.cols, p.cells.len(), p.debris.len()),
            (4, 6, 1, 1)
        );
        assert_eq!(p.cells[0].well, [0, 0]);
        assert_eq!(p.debris[0].diameter, 6e-6);
    }

    #[test]
    fn a_generated_plate_reads_back_exactly() {
        let p = generate(&GenerateOptions {
            rows: 5,
            cols: 7,
            seed: 3,
            ..GenerateOptions::default()
        })
        .unwrap();
        let text = to_toml(&p, "test plate");
        assert_eq!(parse(&text).unwrap(), p);
    }

    #[test]
    fn bad_files_name_the_key() {
        let swap = |a: &str, b: &str| EXAMPLE.replace(a, b);
        assert_eq!(
            key(&swap("offset = [3e-6", "offset = [70e-6")),
            "cell[0].offset"
        );
        assert_eq!(
            key(&swap("diameter = 18e-6", "diameter = -18e-6")),
            "cell[0].diameter"
        );
        assert_eq!(
            key(&swap("rows = 4", "rows = 4\ncolour = 1")),
            "plate.colour"
        );
        assert_eq!(
            key(&swap("well = [0, 0]", "well = [0, -1]")),
            "cell[0].well"
        );
        assert_eq!(key(&swap("well = [0, 0]", "well = [9, 0]")), "cell[0].well");
        assert_eq!(
            key(&swap("well = [0, 0]", "well = [0, 0]\nshape = 1")),
            "cell[0].shape"
        );
        assert_eq!(
            key(&swap("pitch = 150e-6", "pitch = \"wide\"")),
            "plate.pitch"
        );
        assert_eq!(key(&swap("[plate]", "[plates]")), "plate");
        assert_eq!(key(&swap("rows = 4", "rows = [4")), "syntax");
        // Two cells overlapping in one well.
        let two = format!(
            "{EXAMPLE}\n[[cell]]\nwell = [0, 0]\noffset = [10e-6, 0.0]\ndiameter = 12e-6\n"
        );
        assert_eq!(key(&two), "cell[1].offset");
        assert_eq!(key(&swap("[[debris]]", "[debris]")), "debris");
    }

    #[test]
    fn every_problem_of_a_file_is_listed_not_just_the_first() {
        // Three distinct faults: an unknown key, a cell reaching outside its well, a
        // negative diameter; and a fourth, an unknown section.
        let text = "[plate]\nrows = 2\ncols = 2\npitch = 150e-6\ncolour = \"red\"\n\
                    [[cell]]\nwell = [0, 0]\noffset = [70e-6, 0.0]\ndiameter = 20e-6\n\
                    [[cell]]\nwell = [1, 1]\noffset = [0.0, 0.0]\ndiameter = -20e-6\n\
                    [lid]\nclosed = true\n";
        let all = parse_all(text).unwrap_err();
        let keys: Vec<&str> = all.iter().map(|e| e.key().unwrap_or("syntax")).collect();
        assert_eq!(
            keys,
            ["plate.colour", "lid", "cell[0].offset", "cell[1].diameter"],
            "{all:?}"
        );
        // `parse` refuses the same file with the first of them.
        assert_eq!(parse(text).unwrap_err().key(), Some("plate.colour"));
        // A grid that cannot be read still lets the objects' keys be checked.
        let no_rows = "[plate]\ncols = 2\npitch = 150e-6\n[[cell]]\nwell = [0, 0]\noffset = [0.0]\ndiameter = 2e-5\n";
        let keys: Vec<String> = parse_all(no_rows)
            .unwrap_err()
            .iter()
            .map(|e| e.key().unwrap_or("syntax").to_string())
            .collect();
        assert_eq!(keys, ["plate.rows", "cell[0].offset"]);
        // An object that cannot be read shifts the indices after it: the others' checks
        // wait (never a fault named on the wrong object), the grid's are made.
        let unread = "[plate]\nrows = 2\ncols = 2\npitch = 150e-6\n\
                      [[cell]]\nwell = [0, 0]\noffset = [0.0, 0.0]\ndiameter = \"big\"\n\
                      [[cell]]\nwell = [1, 1]\noffset = [70e-6, 0.0]\ndiameter = 2e-5\n";
        let keys: Vec<String> = parse_all(unread)
            .unwrap_err()
            .iter()
            .map(|e| e.key().unwrap_or("syntax").to_string())
            .collect();
        assert_eq!(keys, ["cell[0].diameter"]);
        // A good file has none.
        assert!(parse_all(EXAMPLE).is_ok());
    }

    #[test]
    fn docs_plate_md_documents_the_example_that_is_read() {
        // The first TOML block of docs/plate.md is the example file's plate, and every
        // key its table documents is a key of that block.
        let doc = include_str!("../../../docs/plate.md");
        let block = doc
            .split("```toml\n")
            .nth(1)
            .and_then(|b| b.split("```").next())
            .unwrap();
        assert_eq!(parse(block).unwrap(), parse(EXAMPLE).unwrap());
        let table_keys: Vec<&str> = doc
            .lines()
            .filter_map(|l| l.strip_prefix("| `"))
            .filter_map(|l| l.split('`').next())
            .collect();
        assert!(table_keys.len() >= 8, "{table_keys:?}");
        for k in table_keys {
            let leaf = k.rsplit('.').next().unwrap();
            assert!(
                block
                    .lines()
                    .any(|l| l.trim_start().starts_with(&format!("{leaf} ="))),
                "`{k}` is documented but not in the example"
            );
        }
    }
}
