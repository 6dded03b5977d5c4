//! The joint cache: solved double-notched joints kept on disk, so that a second
//! `cellinject fea` with the same joints reads them back instead of solving two 3-D
//! FEMs again.
//!
//! **This module is the only place in the crate that touches files.**
//!
//! # Key
//!
//! A [`JointKey`] holds everything a joint solve depends on: the joint's geometry (the
//! five [`DoubleNotch`] fields), the material's `E` and `ν` (not its yield strength,
//! which only the safety factors use), the [`JointMesh`] parameters, the mesh level,
//! this module's [`FORMAT_VERSION`] and the FEM's [`SOLUTION_ENCODING_VERSION`]. Its
//! canonical bytes ([`JointKey::to_bytes`]) are those values in that order as
//! little-endian `u64`s (counts, versions) and `f64` bit patterns; the entry's file name
//! is `joint-v{FORMAT_VERSION}-{hash:016x}.bin` with `hash` the 64-bit FNV-1a of those
//! bytes ([`fnv1a64`]).
//!
//! # Entry
//!
//! | bytes | content |
//! |---|---|
//! | 8 | magic `CIFEAJNT` |
//! | 4 | [`FORMAT_VERSION`], `u32` little-endian |
//! | 4 | length `k` of the key, `u32` |
//! | k | the key's canonical bytes, in full |
//! | 8 | length `n` of the payload, `u64` |
//! | 8 | FNV-1a 64 checksum of the payload, `u64` |
//! | n | payload: [`JointSolution::to_bytes`] |
//!
//! An entry is served only if every check holds: magic, version, the full key equal to
//! the one asked for (so a hash collision is detected, not served), the payload length
//! equal to what is left of the file (truncation), the checksum, and the payload's own
//! decoding. Anything else is reported as [`CacheLookup::Corrupt`], and the caller
//! recomputes and overwrites the entry ([`solve_cached`]).
//!
//! Writes are atomic: the entry is written to a temporary file in the same directory,
//! flushed, then renamed over the final name, so a reader sees either no entry or a
//! whole one, and concurrent writers of the same entry do not interfere. A missing
//! directory is created on the first write; one that cannot be created or written is
//! not an error: the joint is computed and the report says `"unwritable"`.
//!
//! **Bump [`FORMAT_VERSION`]** whenever the entry layout, the key, or the joint FEM's
//! results change (a new element, mesh rule, stress recovery...): old entries are then
//! never read again (they have another file name and version).

use std::ffi::OsString;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use cellinject_fem::FemError;
use cellinject_fem::joint3d::{
    self, DoubleNotch, JointMesh, JointSolution, JointWorkspace, SOLUTION_ENCODING_VERSION,
};
use cellinject_flexure::Material;
use serde::Serialize;

/// Version of the cache's key and entry layout, and of the joint FEM whose results it
/// holds. Bump it whenever any of them changes.
pub const FORMAT_VERSION: u32 = 1;

/// Magic bytes that open an entry.
const MAGIC: [u8; 8] = *b"CIFEAJNT";

/// Bytes of an entry before the key.
const HEAD: usize = 8 + 4 + 4;

/// 64-bit FNV-1a hash of `bytes` (Fowler, Noll, Vo; offset basis 0xcbf29ce484222325,
/// prime 0x100000001b3).
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    const OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    let mut h = OFFSET;
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(PRIME);
    }
    h
}

/// Everything one joint solve depends on: the identity of a cache entry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointKey {
    /// The joint's dimensions.
    pub joint: DoubleNotch,
    /// Pa, Young's modulus.
    pub youngs: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// The mesh parameters.
    pub mesh: JointMesh,
    /// The mesh refinement level.
    pub level: usize,
}

