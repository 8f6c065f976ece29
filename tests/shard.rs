//! Sharded builds (`build --shard I/K`, `merge`): the archive merged from
//! any number of shards is byte-identical to a one-machine build, for a
//! still, a glossy scene and a sequence; shards that are damaged, missing,
//! given twice or of another build are refused (exit 4) naming the shard.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use illumnet::bake::shard::manifest::Manifest;

fn illumnet(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_illumnet")).args(args).output().unwrap()
}

fn ok(args: &[&str]) -> String {
    let out = illumnet(args);
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "illumnet {args:?} failed:\n{text}");
    text
}

fn scene(name: &str) -> String {
    format!("{}/scenes/{name}.toml", env!("CARGO_MANIFEST_DIR"))
}

/// Builds the `k` shards of `scene` (with `opts`) into `dir`.
fn shards(scene: &str, opts: &[&str], k: u32, dir: &Path) {
    for i in 0..k {
        let spec = format!("{i}/{k}");
        ok(&[&["build", scene, "-q", "--shard", &spec, "--shard-dir", dir.to_str().unwrap()], opts].concat());
    }
}

/// Merges `dirs` into `out`: the process's output.
fn merge(dirs: &[&Path], out: &Path) -> Output {
    let mut args = vec!["merge", "-q", "-o", out.to_str().unwrap()];
    args.extend(dirs.iter().map(|d| d.to_str().unwrap()));
    illumnet(&args)
}

fn refused(out: Output, says: &[&str]) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(4), "{stderr}");
    for s in says {
        assert!(stderr.contains(s), "the error says `{s}`: {stderr}");
    }
}

#[test]
fn merged_shards_are_byte_identical_to_one_build_still_glossy_and_sequence() {
    let tmp = tempfile::tempdir().unwrap();
    let draft = ["--quality", "draft", "--frequency", "6"];
    for name in ["cornell_box", "glossy_floor", "fan_room"] {
        let one = tmp.path().join(format!("{name}.inet"));
        ok(&[&["build", &scene(name), "-q", "-o", one.to_str().unwrap()], &draft[..]].concat());
        let whole = std::fs::read(&one).unwrap();
        for k in [1, 2, 3, 7] {
            let dir = tmp.path().join(format!("{name}-{k}"));
            shards(&scene(name), &draft, k, &dir);
            let merged = tmp.path().join(format!("{name}-{k}.inet"));
            let out = merge(&[&dir], &merged);
            assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
            assert!(std::fs::read(&merged).unwrap() == whole, "{name} in {k} shards: not the one-machine bytes");
        }
    }
}

#[test]
fn auto_takes_the_shard_from_the_array_index() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("d");
    for i in 0..2 {
        let out = Command::new(env!("CARGO_BIN_EXE_illumnet"))
            .args(["build", &scene("cornell_box"), "-q", "--quality", "draft", "--frequency", "4"])
            .args(["--shard", "auto/2", "--shard-dir", dir.to_str().unwrap()])
            .env("SLURM_ARRAY_TASK_ID", i.to_string())
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        assert!(String::from_utf8_lossy(&out.stdout).contains(&format!("shard {i}/2")));
    }
    let out = illumnet(&["build", &scene("cornell_box"), "--shard", "auto/2", "--shard-dir", dir.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "no index set: {stderr}");
    let merged = tmp.path().join("m.inet");
    assert!(merge(&[&dir], &merged).status.success());
}

/// A fresh copy of a 3-shard build's directory, to damage.
fn copy_of(source: &Path, to: &Path) -> PathBuf {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(source).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
    }
    to.to_path_buf()
}

