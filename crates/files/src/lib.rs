//! # cellinject-files
//!
//! Files a command writes: planned and checked before any computation, then written
//! together at the end, atomically.
//!
//! The rules (README, "Files"): a command never replaces a file it reads, nor one of its
//! own outputs with another; companion files share the stem of `--out` and carry their
//! own extensions; an image's format follows its extension; a file output's directory
//! must exist and be writable before the work starts; a command that fails leaves no
//! half-set of outputs behind (every file is staged as a temporary beside its target and
//! all are renamed only once all are written); a file an output takes the place of is
//! kept beside it as `NAME.~N~` when its contents would change, unless the front end
//! asked to replace without keeping ([`replace_existing`], the binary's `--force`).
//!
//! **Architecture invariant:** the only place a command's outputs are written; errors
//! say whether the user can fix them ([`FilesError::is_input`]).

use std::fs;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

/// Whether outputs replace the files in their way without keeping them.
static REPLACE: AtomicBool = AtomicBool::new(false);
/// The files kept so far ([`take_kept`] drains it).
static KEPT: Mutex<Vec<Kept>> = Mutex::new(Vec::new());

/// A file an output took the place of, kept beside it under a name that starts with
/// its own.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Kept {
    /// The file the output was written to.
    pub file: PathBuf,
    /// Where its previous contents are now: `file` + `.~N~`, N one more than the
    /// highest already there.
    pub kept_as: PathBuf,
}

/// Sets what outputs do to an existing file whose contents they would change: `false`
/// (the default) keeps it beside as `NAME.~N~` ([`Kept`]); `true` replaces it without
/// keeping it (the user asked: `--force`). A file with the same bytes is left as it is
/// either way (nothing would be lost).
pub fn replace_existing(replace: bool) {
    REPLACE.store(replace, Ordering::SeqCst);
}

/// The files kept beside their outputs since the last call, in the order written (a
/// front end says so once its command is done).
pub fn take_kept() -> Vec<Kept> {
    std::mem::take(&mut *KEPT.lock().unwrap_or_else(|e| e.into_inner()))
}

/// `path`'s numbered backup name with the number `n`: `NAME.~n~` beside it.
fn numbered(path: &Path, n: u32) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(format!(".~{n}~"));
    path.with_file_name(name)
}

/// The highest N of the `NAME.~N~` beside `path` (0 when there is none).
fn highest_kept(path: &Path) -> u32 {
    let (Some(dir), Some(name)) = (path.parent(), path.file_name()) else {
        return 0;
    };
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    let prefix = format!("{}.~", name.to_string_lossy());
    let Ok(entries) = fs::read_dir(dir) else {
        return 0;
    };
    entries
        .filter_map(|e| {
            let n = e.ok()?.file_name().to_string_lossy().into_owned();
            n.strip_prefix(&prefix)?
                .strip_suffix('~')?
                .parse::<u32>()
                .ok()
        })
        .max()
        .unwrap_or(0)
}

/// Whether the files `a` and `b` hold the same bytes (a missing one holds none).
fn same_bytes(a: &Path, b: &Path) -> bool {
    match (fs::metadata(a), fs::metadata(b)) {
        (Ok(x), Ok(y)) if x.len() == y.len() => {
            matches!((fs::read(a), fs::read(b)), (Ok(x), Ok(y)) if x == y)
        }
        _ => false,
    }
}

/// Keeps the file at `path` beside it as `NAME.~N~` (a hard link, else a copy) when
/// `staged` would change its contents; the name it is kept under, if it was.
fn keep_previous(path: &Path, staged: &Path) -> Result<Option<PathBuf>> {
    match fs::symlink_metadata(path) {
        Ok(m) if m.is_file() || m.file_type().is_symlink() => {}
        _ => return Ok(None),
    }
    if same_bytes(path, staged) {
        return Ok(None);
    }
    let mut n = highest_kept(path) + 1;
    loop {
        let to = numbered(path, n);
        let made = match fs::hard_link(path, &to) {
            Ok(()) => Ok(()),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                n += 1;
                continue;
            }
            // A file system without hard links: a copy (`create_new` keeps another
            // writer's backup of the same number; a copy left half-written is removed).
            Err(_) => fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&to)
                .and_then(|mut f| {
                    let copied = fs::read(path)
                        .and_then(|b| f.write_all(&b))
                        .and_then(|()| f.sync_all());
                    if copied.is_err() {
                        let _ = fs::remove_file(&to);
                    }
                    copied
                }),
        };
        return match made {
            Ok(()) => Ok(Some(to)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                n += 1;
                continue;
            }
            Err(source) => Err(FilesError::Write { path: to, source }),
        };
    }
}