impl JointKey {
    /// The key of solving `joint` in `material` on `mesh` at `level`.
    pub fn new(joint: &DoubleNotch, material: &Material, mesh: &JointMesh, level: usize) -> Self {
        JointKey {
            joint: *joint,
            youngs: material.youngs,
            poisson: material.poisson,
            mesh: *mesh,
            level,
        }
    }

    /// The key's canonical bytes (see the module documentation): the versions, then
    /// every field, as little-endian `u64`s and `f64` bit patterns.
    pub fn to_bytes(&self) -> Vec<u8> {
        let j = &self.joint;
        let m = &self.mesh;
        let words: [u64; 15] = [
            u64::from(FORMAT_VERSION),
            SOLUTION_ENCODING_VERSION,
            j.side.to_bits(),
            j.radius.to_bits(),
            j.flat.to_bits(),
            j.throat.to_bits(),
            j.gap.to_bits(),
            self.youngs.to_bits(),
            self.poisson.to_bits(),
            m.across as u64,
            m.notch as u64,
            m.block as u64,
            m.gap as u64,
            m.grading.to_bits(),
            self.level as u64,
        ];
        words.iter().flat_map(|w| w.to_le_bytes()).collect()
    }

    /// FNV-1a 64 of the canonical bytes.
    pub fn hash(&self) -> u64 {
        fnv1a64(&self.to_bytes())
    }

    /// The entry's file name, `joint-v{FORMAT_VERSION}-{hash:016x}.bin`.
    pub fn file_name(&self) -> String {
        format!("joint-v{FORMAT_VERSION}-{:016x}.bin", self.hash())
    }

    /// Solves the joint (the 3-D FEM), ignoring any cache.
    pub fn solve(&self) -> Result<JointSolution, FemError> {
        self.solve_in(&mut JointWorkspace::default())
    }

    /// [`JointKey::solve`] in `workspace` (memory shared by the joints solved in turn:
    /// [`JointWorkspace`]).
    pub fn solve_in(&self, workspace: &mut JointWorkspace) -> Result<JointSolution, FemError> {
        let material = Material {
            youngs: self.youngs,
            poisson: self.poisson,
            // Not used by the FEM; not part of the key.
            yield_strength: f64::NAN,
        };
        joint3d::solve_in(&self.joint, &material, &self.mesh, self.level, workspace)
    }
}

/// What a [`JointStore`] found for a key.
#[derive(Debug, Clone)]
pub enum CacheLookup {
    /// No cache is in use.
    Off,
    /// No entry for the key.
    Miss,
    /// A valid entry.
    Hit(Box<JointSolution>),
    /// An entry that failed its checks: why. Never to be trusted.
    Corrupt(String),
    /// The entry exists but could not be read: why.
    Unreadable(String),
}

/// Where solved joints are kept.
pub trait JointStore {
    /// The entry for `key`, checked.
    fn load(&self, key: &JointKey) -> CacheLookup;
    /// Keeps `solution` as the entry for `key`, replacing any entry there.
    fn store(&self, key: &JointKey, solution: &JointSolution) -> std::io::Result<()>;
    /// Whether an entry for `key` is there (not checked: for estimates only).
    fn has(&self, _key: &JointKey) -> bool {
        false
    }
}

/// The joint cache every front end uses: the platform's directory
/// ([`DirCache::default_location`]) when `use_cache` and there is one, else
/// [`NoCache`].
pub fn default_store(use_cache: bool) -> Box<dyn JointStore + Send + Sync> {
    match DirCache::default_location() {
        Some(dir) if use_cache => Box::new(DirCache::new(dir)),
        _ => Box::new(NoCache),
    }
}

/// No cache: every joint is solved, nothing is read or written.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoCache;

impl JointStore for NoCache {
    fn load(&self, _key: &JointKey) -> CacheLookup {
        CacheLookup::Off
    }

    fn store(&self, _key: &JointKey, _solution: &JointSolution) -> std::io::Result<()> {
        Ok(())
    }
}

/// A cache directory: one file per joint solve.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DirCache {
    dir: PathBuf,
}

