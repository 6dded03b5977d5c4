//! Frame files named on a command line (`cellinject dic track --frames`): every frame of
//! a folder, or those of `folder/pattern` matching a shell-like pattern (`*` any run,
//! `?` one character), sorted by name. A frame is what [`crate::FolderCamera`] takes
//! for one: a PNG or TIFF file whose name does not start with `.`.

use std::path::{Path, PathBuf};

/// The frames `spec` names: the frame files of the folder `spec`, or of its parent
/// whose names match its last component. The error says which folder could not be
/// read.
pub fn frame_files(spec: &Path) -> Result<Vec<PathBuf>, String> {
    let (dir, pattern) = if spec.is_dir() {
        (spec.to_path_buf(), None)
    } else {
        let dir = spec
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        let name = spec.file_name().and_then(|n| n.to_str()).unwrap_or("");
        (dir.to_path_buf(), Some(name.to_string()))
    };
    let entries = std::fs::read_dir(&dir)
        .map_err(|e| format!("cannot read directory `{}`: {e}", dir.display()))?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .filter(|p| {
            p.file_name().and_then(|n| n.to_str()).is_some_and(|n| {
                crate::is_frame(n) && pattern.as_deref().is_none_or(|pat| wildcard(pat, n))
            })
        })
        .collect();
    files.sort();
    Ok(files)
}

/// Whether `name` matches `pattern`: `*` any run of characters, `?` one.
pub fn wildcard(pattern: &str, name: &str) -> bool {
    let (p, n): (Vec<char>, Vec<char>) = (pattern.chars().collect(), name.chars().collect());
    let (mut i, mut j, mut star, mut mark) = (0, 0, None, 0);
    while j < n.len() {
        if i < p.len() && (p[i] == '?' || p[i] == n[j]) {
            i += 1;
            j += 1;
        } else if i < p.len() && p[i] == '*' {
            star = Some(i);
            mark = j;
            i += 1;
        } else if let Some(s) = star {
            i = s + 1;
            mark += 1;
            j = mark;
        } else {
            return false;
        }
    }
    while i < p.len() && p[i] == '*' {
        i += 1;
    }
    i == p.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wildcards_match_like_a_shell() {
        assert!(wildcard("*.png", "frame_001.png"));
        assert!(wildcard("frame_??1.png", "frame_001.png"));
        assert!(!wildcard("*.png", "frame_001.tif"));
        assert!(wildcard("*", "x"));
        assert!(!wildcard("a*b", "acd"));
        assert!(wildcard("a*b*c", "aXbYbZc"));
        assert!(!wildcard("?", ""));
    }

    #[test]
    fn a_folder_or_a_pattern_lists_its_frames_sorted_and_nothing_else() {
        let d = std::env::temp_dir().join(format!("cellinject-list-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        for n in [
            "b.png",
            "a.TIF",
            "c.tiff",
            ".hidden.png",
            "notes.txt",
            "d.png.part",
        ] {
            std::fs::write(d.join(n), b"x").unwrap();
        }
        std::fs::create_dir_all(d.join("sub.png")).unwrap();
        let names = |v: Vec<PathBuf>| -> Vec<String> {
            v.iter()
                .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
                .collect()
        };
        assert_eq!(
            names(frame_files(&d).unwrap()),
            ["a.TIF", "b.png", "c.tiff"]
        );
        assert_eq!(names(frame_files(&d.join("*.png")).unwrap()), ["b.png"]);
        let e = frame_files(&d.join("missing").join("*.png")).unwrap_err();
        assert!(
            e.contains("cannot read directory") && e.contains("missing"),
            "{e}"
        );
        std::fs::remove_dir_all(&d).unwrap();
    }
}