/// Why a file could not be planned, written or encoded.
#[derive(Debug, thiserror::Error)]
pub enum FilesError {
    /// A path the user gave cannot be used as given (a wrong extension, a missing
    /// directory, an output on an input, ...): the message names the argument.
    #[error("{0}")]
    Invalid(String),
    /// A file could not be written (a full disk, a permission); nothing was replaced.
    #[error("cannot write `{}`: {source}", path.display())]
    Write {
        /// The file that was to be written.
        path: PathBuf,
        /// Why not.
        source: std::io::Error,
    },
    /// An image or a plot could not be encoded.
    #[error("{0}")]
    Encode(String),
}

impl FilesError {
    /// Whether the user can fix it (a command exits with 2 then, else with 1).
    pub fn is_input(&self) -> bool {
        !matches!(self, FilesError::Encode(_))
    }
}

/// A result of this crate.
pub type Result<T> = std::result::Result<T, FilesError>;

/// What a file holds, as its extension says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Comma-separated values (`.csv`).
    Csv,
    /// Scalable vector graphics (`.svg`).
    Svg,
    /// Portable network graphics (`.png`).
    Png,
    /// TIFF (`.tif`, `.tiff`).
    Tiff,
    /// JSON (`.json`).
    Json,
    /// Markdown (`.md`).
    Markdown,
    /// TOML (`.toml`).
    Toml,
    /// HTML (`.html`).
    Html,
    /// JSON lines (`.jsonl`): one JSON document per line.
    Jsonl,
}

impl Kind {
    /// The kind an extension names, if any.
    pub fn of(path: &Path) -> Option<Kind> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        Some(match ext.as_str() {
            "csv" => Kind::Csv,
            "svg" => Kind::Svg,
            "png" => Kind::Png,
            "tif" | "tiff" => Kind::Tiff,
            "json" => Kind::Json,
            "md" => Kind::Markdown,
            "toml" => Kind::Toml,
            "html" | "htm" => Kind::Html,
            "jsonl" => Kind::Jsonl,
            _ => return None,
        })
    }

    /// The extension written for this kind.
    pub fn extension(self) -> &'static str {
        match self {
            Kind::Csv => "csv",
            Kind::Svg => "svg",
            Kind::Png => "png",
            Kind::Tiff => "tif",
            Kind::Json => "json",
            Kind::Markdown => "md",
            Kind::Toml => "toml",
            Kind::Html => "html",
            Kind::Jsonl => "jsonl",
        }
    }
}

fn names(kinds: &[Kind]) -> String {
    let v: Vec<String> = kinds
        .iter()
        .map(|k| format!(".{}", k.extension()))
        .collect();
    v.join(" or ")
}

/// The absolute form of a path that may not exist yet: its directory resolved (links
/// followed), its file name kept; if the file exists, the file resolved too.
fn resolved(path: &Path) -> Option<PathBuf> {
    if let Ok(p) = fs::canonicalize(path) {
        return Some(p);
    }
    let name = path.file_name()?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    Some(fs::canonicalize(dir).ok()?.join(name))
}

/// One planned output.
#[derive(Debug, Clone)]
struct Planned {
    arg: String,
    path: PathBuf,
}

/// The outputs of one command, checked together before it computes anything.
#[derive(Debug, Default)]
pub struct Plan {
    outputs: Vec<Planned>,
    inputs: Vec<(String, PathBuf)>,
}

impl Plan {
    /// An empty plan.
    pub fn new() -> Self {
        Plan::default()
    }

    /// A file the command reads (`arg` names it in messages).
    pub fn input(&mut self, arg: &str, path: &Path) -> &mut Self {
        self.inputs.push((arg.to_string(), path.to_path_buf()));
        self
    }

    /// One output of one of `kinds` (its extension must name one).
    pub fn output(&mut self, arg: &str, path: &Path, kinds: &[Kind]) -> Result<PathBuf> {
        match Kind::of(path) {
            Some(k) if kinds.contains(&k) => {}
            _ => {
                return Err(FilesError::Invalid(format!(
                    "{arg} `{}`: give a {} file (the format follows the extension)",
                    path.display(),
                    names(kinds)
                )));
            }
        }
        self.outputs.push(Planned {
            arg: arg.to_string(),
            path: path.to_path_buf(),
        });
        Ok(path.to_path_buf())
    }

