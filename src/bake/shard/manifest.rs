//! A shard's manifest: what a shard of a build holds and how to check it
//! (format-spec/shard.md). Across machines a shard's files are input, not
//! scratch: the manifest is checksummed, and names every file of the
//! shard with its length and checksum, so that the merge refuses what is
//! damaged, truncated, or of another build before it reads a link.

use std::io::Read;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use xxhash_rust::xxh3::Xxh3;

/// `kind` of every manifest.
pub const KIND: &str = "illumnet build shard";
/// The manifest layout this binary writes and reads.
pub const MANIFEST_VERSION: u32 = 2;
/// The line that ends a manifest, before its checksum in hex.
const TRAILER: &str = "\nxxh3-64 ";

/// A shard's manifest (format-spec/shard.md, "Manifest").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// [`KIND`].
    pub kind: String,
    /// [`MANIFEST_VERSION`].
    pub manifest_version: u32,
    /// The version of the program that traced the shard.
    pub binary_version: String,
    /// The archive format version the merge will write.
    pub archive_format: u32,
    /// The build's fingerprint: XXH3-64 over the scene as read (every file
    /// it names, through what was read from them), the resolved settings,
    /// the format and binary versions and the patch and pair counts.
    pub fingerprint: String,
    /// Patches, direction pairs, frames and chunks of pairs of the build.
    pub patches: u64,
    /// Direction pairs.
    pub pairs: u64,
    /// Frames (1 for a still).
    pub frames: u32,
    /// Chunks of pairs (the unit a shard takes).
    pub chunks: u32,
    /// This shard's index, of `shards`.
    pub shard: u32,
    /// Shards the build was cut into.
    pub shards: u32,
    /// The chunks this shard traced, `[first, end)`.
    pub chunk_range: [u32; 2],
    /// Rays this shard's bundles hold (its estimated work), and of all shards.
    pub rays: u64,
    /// Rays of the whole build.
    pub build_rays: u64,
    /// Seconds tracing took (for the report: slowest against mean).
    pub trace_seconds: f64,
    /// The `build` command's arguments, to read the scene again at the merge.
    pub invocation: Vec<String>,
    /// The directory the build ran in (relative paths in `invocation`).
    pub directory: String,
    /// The shard's counts file.
    pub counts: FileSum,
    /// Its link-end runs, in the order of their first link.
    pub runs: Vec<RunEntry>,
}

/// A file of the shard: its name (in the manifest's directory), length
/// and XXH3-64 checksum in hex.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FileSum {
    /// File name, in the manifest's directory.
    pub file: String,
    /// Length in bytes.
    pub bytes: u64,
    /// XXH3-64 of its bytes, 16 hex digits.
    pub xxh3: String,
}

/// One run of link ends (the bounded build's run format, `bake/spill`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunEntry {
    /// The pair of its first link.
    pub first_pair: u32,
    /// Its first link's index in that pair's bundle.
    pub first_link: u64,
    /// Link-end records, then slot records.
    pub ends: u64,
    /// Slot records.
    pub slots: u64,
    /// Bytes of an end record: 8 (16-bit weight and direction) or 12.
    pub end_bytes: u64,
    /// The file.
    pub file: FileSum,
}

/// The XXH3-64 of a file and its length, read in 1 MiB pieces.
pub fn file_sum(path: &Path) -> std::io::Result<(u64, String)> {
    let mut file = std::fs::File::open(path)?;
    let mut hasher = Xxh3::new();
    let mut buf = vec![0u8; 1 << 20];
    let mut bytes = 0u64;
    loop {
        let n = file.read(&mut buf)?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
        bytes += n as u64;
    }
    Ok((bytes, format!("{:016x}", hasher.digest())))
}