#[test]
fn damaged_missing_doubled_and_foreign_shards_are_refused_naming_the_shard() {
    let tmp = tempfile::tempdir().unwrap();
    let opts = ["--quality", "draft", "--frequency", "4"];
    let good = tmp.path().join("good");
    shards(&scene("cornell_box"), &opts, 3, &good);
    let out = tmp.path().join("out.inet");
    let run1 = "shard-0001-of-0003-run-000000.bin";

    // A flipped byte in a run, under its unchanged manifest.
    let d = copy_of(&good, &tmp.path().join("flipped"));
    let mut bytes = std::fs::read(d.join(run1)).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x40;
    std::fs::write(d.join(run1), &bytes).unwrap();
    refused(merge(&[&d], &out), &["shard 1/3", run1, "damaged"]);

    // A run cut short.
    let d = copy_of(&good, &tmp.path().join("cut"));
    bytes[mid] ^= 0x40;
    std::fs::write(d.join(run1), &bytes[..bytes.len() - 12]).unwrap();
    refused(merge(&[&d], &out), &["shard 1/3", "truncated"]);

    // A manifest edited by hand (its checksum no longer matches).
    let d = copy_of(&good, &tmp.path().join("edited"));
    let m = d.join("shard-0002-of-0003.manifest");
    let text = std::fs::read_to_string(&m).unwrap().replacen("\"shard\": 2", "\"shard\": 1", 1);
    std::fs::write(&m, text).unwrap();
    refused(merge(&[&d], &out), &["shard-0002-of-0003.manifest", "damaged"]);

    // A manifest forged with a valid checksum: shard 2's run claimed for
    // pair 0, another shard's pairs.
    let d = copy_of(&good, &tmp.path().join("forged"));
    let m = d.join("shard-0002-of-0003.manifest");
    let mut forged = Manifest::from_text(&std::fs::read_to_string(&m).unwrap()).unwrap();
    forged.runs[0].first_pair = 0;
    std::fs::write(&m, forged.to_text()).unwrap();
    refused(merge(&[&d], &out), &["shard 2/3", "outside the shard's pairs"]);
    let mut forged =
        Manifest::from_text(&std::fs::read_to_string(d.join("shard-0001-of-0003.manifest")).unwrap()).unwrap();
    forged.runs[0].ends = u64::MAX;
    std::fs::write(d.join("shard-0001-of-0003.manifest"), forged.to_text()).unwrap();
    std::fs::copy(good.join("shard-0002-of-0003.manifest"), d.join("shard-0002-of-0003.manifest")).unwrap();
    refused(merge(&[&d], &out), &["shard 1/3", "does not hold its records"]);
    // End records of a size the format has not, or of the other size.
    let good1 =
        Manifest::from_text(&std::fs::read_to_string(good.join("shard-0001-of-0003.manifest")).unwrap()).unwrap();
    assert_eq!(good1.runs[0].end_bytes, 8, "the Cornell box's runs have narrow records");
    for (end_bytes, why) in [(9, "end records of 9 bytes"), (12, "does not hold its records")] {
        let mut forged = good1.clone();
        forged.runs[0].end_bytes = end_bytes;
        std::fs::write(d.join("shard-0001-of-0003.manifest"), forged.to_text()).unwrap();
        refused(merge(&[&d], &out), &["shard 1/3", why]);
    }

    // A stale shard: traced by another version of the program.
    let d = copy_of(&good, &tmp.path().join("stale"));
    let m = d.join("shard-0001-of-0003.manifest");
    let mut stale = Manifest::from_text(&std::fs::read_to_string(&m).unwrap()).unwrap();
    stale.binary_version = "0.0.1".into();
    std::fs::write(&m, stale.to_text()).unwrap();
    refused(merge(&[&d], &out), &["shard 1/3", "traced by illumnet 0.0.1"]);

    // A missing shard (a gap), and a shard given twice.
    let d = copy_of(&good, &tmp.path().join("gap"));
    std::fs::remove_file(d.join("shard-0001-of-0003.manifest")).unwrap();
    refused(merge(&[&d], &out), &["shard-0002-of-0003.manifest", "no shard (a gap)"]);
    refused(merge(&[&good, &good], &out), &["are both shard 0/3"]);

    // A shard of another build (another frequency) among them.
    let other = tmp.path().join("other");
    shards(&scene("cornell_box"), &["--quality", "draft", "--frequency", "5"], 3, &other);
    let d = copy_of(&good, &tmp.path().join("mixed"));
    std::fs::remove_file(d.join("shard-0001-of-0003.manifest")).unwrap();
    let o = tmp.path().join("other-1");
    std::fs::create_dir(&o).unwrap();
    std::fs::copy(other.join("shard-0001-of-0003.manifest"), o.join("shard-0001-of-0003.manifest")).unwrap();
    refused(merge(&[&d, &o], &out), &["shard 1/3 of another build"]);

    // The scene changed since the shards were traced.
    let moved = tmp.path().join("box.toml");
    std::fs::write(&moved, std::fs::read_to_string(scene("cornell_box")).unwrap()).unwrap();
    let d = tmp.path().join("changed");
    shards(moved.to_str().unwrap(), &opts, 2, &d);
    let text = std::fs::read_to_string(&moved).unwrap();
    let changed = text.replacen("0.885809", "0.885808", 1);
    assert!(changed != text, "the scene has the white reflectance to change");
    std::fs::write(&moved, changed).unwrap();
    refused(merge(&[&d], &out), &["shard 0/2", "another scene or settings"]);

    assert!(!out.exists(), "no archive from refused shards");
    assert!(merge(&[&good], &out).status.success(), "the sound shards still merge");
}