    /// Companion outputs: `out`'s stem with each of `kinds`' extensions. `out` must end
    /// in one of them (or have no extension); `--out loop.svg` and `--out loop.csv` both
    /// mean `loop.csv` + `loop.svg`.
    pub fn companions(&mut self, arg: &str, out: &Path, kinds: &[Kind]) -> Result<Vec<PathBuf>> {
        if out.extension().is_some() && !matches!(Kind::of(out), Some(k) if kinds.contains(&k)) {
            return Err(FilesError::Invalid(format!(
                "{arg} `{}`: this command writes {}; give a path ending in one of them",
                out.display(),
                names(kinds)
            )));
        }
        if out
            .file_stem()
            .is_none_or(|s| s.is_empty() || s.to_string_lossy().starts_with('.'))
        {
            return Err(FilesError::Invalid(format!(
                "{arg} `{}`: give a file name with a stem (e.g. `run.csv`)",
                out.display()
            )));
        }
        if out.is_dir() {
            return Err(FilesError::Invalid(format!(
                "{arg} `{}` is a directory; give a file name in it (e.g. `{}`)",
                out.display(),
                out.join(format!("out.{}", kinds[0].extension())).display()
            )));
        }
        Ok(kinds
            .iter()
            .map(|k| {
                let p = out.with_extension(k.extension());
                self.outputs.push(Planned {
                    arg: arg.to_string(),
                    path: p.clone(),
                });
                p
            })
            .collect())
    }

    /// Checks the plan: no two outputs on one path, no output on an input, every
    /// output's directory exists and is writable, no output is a directory.
    pub fn check(&self) -> Result<()> {
        let mut seen: Vec<(PathBuf, &Planned)> = Vec::new();
        for o in &self.outputs {
            let Some(r) = resolved(&o.path) else {
                let dir = o
                    .path
                    .parent()
                    .filter(|d| !d.as_os_str().is_empty())
                    .unwrap_or(Path::new("."));
                return Err(FilesError::Invalid(format!(
                    "{} `{}`: the directory `{}` does not exist (it is not created)",
                    o.arg,
                    o.path.display(),
                    dir.display()
                )));
            };
            if r.is_dir() {
                return Err(FilesError::Invalid(format!(
                    "{} `{}` is a directory; give a file name",
                    o.arg,
                    o.path.display()
                )));
            }
            if let Some((_, other)) = seen.iter().find(|(p, _)| *p == r) {
                return Err(FilesError::Invalid(format!(
                    "{} `{}` and {} `{}` are the same file: one would replace the other",
                    other.arg,
                    other.path.display(),
                    o.arg,
                    o.path.display()
                )));
            }
            for (arg, input) in &self.inputs {
                if resolved(input).as_ref() == Some(&r) || same_file(input, &r) {
                    return Err(FilesError::Invalid(format!(
                        "{} `{}` is the input {arg} `{}`: refusing to replace a file the command reads",
                        o.arg,
                        o.path.display(),
                        input.display()
                    )));
                }
            }
            writable(&r).map_err(|e| {
                FilesError::Invalid(format!(
                    "{} `{}`: cannot write in its directory: {e}",
                    o.arg,
                    o.path.display()
                ))
            })?;
            seen.push((r, o));
        }
        Ok(())
    }
}

/// Whether `a` and `b` are one existing file under two names (hard links: the same
/// device and inode), which their resolved paths do not tell apart.
fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt as _;
        match (fs::metadata(a), fs::metadata(b)) {
            (Ok(x), Ok(y)) => x.dev() == y.dev() && x.ino() == y.ino(),
            _ => false,
        }
    }
    #[cfg(not(unix))]
    {
        let _ = (a, b);
        false
    }
}

/// Whether a file can be created beside `path` (a probe file, removed at once).
fn writable(path: &Path) -> std::io::Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let probe = dir.join(format!(".cellinject-probe-{}", std::process::id()));
    fs::File::create(&probe)?;
    fs::remove_file(&probe)
}

fn temporary(path: &Path) -> PathBuf {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    dir.join(format!(".{name}.tmp-{}", std::process::id()))
}

/// Files written as temporaries beside their targets, renamed into place together by
/// [`Staged::commit`]; dropped uncommitted, the temporaries are removed and the targets
/// left as they were.
#[derive(Debug, Default)]
pub struct Staged {
    files: Vec<(PathBuf, PathBuf)>,
}

