//! The prototype library: tables cached on disk, so that a reflectance
//! function is tabulated once per (model, parameters, direction set) and
//! reused by later builds (§3.6.2: "the bulk of the work is in computing the
//! prototype reflectance functions").
//!
//! One file per table, named by the XXH3-64 hash of its key (model,
//! parameters, threshold, and the direction set's vectors and cells): a zstd
//! frame holding a 64-byte header (`ILPTAB01`, key, counts), the row
//! offsets, outgoing directions and factors (little-endian), and an XXH3-64
//! checksum of all of it. A file that does not decode, or whose key differs,
//! is rebuilt and replaced; writes go to a temporary file renamed into place.
//! Failing to write the cache never fails a build: the lookup reports it.

use std::path::{Path, PathBuf};

use super::model::{Lobe, TableModel};
use super::prototype::{self, PrototypeTable, TableStats};

const MAGIC: &[u8; 8] = b"ILPTAB01";

/// A directory of cached prototype tables.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Library {
    /// Where the tables live.
    pub dir: PathBuf,
}

/// What [`Library::get_or_build`] found or made.
#[derive(Debug, Clone)]
pub struct Lookup {
    /// The table.
    pub table: PrototypeTable,
    /// Build statistics when the table was built now (`None`: read from the library).
    pub built: Option<TableStats>,
    /// Seconds spent building or reading.
    pub seconds: f64,
    /// A problem with the cache that did not stop the lookup.
    pub warning: Option<String>,
}

/// The key bytes identifying a table: model, parameters, threshold and the
/// direction set (vectors and cells, hashed).
pub fn key(model: &TableModel, directions: &[[f32; 3]], solid_angle: &[f64], threshold: f64) -> Vec<u8> {
    let mut k = Vec::with_capacity(48);
    let (code, lobe) = match model {
        TableModel::Lambertian => (0u32, Lobe { alpha_u: 0.0, alpha_v: 0.0, ior: None }),
        TableModel::Ggx(l) => (1u32, *l),
    };
    k.extend_from_slice(&code.to_le_bytes());
    k.extend_from_slice(&lobe.alpha_u.to_le_bytes());
    k.extend_from_slice(&lobe.alpha_v.to_le_bytes());
    for c in lobe.ior.unwrap_or([0.0; 3]) {
        k.extend_from_slice(&c.to_le_bytes());
    }
    k.extend_from_slice(&threshold.to_le_bytes());
    k.extend_from_slice(&(directions.len() as u64).to_le_bytes());
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    h.update(bytemuck::cast_slice(directions));
    h.update(bytemuck::cast_slice(solid_angle));
    k.extend_from_slice(&h.digest().to_le_bytes());
    k
}

/// Encodes a table with its key (the file format above, before zstd).
pub fn encode(table: &PrototypeTable, key: &[u8]) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend_from_slice(MAGIC);
    b.extend_from_slice(&(key.len() as u32).to_le_bytes());
    b.extend_from_slice(key);
    b.extend_from_slice(&(table.bands as u32).to_le_bytes());
    b.extend_from_slice(&(table.offsets.len() as u64).to_le_bytes());
    b.extend_from_slice(&(table.outgoing.len() as u64).to_le_bytes());
    for x in &table.offsets {
        b.extend_from_slice(&x.to_le_bytes());
    }
    for x in &table.outgoing {
        b.extend_from_slice(&x.to_le_bytes());
    }
    for x in &table.factors {
        b.extend_from_slice(&x.to_le_bytes());
    }
    let sum = xxhash_rust::xxh3::xxh3_64(&b);
    b.extend_from_slice(&sum.to_le_bytes());
    b
}

struct Reader<'a> {
    b: &'a [u8],
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], String> {
        if self.b.len() < n {
            return Err("truncated".into());
        }
        let (a, rest) = self.b.split_at(n);
        self.b = rest;
        Ok(a)
    }
    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().expect("4 bytes")))
    }
    fn u64(&mut self) -> Result<u64, String> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes")))
    }
}

/// Decodes what [`encode`] wrote for `model` and `key`, checking the
/// checksum, the key and every index.
pub fn decode(bytes: &[u8], model: &TableModel, key: &[u8], directions: usize) -> Result<PrototypeTable, String> {
    if bytes.len() < MAGIC.len() + 8 || &bytes[..8] != MAGIC {
        return Err("not a prototype table".into());
    }
    let (body, sum) = bytes.split_at(bytes.len() - 8);
    if xxhash_rust::xxh3::xxh3_64(body).to_le_bytes() != sum {
        return Err("checksum mismatch".into());
    }
    let mut r = Reader { b: &body[8..] };
    let klen = r.u32()? as usize;
    if r.take(klen)? != key {
        return Err("key differs".into());
    }
    let bands = r.u32()? as usize;
    let rows = r.u64()? as usize;
    let entries = r.u64()? as usize;
    if bands != model.bands() || rows != directions + 1 {
        return Err("shape differs".into());
    }
    let expected = rows.checked_mul(4).and_then(|x| x.checked_add(entries.checked_mul(4 * (1 + bands))?));
    if expected != Some(r.b.len()) {
        return Err("length differs".into());
    }
    let offsets: Vec<u32> = (0..rows).map(|_| r.u32()).collect::<Result<_, _>>()?;
    let outgoing: Vec<u32> = (0..entries).map(|_| r.u32()).collect::<Result<_, _>>()?;
    let factors: Vec<f32> = (0..entries * bands).map(|_| r.u32().map(f32::from_bits)).collect::<Result<_, _>>()?;
    if offsets[0] != 0 || offsets.windows(2).any(|w| w[0] > w[1]) || offsets[rows - 1] as usize != entries {
        return Err("row offsets invalid".into());
    }
    if outgoing.iter().any(|&o| o as usize >= directions) || factors.iter().any(|f| !f.is_finite() || *f < 0.0) {
        return Err("entries invalid".into());
    }
    for w in offsets.windows(2) {
        let row = &factors[w[0] as usize * bands..w[1] as usize * bands];
        for c in 0..bands {
            if row.iter().skip(c).step_by(bands).map(|&x| x as f64).sum::<f64>() > 1.0 + 1e-4 {
                return Err("a row returns more than it receives".into());
            }
        }
    }
    Ok(PrototypeTable { model: *model, bands, offsets, outgoing, factors })
}