/// Distinguishes the temporary files of concurrent writers within one process.
static TEMP_COUNTER: AtomicU64 = AtomicU64::new(0);

impl DirCache {
    /// A cache in `dir` (created on the first write if missing).
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        DirCache { dir: dir.into() }
    }

    /// The platform's cache directory for cellinject: `$XDG_CACHE_HOME/cellinject` if
    /// `XDG_CACHE_HOME` is set and not empty, else the platform cache directory
    /// (`~/.cache`, `~/Library/Caches`, `%LOCALAPPDATA%`) followed by `cellinject`;
    /// `None` if there is none.
    pub fn default_location() -> Option<PathBuf> {
        location(std::env::var_os("XDG_CACHE_HOME"), dirs::cache_dir())
    }

    /// The directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The file of `key`'s entry.
    pub fn path_of(&self, key: &JointKey) -> PathBuf {
        self.dir.join(key.file_name())
    }
}

/// [`DirCache::default_location`] from the environment variable's value and the
/// platform directory.
fn location(xdg_cache_home: Option<OsString>, platform: Option<PathBuf>) -> Option<PathBuf> {
    match xdg_cache_home {
        Some(x) if !x.is_empty() => Some(PathBuf::from(x).join("cellinject")),
        _ => platform.map(|p| p.join("cellinject")),
    }
}

impl JointStore for DirCache {
    fn has(&self, key: &JointKey) -> bool {
        self.path_of(key).is_file()
    }

    fn load(&self, key: &JointKey) -> CacheLookup {
        let path = self.path_of(key);
        let bytes = match fs::read(&path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return CacheLookup::Miss,
            Err(e) => return CacheLookup::Unreadable(format!("{}: {e}", path.display())),
        };
        match decode_entry(key, &bytes) {
            Ok(payload) => match JointSolution::from_bytes(payload) {
                Ok(s) => CacheLookup::Hit(Box::new(s)),
                Err(e) => CacheLookup::Corrupt(format!("{}: {e}", path.display())),
            },
            Err(why) => CacheLookup::Corrupt(format!("{}: {why}", path.display())),
        }
    }

    fn store(&self, key: &JointKey, solution: &JointSolution) -> std::io::Result<()> {
        fs::create_dir_all(&self.dir)?;
        let entry = encode_entry(key, &solution.to_bytes());
        let name = key.file_name();
        let temp = self.dir.join(format!(
            ".{name}.tmp-{}-{}",
            std::process::id(),
            TEMP_COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        let written = (|| {
            let mut f = fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&temp)?;
            f.write_all(&entry)?;
            f.sync_all()?;
            fs::rename(&temp, self.dir.join(&name))
        })();
        if written.is_err() {
            let _ = fs::remove_file(&temp);
        }
        written
    }
}

/// An entry's bytes for `key` and `payload`.
pub(crate) fn encode_entry(key: &JointKey, payload: &[u8]) -> Vec<u8> {
    let k = key.to_bytes();
    let mut out = Vec::with_capacity(HEAD + k.len() + 16 + payload.len());
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&(k.len() as u32).to_le_bytes());
    out.extend_from_slice(&k);
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&fnv1a64(payload).to_le_bytes());
    out.extend_from_slice(payload);
    out
}