impl Staged {
    /// Nothing staged yet.
    pub fn new() -> Self {
        Staged::default()
    }

    /// Writes `bytes` to a temporary beside `path` and syncs it.
    pub fn add(&mut self, path: &Path, bytes: &[u8]) -> Result<()> {
        let tmp = temporary(path);
        let r = (|| {
            let mut f = fs::File::create(&tmp)?;
            f.write_all(bytes)?;
            f.sync_all()
        })();
        if let Err(e) = r {
            let _ = fs::remove_file(&tmp);
            return Err(FilesError::Write {
                path: path.to_path_buf(),
                source: e,
            });
        }
        self.files.push((tmp, path.to_path_buf()));
        Ok(())
    }

    /// Renames every temporary onto its target. A target that exists and would change
    /// is kept beside it first ([`Kept`], unless [`replace_existing`] says otherwise);
    /// returns what was kept.
    pub fn commit(mut self) -> Result<Vec<Kept>> {
        let files = std::mem::take(&mut self.files);
        let replace = REPLACE.load(Ordering::SeqCst);
        let mut kept = Vec::new();
        for (i, (tmp, path)) in files.iter().enumerate() {
            let keep = if replace {
                Ok(None)
            } else {
                keep_previous(path, tmp)
            };
            let renamed = keep.and_then(|k| {
                fs::rename(tmp, path).map_err(|e| FilesError::Write {
                    path: path.to_path_buf(),
                    source: e,
                })?;
                Ok(k)
            });
            match renamed {
                Ok(Some(to)) => kept.push(Kept {
                    file: path.to_path_buf(),
                    kept_as: to,
                }),
                Ok(None) => {}
                Err(e) => {
                    for (t, _) in &files[i..] {
                        let _ = fs::remove_file(t);
                    }
                    record(&kept);
                    return Err(e);
                }
            }
        }
        record(&kept);
        Ok(kept)
    }
}

/// Adds `kept` to what [`take_kept`] returns.
fn record(kept: &[Kept]) {
    if !kept.is_empty() {
        KEPT.lock()
            .unwrap_or_else(|e| e.into_inner())
            .extend_from_slice(kept);
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        for (tmp, _) in &self.files {
            let _ = fs::remove_file(tmp);
        }
    }
}

/// Writes one file atomically (temporary, sync, rename).
pub fn write_one(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut s = Staged::new();
    s.add(path, bytes)?;
    s.commit().map(|_| ())
}

/// Encodes an image in the format its path's extension names (PNG or TIFF).
pub fn encode_image<P, C>(img: &image::ImageBuffer<P, C>, path: &Path) -> Result<Vec<u8>>
where
    P: image::Pixel + image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
    C: std::ops::Deref<Target = [P::Subpixel]>,
{
    let format = match Kind::of(path) {
        Some(Kind::Png) => image::ImageFormat::Png,
        Some(Kind::Tiff) => image::ImageFormat::Tiff,
        _ => {
            return Err(FilesError::Invalid(format!(
                "`{}`: images are written as .png or .tif",
                path.display()
            )));
        }
    };
    let mut buf = std::io::Cursor::new(Vec::new());
    img.write_to(&mut buf, format)
        .map_err(|e| FilesError::Encode(format!("encoding `{}`: {e}", path.display())))?;
    Ok(buf.into_inner())
}

/// Writes a main file (`files[0]`: CSV, JSON, ...) with its plot as SVG (`files[1]`) and
/// PNG (`files[2]`), all together (`Staged`): the companions of `Plan::companions`.
pub fn write_with_plots(
    files: &[PathBuf],
    main: &[u8],
    charts: &[cellinject_plot::Chart],
    columns: usize,
) -> Result<()> {
    let (svg, rgb) = render(charts, columns)?;
    let mut staged = Staged::new();
    staged.add(&files[0], main)?;
    staged.add(&files[1], svg.as_bytes())?;
    staged.add(&files[2], &encode_rgb(rgb, &files[2])?)?;
    staged.commit().map(|_| ())
}

/// `charts` in so many `columns`, 720 x 480 each, as SVG and as an RGB image.
fn render(
    charts: &[cellinject_plot::Chart],
    columns: usize,
) -> Result<(String, cellinject_plot::Rgb)> {
    let size = (720, 480);
    let plot = |e| FilesError::Encode(format!("plot: {e}"));
    let svg = cellinject_plot::svg(charts, columns, size).map_err(plot)?;
    let rgb = cellinject_plot::rgb(charts, columns, size).map_err(plot)?;
    Ok((svg, rgb))
}