/// Checks `sum` against the file it names in `dir`: an error naming what
/// differs.
pub fn check_file(dir: &Path, sum: &FileSum) -> Result<PathBuf, String> {
    if sum.file.contains(['/', '\\']) || sum.file.starts_with('.') {
        return Err(format!("names a file outside its directory: `{}`", sum.file));
    }
    let path = dir.join(&sum.file);
    let meta = std::fs::metadata(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    if !meta.is_file() {
        return Err(format!("{}: not a regular file", path.display()));
    }
    if meta.len() != sum.bytes {
        return Err(format!(
            "{}: {} bytes where the manifest says {} (truncated or replaced)",
            path.display(),
            meta.len(),
            sum.bytes
        ));
    }
    let (_, hex) = file_sum(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    if hex != sum.xxh3 {
        return Err(format!("{}: checksum {hex} where the manifest says {} (damaged)", path.display(), sum.xxh3));
    }
    Ok(path)
}

impl Manifest {
    /// The manifest's text: its JSON, then its checksum's line.
    pub fn to_text(&self) -> String {
        let json = serde_json::to_string_pretty(self).expect("a manifest serialises");
        format!("{json}{TRAILER}{:016x}\n", xxhash_rust::xxh3::xxh3_64(json.as_bytes()))
    }

    /// Reads and checks a manifest's text (`name` for errors): its
    /// checksum, kind and version.
    pub fn from_text(text: &str) -> Result<Self, String> {
        let at = text.rfind(TRAILER).ok_or("no checksum line (not a shard manifest, or cut short)")?;
        let (json, hex) = (&text[..at], text[at + TRAILER.len()..].trim_end());
        let sum = format!("{:016x}", xxhash_rust::xxh3::xxh3_64(json.as_bytes()));
        if hex != sum {
            return Err(format!("checksum {sum} where the manifest says {hex} (damaged)"));
        }
        let m: Manifest = serde_json::from_str(json).map_err(|e| format!("not a shard manifest: {e}"))?;
        if m.kind != KIND {
            return Err(format!("kind `{}`, not `{KIND}`", m.kind));
        }
        if m.manifest_version != MANIFEST_VERSION {
            return Err(format!(
                "manifest version {} (this program reads version {MANIFEST_VERSION}): merge with the program that built it",
                m.manifest_version
            ));
        }
        let [a, b] = m.chunk_range;
        if m.shards == 0 || m.shard >= m.shards || a > b || b > m.chunks {
            return Err(format!("shard {}/{} of chunks {a}..{b} of {} is not a shard", m.shard, m.shards, m.chunks));
        }
        Ok(m)
    }

    /// The manifest's file name for shard `index` of `count`.
    pub fn file_name(index: u32, count: u32) -> String {
        format!("{}.manifest", stem(index, count))
    }
}

/// The common stem of shard `index` of `count`'s files.
pub fn stem(index: u32, count: u32) -> String {
    format!("shard-{index:04}-of-{count:04}")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Manifest {
        let sum = FileSum { file: "shard-0000-of-0002.counts".into(), bytes: 10, xxh3: "00".repeat(8) };
        Manifest {
            kind: KIND.into(),
            manifest_version: MANIFEST_VERSION,
            binary_version: "0".into(),
            archive_format: 11,
            fingerprint: "ab".repeat(8),
            patches: 5,
            pairs: 3,
            frames: 1,
            chunks: 3,
            shard: 0,
            shards: 2,
            chunk_range: [0, 2],
            rays: 10,
            build_rays: 20,
            trace_seconds: 0.5,
            invocation: vec!["scene.toml".into()],
            directory: "/".into(),
            counts: sum.clone(),
            runs: vec![RunEntry { first_pair: 0, first_link: 0, ends: 2, slots: 1, end_bytes: 8, file: sum }],
        }
    }

    #[test]
    fn a_manifest_reads_back_and_any_change_is_refused() {
        let text = sample().to_text();
        assert_eq!(Manifest::from_text(&text).unwrap(), sample());
        let changed = text.replacen("\"rays\": 10", "\"rays\": 11", 1);
        assert!(Manifest::from_text(&changed).unwrap_err().contains("damaged"));
        assert!(Manifest::from_text(&text[..text.len() / 2]).is_err());
        assert!(Manifest::from_text("").is_err());
        let mut m = sample();
        m.chunk_range = [2, 4];
        assert!(Manifest::from_text(&m.to_text()).unwrap_err().contains("not a shard"));
    }
}