/// The payload of an entry, if the entry is whole and belongs to `key`; else why not.
pub(crate) fn decode_entry<'a>(key: &JointKey, bytes: &'a [u8]) -> Result<&'a [u8], String> {
    let word = |at: usize, n: usize| -> Option<u64> {
        let s = bytes.get(at..at.checked_add(n)?)?;
        let mut b = [0u8; 8];
        b[..n].copy_from_slice(s);
        Some(u64::from_le_bytes(b))
    };
    if bytes.len() < HEAD {
        return Err(format!("truncated: {} bytes, no header", bytes.len()));
    }
    if bytes[..8] != MAGIC {
        return Err("not a cellinject joint entry (wrong magic)".into());
    }
    let version = word(8, 4).unwrap_or(0);
    if version != u64::from(FORMAT_VERSION) {
        return Err(format!(
            "format version {version}, expected {FORMAT_VERSION}"
        ));
    }
    let k = key.to_bytes();
    let key_len = word(12, 4).unwrap_or(0) as usize;
    let stored = bytes
        .get(HEAD..HEAD + key_len)
        .ok_or_else(|| format!("truncated: {} bytes, in the key", bytes.len()))?;
    if stored != k.as_slice() {
        return Err("the entry belongs to another joint (key mismatch)".into());
    }
    let at = HEAD + key_len;
    let (Some(len), Some(sum)) = (word(at, 8), word(at + 8, 8)) else {
        return Err(format!(
            "truncated: {} bytes, in the payload header",
            bytes.len()
        ));
    };
    let payload = &bytes[at + 16..];
    if payload.len() as u64 != len {
        return Err(format!(
            "payload of {} bytes where the header says {len} (truncated or extended)",
            payload.len()
        ));
    }
    let actual = fnv1a64(payload);
    if actual != sum {
        return Err(format!(
            "payload checksum {actual:016x}, header says {sum:016x}"
        ));
    }
    Ok(payload)
}

/// How the cache served one joint, as the reports give it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum CacheStatus {
    /// No cache in use (`--no-cache`, or no cache directory on this platform).
    #[serde(rename = "off")]
    Off,
    /// Read from the cache.
    #[serde(rename = "hit")]
    Hit,
    /// Not in the cache: solved and stored.
    #[serde(rename = "miss")]
    Miss,
    /// The entry failed its checks: solved again and overwritten.
    #[serde(rename = "recomputed (corrupt entry)")]
    Recomputed,
    /// Solved, but the cache directory could not be created or written.
    #[serde(rename = "unwritable")]
    Unwritable,
}

impl CacheStatus {
    /// The string the reports carry.
    pub fn as_str(self) -> &'static str {
        match self {
            CacheStatus::Off => "off",
            CacheStatus::Hit => "hit",
            CacheStatus::Miss => "miss",
            CacheStatus::Recomputed => "recomputed (corrupt entry)",
            CacheStatus::Unwritable => "unwritable",
        }
    }
}

impl std::fmt::Display for CacheStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// How one joint was obtained.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CacheUse {
    /// Hit, miss, ...
    pub status: CacheStatus,
    /// Why an entry was refused or could not be written (file and reason).
    pub detail: Option<String>,
}

/// The joint of `key`: from `store` if it holds a valid entry, else solved and stored
/// (overwriting a corrupt entry). A store that cannot be written is not an error.
pub fn solve_cached(
    store: &dyn JointStore,
    key: &JointKey,
) -> Result<(JointSolution, CacheUse), FemError> {
    solve_cached_in(store, key, &mut JointWorkspace::default())
}