/// "wrote a, b and c" for the files a command wrote.
pub fn wrote(files: &[PathBuf]) -> String {
    let names: Vec<String> = files.iter().map(|f| f.display().to_string()).collect();
    match names.split_last() {
        None => "wrote nothing".into(),
        Some((last, [])) => format!("wrote {last}"),
        Some((last, rest)) => format!("wrote {} and {last}", rest.join(", ")),
    }
}

/// A rendered plot encoded in the format its path names (PNG or TIFF).
pub fn encode_rgb(rgb: cellinject_plot::Rgb, path: &Path) -> Result<Vec<u8>> {
    let img = image::RgbImage::from_raw(rgb.width, rgb.height, rgb.data)
        .ok_or_else(|| FilesError::Encode("plot buffer size".into()))?;
    encode_image(&img, path)
}

/// Refuses an output directory that cannot be made (a file in the way); nothing is
/// created yet, so a command that fails leaves nothing. `arg` names it in messages.
pub fn check_dir(arg: &str, dir: &Path) -> Result<()> {
    let mut p = Some(dir);
    while let Some(d) = p {
        if d.as_os_str().is_empty() || d.is_dir() {
            return Ok(());
        }
        if d.exists() {
            return Err(FilesError::Invalid(format!(
                "{arg} `{}`: `{}` is a file, not a directory",
                dir.display(),
                d.display()
            )));
        }
        p = d.parent();
    }
    Ok(())
}

/// Creates an output directory and its parents (when the outputs are ready to be
/// written), after [`check_dir`].
pub fn make_dir(arg: &str, dir: &Path) -> Result<()> {
    check_dir(arg, dir)?;
    fs::create_dir_all(dir).map_err(|e| {
        FilesError::Invalid(format!(
            "{arg}: cannot create the directory `{}`: {e}",
            dir.display()
        ))
    })
}

/// The files of one command under an output directory (`arg`, `--out`), written
/// together ([`Staged`]), their directories made as they are added; the paths written
/// are returned by [`Outputs::commit`], in order.
pub struct Outputs {
    arg: String,
    staged: Staged,
    written: Vec<PathBuf>,
}

impl Outputs {
    /// Nothing yet; `arg` names the output directory in messages.
    pub fn new(arg: &str) -> Self {
        Outputs {
            arg: arg.to_string(),
            staged: Staged::new(),
            written: Vec::new(),
        }
    }

    /// `path`, its directory made.
    pub fn add(&mut self, path: PathBuf, bytes: &[u8]) -> Result<()> {
        if let Some(dir) = path.parent() {
            make_dir(&self.arg, dir)?;
        }
        self.staged.add(&path, bytes)?;
        self.written.push(path);
        Ok(())
    }

    /// Each `(name, bytes)` of `files` as `dir/name.extension` (`dir` made only if
    /// there is any).
    pub fn add_named(
        &mut self,
        dir: &Path,
        files: Vec<(String, Vec<u8>)>,
        extension: &str,
    ) -> Result<()> {
        for (name, bytes) in files {
            self.add(dir.join(format!("{name}.{extension}")), &bytes)?;
        }
        Ok(())
    }

    /// `charts` (in so many `columns`) as `stem`.svg and `stem`.png.
    pub fn plots(
        &mut self,
        stem: &Path,
        charts: &[cellinject_plot::Chart],
        columns: usize,
    ) -> Result<()> {
        let (svg, rgb) = render(charts, columns)?;
        let png_path = stem.with_extension("png");
        let png = encode_rgb(rgb, &png_path)?;
        self.add(stem.with_extension("svg"), svg.as_bytes())?;
        self.add(png_path, &png)
    }