impl Library {
    /// A library in `dir` (created on first write).
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        Self { dir: dir.into() }
    }

    /// The default location: `$ILLUMNET_PROTOTYPES`, else
    /// `$XDG_CACHE_HOME/illumnet/prototypes`, else
    /// `$HOME/.cache/illumnet/prototypes`; `None` without any of them.
    pub fn default_location() -> Option<PathBuf> {
        let var = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty()).map(PathBuf::from);
        var("ILLUMNET_PROTOTYPES")
            .or_else(|| var("XDG_CACHE_HOME").map(|d| d.join("illumnet/prototypes")))
            .or_else(|| var("HOME").map(|d| d.join(".cache/illumnet/prototypes")))
    }

    /// The file holding the table of `key`.
    pub fn path_of(&self, key: &[u8]) -> PathBuf {
        self.dir.join(format!("{:016x}.iltab.zst", xxhash_rust::xxh3::xxh3_64(key)))
    }

    /// The table of `model` over the direction set: from the library if it
    /// holds it, else built and stored.
    pub fn get_or_build(
        &self,
        model: TableModel,
        directions: &[[f32; 3]],
        solid_angle: &[f64],
        threshold: f64,
    ) -> Lookup {
        let t0 = std::time::Instant::now();
        let key = key(&model, directions, solid_angle, threshold);
        let path = self.path_of(&key);
        let mut warning = None;
        if let Ok(compressed) = std::fs::read(&path) {
            match zstd::decode_all(&compressed[..])
                .map_err(|e| e.to_string())
                .and_then(|b| decode(&b, &model, &key, directions.len()))
            {
                Ok(table) => return Lookup { table, built: None, seconds: t0.elapsed().as_secs_f64(), warning },
                Err(e) => warning = Some(format!("{}: {e}; rebuilt", path.display())),
            }
        }
        let (table, stats) = prototype::build(model, directions, solid_angle, threshold);
        if let Err(e) = store(&path, &encode(&table, &key)) {
            warning = Some(format!("could not store prototype table in {}: {e}", self.dir.display()));
        }
        Lookup { table, built: Some(stats), seconds: t0.elapsed().as_secs_f64(), warning }
    }
}

fn store(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)?;
    let compressed = zstd::encode_all(bytes, 9)?;
    let mut builder = tempfile::Builder::new();
    builder.prefix(".iltab-").suffix(".tmp");
    #[cfg(unix)]
    builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666));
    let mut tmp = builder.tempfile_in(dir)?;
    std::io::Write::write_all(&mut tmp, &compressed)?;
    tmp.persist(path).map_err(|e| e.error)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geodesic::DirectionSet;

    #[test]
    fn library_builds_once_then_reads_back_and_survives_corruption() {
        let dir = tempfile::tempdir().unwrap();
        let lib = Library::new(dir.path().join("protos"));
        let dirs = DirectionSet::new(5).unwrap();
        let model = TableModel::Ggx(Lobe { alpha_u: 0.3, alpha_v: 0.3, ior: None });
        let t = 1e-4;
        let first = lib.get_or_build(model, &dirs.directions, &dirs.solid_angle, t);
        assert!(first.built.is_some() && first.warning.is_none());
        let second = lib.get_or_build(model, &dirs.directions, &dirs.solid_angle, t);
        assert!(second.built.is_none(), "read from the library");
        assert_eq!(first.table, second.table);
        // Another model is another file.
        let other = TableModel::Ggx(Lobe { alpha_u: 0.3, alpha_v: 0.31, ior: None });
        assert!(lib.get_or_build(other, &dirs.directions, &dirs.solid_angle, t).built.is_some());
        // A corrupt file is rebuilt, with a warning.
        let path = lib.path_of(&key(&model, &dirs.directions, &dirs.solid_angle, t));
        let mut bytes = zstd::decode_all(&std::fs::read(&path).unwrap()[..]).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 1;
        std::fs::write(&path, zstd::encode_all(&bytes[..], 1).unwrap()).unwrap();
        let third = lib.get_or_build(model, &dirs.directions, &dirs.solid_angle, t);
        assert!(third.built.is_some() && third.warning.as_deref().unwrap().contains("checksum"));
        assert_eq!(third.table, first.table);
    }
}