/// [`solve_cached`], a solve made in `workspace` ([`JointWorkspace`]).
pub fn solve_cached_in(
    store: &dyn JointStore,
    key: &JointKey,
    workspace: &mut JointWorkspace,
) -> Result<(JointSolution, CacheUse), FemError> {
    let (status, detail) = match store.load(key) {
        CacheLookup::Hit(s) => {
            return Ok((
                *s,
                CacheUse {
                    status: CacheStatus::Hit,
                    detail: None,
                },
            ));
        }
        CacheLookup::Off => {
            let s = key.solve_in(workspace)?;
            return Ok((
                s,
                CacheUse {
                    status: CacheStatus::Off,
                    detail: None,
                },
            ));
        }
        CacheLookup::Miss => (CacheStatus::Miss, None),
        CacheLookup::Unreadable(why) => (CacheStatus::Miss, Some(why)),
        CacheLookup::Corrupt(why) => (CacheStatus::Recomputed, Some(why)),
    };
    let s = key.solve_in(workspace)?;
    let used = match store.store(key, &s) {
        Ok(()) => CacheUse { status, detail },
        Err(e) => CacheUse {
            status: CacheStatus::Unwritable,
            detail: Some(match detail {
                Some(d) => format!("{d}; writing: {e}"),
                None => format!("writing: {e}"),
            }),
        },
    };
    Ok((s, used))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(throat: f64) -> JointKey {
        JointKey::new(
            &DoubleNotch {
                side: 13.99e-3,
                radius: 2e-3,
                flat: 2.31e-3,
                throat,
                gap: 2e-3,
            },
            &Material::x2crni18_9(),
            &JointMesh::default(),
            1,
        )
    }

    #[test]
    fn fnv1a_matches_the_published_test_vectors() {
        // From the FNV reference (Noll's test suite).
        assert_eq!(fnv1a64(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a64(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a64(b"foobar"), 0x8594_4171_f739_67e8);
    }

    #[test]
    fn every_field_of_the_key_changes_the_file_name() {
        let base = key(1.2e-3);
        assert_eq!(base.file_name(), key(1.2e-3).file_name());
        assert!(
            base.file_name()
                .starts_with(&format!("joint-v{FORMAT_VERSION}-"))
        );
        assert_eq!(base.to_bytes().len(), 15 * 8);
        let mut variants = vec![key(2.0e-3)];
        let mut k = base;
        k.joint.side *= 1.0 + f64::EPSILON;
        variants.push(k);
        for f in [
            |k: &mut JointKey| k.joint.radius = 1e-3,
            |k: &mut JointKey| k.joint.flat = 0.0,
            |k: &mut JointKey| k.joint.gap = 1e-3,
            |k: &mut JointKey| k.youngs = 200e9,
            |k: &mut JointKey| k.poisson = 0.29,
            |k: &mut JointKey| k.mesh.across = 5,
            |k: &mut JointKey| k.mesh.notch = 13,
            |k: &mut JointKey| k.mesh.block = 4,
            |k: &mut JointKey| k.mesh.gap = 3,
            |k: &mut JointKey| k.mesh.grading = 1.5,
            |k: &mut JointKey| k.level = 2,
        ] {
            let mut k = base;
            f(&mut k);
            variants.push(k);
        }
        let mut names: Vec<String> = variants.iter().map(JointKey::file_name).collect();
        names.push(base.file_name());
        let n = names.len();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), n);
    }

    #[test]
    fn an_entry_is_served_only_whole_and_to_its_own_key() {
        let k = key(1.2e-3);
        let payload: Vec<u8> = (0..1000u32).map(|i| (i * 7 % 251) as u8).collect();
        let entry = encode_entry(&k, &payload);
        assert_eq!(decode_entry(&k, &entry), Ok(payload.as_slice()));
        // Another key (a collision of file names would look like this): refused.
        let other = key(2.0e-3);
        let e = decode_entry(&other, &entry).unwrap_err();
        assert!(e.contains("key mismatch"), "{e}");
        // Every truncation, a flipped payload byte, trailing bytes, another version.
        for cut in [0, 5, HEAD, HEAD + 20, entry.len() - 1000, entry.len() - 1] {
            assert!(decode_entry(&k, &entry[..cut]).is_err(), "cut at {cut}");
        }
        let mut flipped = entry.clone();
        let last = flipped.len() - 300;
        flipped[last] ^= 0x01;
        let e = decode_entry(&k, &flipped).unwrap_err();
        assert!(e.contains("checksum"), "{e}");
        let mut longer = entry.clone();
        longer.push(0);
        assert!(decode_entry(&k, &longer).is_err());
        let mut version = entry.clone();
        version[8] = version[8].wrapping_add(1);
        assert!(decode_entry(&k, &version).unwrap_err().contains("version"));
        let mut magic = entry;
        magic[0] = b'X';
        assert!(decode_entry(&k, &magic).unwrap_err().contains("magic"));
    }

    #[test]
    fn the_default_location_follows_xdg_cache_home() {
        let home = Some(PathBuf::from("/home/u/.cache"));
        assert_eq!(
            location(Some("/x/cache".into()), home.clone()),
            Some(PathBuf::from("/x/cache/cellinject"))
        );
        assert_eq!(
            location(Some(OsString::new()), home.clone()),
            Some(PathBuf::from("/home/u/.cache/cellinject"))
        );
        assert_eq!(
            location(None, home),
            Some(PathBuf::from("/home/u/.cache/cellinject"))
        );
        assert_eq!(location(None, None), None);
    }

    /// A joint on a mesh so coarse that it solves in milliseconds.
    fn tiny(throat: f64) -> JointKey {
        let mut k = key(throat);
        k.mesh = JointMesh {
            across: 2,
            notch: 4,
            block: 1,
            gap: 1,
            grading: 1.0,
        };
        k
    }

    fn temp(name: &str) -> PathBuf {
        let d =
            std::env::temp_dir().join(format!("cellinject-fea-unit-{}-{name}", std::process::id()));
        let _ = fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn solved_joints_are_stored_served_and_repaired() {
        let dir = temp("store");
        let cache = DirCache::new(dir.join("not yet created"));
        let k = tiny(1.2e-3);
        let (first, used) = solve_cached(&cache, &k).unwrap();
        assert_eq!(used.status, CacheStatus::Miss);
        let (again, used) = solve_cached(&cache, &k).unwrap();
        assert_eq!(used.status, CacheStatus::Hit);
        assert_eq!(again.to_bytes(), first.to_bytes());
        // A flipped payload byte: recomputed, reported, and the entry repaired.
        let path = cache.path_of(&k);
        let mut bytes = fs::read(&path).unwrap();
        let at = bytes.len() - 17;
        bytes[at] ^= 0x80;
        fs::write(&path, &bytes).unwrap();
        let (fixed, used) = solve_cached(&cache, &k).unwrap();
        assert_eq!(used.status, CacheStatus::Recomputed);
        assert!(
            used.detail.as_deref().unwrap_or("").contains("checksum"),
            "{used:?}"
        );
        assert_eq!(fixed.to_bytes(), first.to_bytes());
        assert_eq!(solve_cached(&cache, &k).unwrap().1.status, CacheStatus::Hit);
        // Another joint's entry under this joint's name is refused.
        let other = tiny(2.0e-3);
        solve_cached(&cache, &other).unwrap();
        fs::copy(cache.path_of(&other), &path).unwrap();
        let (s, used) = solve_cached(&cache, &k).unwrap();
        assert_eq!(used.status, CacheStatus::Recomputed);
        assert!(
            used.detail
                .as_deref()
                .unwrap_or("")
                .contains("key mismatch")
        );
        assert_eq!(s.k_bend, first.k_bend);
        // No temporary files are left behind.
        let names: Vec<String> = fs::read_dir(cache.dir())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names.len(), 2, "{names:?}");
        assert!(names.iter().all(|n| n.starts_with("joint-v")), "{names:?}");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn an_unwritable_directory_is_not_an_error() {
        // A directory that cannot be created: a path below a regular file.
        let file = temp("plain-file");
        fs::write(&file, b"x").unwrap();
        let cache = DirCache::new(file.join("cache"));
        let k = tiny(1.2e-3);
        let (s, used) = solve_cached(&cache, &k).unwrap();
        assert_eq!(used.status, CacheStatus::Unwritable);
        assert!(used.detail.is_some());
        assert!(s.k_bend[0] > 0.0);
        let (_, used) = solve_cached(&NoCache, &k).unwrap();
        assert_eq!(used.status, CacheStatus::Off);
        fs::remove_file(&file).unwrap();
    }
}