    /// Renames every file into place; the paths written.
    pub fn commit(self) -> Result<Vec<PathBuf>> {
        self.staged.commit()?;
        Ok(self.written)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    fn dir(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("cellinject-files-{tag}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&d);
        fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn companions_share_the_stem_and_collisions_are_refused() {
        let d = dir("companions");
        let mut p = Plan::new();
        let out = p
            .companions("--out", &d.join("loop.svg"), &[Kind::Csv, Kind::Svg])
            .unwrap();
        assert_eq!(out, vec![d.join("loop.csv"), d.join("loop.svg")]);
        p.check().unwrap();
        assert!(
            Plan::new()
                .companions("--out", &d.join("loop.txt"), &[Kind::Csv, Kind::Svg])
                .is_err()
        );
        // An output on an input, and two outputs on one file.
        let input = d.join("in.png");
        fs::write(&input, b"x").unwrap();
        let mut p = Plan::new();
        p.input("--reference", &input);
        p.output("--out", &d.join("./in.png"), &[Kind::Png])
            .unwrap();
        assert!(p.check().unwrap_err().to_string().contains("--reference"));
        // The input under another name (a hard link) is the input.
        #[cfg(unix)]
        {
            fs::hard_link(&input, d.join("link.png")).unwrap();
            let mut p = Plan::new();
            p.input("--reference", &input);
            p.output("--out", &d.join("link.png"), &[Kind::Png])
                .unwrap();
            let e = p.check().unwrap_err().to_string();
            assert!(
                e.contains("refusing to replace") && e.contains("link.png"),
                "{e}"
            );
        }
        let mut p = Plan::new();
        p.output("--reference", &d.join("a.png"), &[Kind::Png])
            .unwrap();
        p.output("--current", &d.join("a.png"), &[Kind::Png])
            .unwrap();
        assert!(p.check().unwrap_err().to_string().contains("same file"));
        // A missing directory is not created.
        let mut p = Plan::new();
        p.output("--out", &d.join("no/such/x.csv"), &[Kind::Csv])
            .unwrap();
        assert!(
            p.check()
                .unwrap_err()
                .to_string()
                .contains("does not exist")
        );
        assert!(!d.join("no").exists());
        // The format follows the extension.
        assert!(
            Plan::new()
                .output("--out", &d.join("f.jpg"), &[Kind::Png])
                .is_err()
        );
        fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn an_uncommitted_stage_leaves_the_targets_untouched() {
        let d = dir("staged");
        let a = d.join("a.csv");
        fs::write(&a, b"old").unwrap();
        {
            let mut s = Staged::new();
            s.add(&a, b"new").unwrap();
            s.add(&d.join("b.svg"), b"new").unwrap();
            // Dropped: the computation failed after staging.
        }
        assert_eq!(fs::read(&a).unwrap(), b"old");
        assert_eq!(fs::read_dir(&d).unwrap().count(), 1);
        let mut s = Staged::new();
        s.add(&a, b"new").unwrap();
        let kept = s.commit().unwrap();
        assert_eq!(fs::read(&a).unwrap(), b"new");
        // The previous contents kept beside it, under a name that starts with its own.
        let first = d.join("a.csv.~1~");
        assert_eq!(
            kept,
            vec![Kept {
                file: a.clone(),
                kept_as: first.clone()
            }]
        );
        assert_eq!(fs::read(&first).unwrap(), b"old");
        assert_eq!(fs::read_dir(&d).unwrap().count(), 2);
        fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_file_in_the_way_is_kept_under_the_next_number_unless_nothing_would_change() {
        let d = dir("kept");
        let a = d.join("plate.toml");
        let write = |bytes: &[u8]| {
            let mut s = Staged::new();
            s.add(&a, bytes).unwrap();
            s.commit().unwrap()
        };
        // No file in the way: nothing kept.
        assert!(write(b"one").is_empty());
        // The same bytes again: nothing would be lost, nothing kept.
        assert!(write(b"one").is_empty());
        // Other bytes: the previous version kept as .~1~, then .~2~; a gap or a
        // stranger's name does not confuse the numbering (the next is one more than the
        // highest).
        assert_eq!(write(b"two")[0].kept_as, d.join("plate.toml.~1~"));
        fs::write(d.join("plate.toml.~7~"), b"older").unwrap();
        fs::write(d.join("plate.toml.~x~"), b"not a number").unwrap();
        fs::write(d.join("other.toml.~9~"), b"another file's").unwrap();
        assert_eq!(write(b"three")[0].kept_as, d.join("plate.toml.~8~"));
        assert_eq!(fs::read(&a).unwrap(), b"three");
        assert_eq!(fs::read(d.join("plate.toml.~1~")).unwrap(), b"one");
        assert_eq!(fs::read(d.join("plate.toml.~8~")).unwrap(), b"two");
        assert_eq!(fs::read(d.join("plate.toml.~7~")).unwrap(), b"older");
        // What was kept is also there for the front end to say.
        let said = take_kept();
        assert!(
            said.iter().any(|k| k.kept_as == d.join("plate.toml.~8~")),
            "{said:?}"
        );
        fs::remove_dir_all(&d).unwrap();
    }
}
