//! `illumnet verify`: sound archives of every kind verify clean; each
//! class of damage gives its precise finding (section and record) and
//! exit code 4.

mod common;

use std::path::Path;

use common::CAMERA;
use illumnet::archive::layout::{self, DeltaIndexRecord, SectionEntry, tag};
use illumnet::archive::{self, Archive, ArchiveContents, verify::verify};
use illumnet::bake::{self, BuildSettings};
use illumnet::progress::NoProgress;
use illumnet::scene::{BuildHints, Scene};

const ROOM: &str = "[[material]]\nname = 'grey'\ntype = 'diffuse'\nreflectance = [0.6, 0.5, 0.4]\n\
    [[surface]]\nname = 'room'\nmaterial = 'grey'\nbox = { min = [0, 0, 0], max = [2, 2, 2], inward = true }\n\
    [[surface]]\nname = 'lamp'\nmaterial = 'grey'\nemission = [5, 5, 5]\n\
    quad = [[0.8, 1.9, 0.8], [1.2, 1.9, 0.8], [1.2, 1.9, 1.2], [0.8, 1.9, 1.2]]\n";

const MOVING: &str = "[animation]\nframes = 4\nfps = 10\n\
    [[surface]]\nname = 'mover'\nmaterial = 'grey'\nbox = { min = [0.3, 0.2, 0.3], max = [0.7, 0.6, 0.7] }\n\
    keyframes = [{ frame = 0 }, { frame = 3, translate = [0.8, 0.2, 0.6] }]\n";

const GLOSSY: &str = "[[material]]\nname = 'metal'\ntype = 'rough_conductor'\nspecular = [0.9, 0.8, 0.7]\n\
    alpha_u = 0.2\nalpha_v = 0.4\n[[surface]]\nname = 'plate'\nmaterial = 'metal'\n\
    quad = [[0.5, 0.3, 0.5], [1.5, 0.3, 0.5], [1.5, 0.3, 1.5], [0.5, 0.3, 1.5]]\n";

fn contents(text: &str, dir: &Path) -> ArchiveContents {
    let scene = Scene::from_toml(&format!("{CAMERA}{text}"), &dir.join("v.toml"), dir).unwrap();
    let hints = BuildHints { patch_size: Some(0.25), frequency: Some(4), ray_spacing: Some(0.04), buckets: None };
    let mut settings = BuildSettings::resolve(&scene, hints);
    settings.prototype_library = None;
    bake::build_sequence(&scene, &settings, &NoProgress).unwrap().contents
}

/// A floor mesh of 128 small triangles, for grouped patches.
fn write_mesh(dir: &Path) -> &'static str {
    let obj = common::grid_obj(8, (0.5, 0.5), 1.0, |x, z| 0.05 + 0.03 * (7.0 * x).sin() * (5.0 * z).cos());
    std::fs::write(dir.join("bumps.obj"), obj).unwrap();
    "[[surface]]\nname = 'bumps'\nmaterial = 'grey'\nmesh = 'bumps.obj'\n"
}

fn entry(bytes: &[u8], t: [u8; 4]) -> SectionEntry {
    let a = Archive::from_bytes(bytes).unwrap();
    *a.sections().iter().find(|e| e.tag == t).unwrap()
}

/// `illumnet verify` on `bytes` written to a file: exit code and output.
fn cli(dir: &Path, bytes: &[u8], json: bool) -> (Option<i32>, String) {
    let path = dir.join("x.inet");
    std::fs::write(&path, bytes).unwrap();
    let mut args = vec!["verify", path.to_str().unwrap()];
    if json {
        args.push("--json");
    }
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_illumnet")).args(&args).output().unwrap();
    (out.status.code(), String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr))
}

/// `illumnet inspect --json` (with `extra` arguments) on `bytes` written
/// to a file: exit code and the JSON it answers on stdout.
fn inspect_json(dir: &Path, bytes: &[u8], extra: &[&str]) -> (Option<i32>, serde_json::Value) {
    let path = dir.join("i.inet");
    std::fs::write(&path, bytes).unwrap();
    let mut args = vec!["inspect", path.to_str().unwrap(), "--json"];
    args.extend_from_slice(extra);
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_illumnet")).args(&args).output().unwrap();
    let json = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("inspect --json answered no JSON ({e}): {}", String::from_utf8_lossy(&out.stdout)));
    (out.status.code(), json)
}

/// The findings `verify` makes of `bytes`, as "SECTION[record]: what".
fn findings(dir: &Path, bytes: &[u8]) -> Vec<String> {
    let path = dir.join("f.inet");
    std::fs::write(&path, bytes).unwrap();
    let r = verify(&path).unwrap();
    assert_eq!(r.finding_count as usize, r.findings.len());
    r.findings
        .iter()
        .map(|f| format!("{}[{}]: {}", f.section, f.record.map_or("-".into(), |x| x.to_string()), f.what))
        .collect()
}

#[test]
fn sound_archives_of_every_kind_verify_clean() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = write_mesh(dir.path());
    for (name, text) in [
        ("still", ROOM.to_string()),
        ("glossy", format!("{ROOM}{GLOSSY}")),
        ("sequence", format!("{ROOM}{MOVING}")),
        ("mesh", format!("{ROOM}{mesh}")),
    ] {
        let bytes = archive::write_to_vec(&contents(&text, dir.path())).unwrap();
        assert_eq!(findings(dir.path(), &bytes), Vec::<String>::new(), "{name}");
        let (code, out) = cli(dir.path(), &bytes, true);
        assert_eq!(code, Some(0), "{name}: {out}");
        let json: serde_json::Value = serde_json::from_str(&out).unwrap();
        assert_eq!(json["sound"], true, "{name}");
        // inspect --json answers with the archive's summary.
        let (code, summary) = inspect_json(dir.path(), &bytes, &[]);
        assert_eq!(code, Some(0), "{name}: {summary}");
        assert_eq!(summary["format_version"], 11, "{name}");
        assert!(summary["patches"].as_u64().unwrap() > 0, "{name}");
        assert_eq!(json["frames"], if name == "sequence" { 4 } else { 1 }, "{name}");
        assert!(json["link_ends"].as_u64().unwrap() > 1000 && json["gb_per_s"].as_f64().unwrap() > 0.0, "{name}");
    }
}

#[test]
fn each_class_of_damage_gives_its_precise_finding() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let still = contents(ROOM, d);
    let good = archive::write_to_vec(&still).unwrap();
    let (loth, ldir) = (entry(&good, tag::LINK_OTHER), entry(&good, tag::LINK_DIRECTION));

    // A flipped byte: the section's checksum.
    let mut flipped = good.clone();
    flipped[loth.offset as usize + 100] ^= 0x40;
    let f = findings(d, &flipped);
    assert!(f.len() == 1 && f[0].starts_with("file[-]: does not open") && f[0].contains("LOTH"), "{f:?}");
    let (code, out) = cli(d, &flipped, false);
    assert_eq!(code, Some(4), "{out}");
    assert!(out.contains("1 finding") && out.contains("checksum"), "{out}");
    // inspect --json refuses it in JSON, naming the section.
    let refused = |bytes: &[u8], needle: &str| {
        let (code, json) = inspect_json(d, bytes, &[]);
        let message = json["error"]["message"].as_str().unwrap_or_default().to_string();
        assert_eq!((code, json["error"]["exit_code"].as_i64()), (Some(4), Some(4)), "{json}");
        assert!(message.contains("LOTH") && message.contains(needle), "{message}");
    };
    refused(&flipped, "checksum");

    // A wrong index under a valid checksum: refused at open, naming it.
    let mut index = good.clone();
    let p = still.build.patch_count;
    index[loth.offset as usize + 40..][..4].copy_from_slice(&(p + 7).to_le_bytes());
    archive::reseal(&mut index);
    let f = findings(d, &index);
    assert!(f.len() == 1 && f[0].contains("does not open") && f[0].contains("LOTH"), "{f:?}");
    refused(&index, "out of range");

    // A link end between patches that do not face each other along its
    // direction: its own direction reversed.
    let e = 10usize;
    let dir_e = still.link_direction[e];
    let mut turned = good.clone();
    turned[ldir.offset as usize + 4 * e..][..4].copy_from_slice(&(dir_e ^ 1).to_le_bytes());
    archive::reseal(&mut turned);
    let f = findings(d, &turned);
    assert!(
        f.iter().any(|x| x.starts_with(&format!("LDIR[{e}]: link end of patch")) && x.contains("do not face")),
        "{f:?}"
    );
    // …and the link no longer pairs up with its other end.
    assert!(f.iter().any(|x| x.starts_with("LOTH[-]: link ends do not pair up")), "{f:?}");
    // Every index is in range, so the archive opens: inspect describes it
    // (it is no verifier), and only verify finds the turned link.
    let (code, summary) = inspect_json(d, &turned, &[]);
    assert!(code == Some(0) && summary["error"].is_null(), "{summary}");
    let (code, out) = cli(d, &turned, true);
    assert_eq!(code, Some(4));
    let json: serde_json::Value =
        serde_json::from_str(out.lines().take_while(|l| !l.starts_with("illumnet:")).collect::<String>().as_str())
            .unwrap();
    assert_eq!(
        (json["sound"].as_bool(), json["findings"][0]["section"].as_str()),
        (Some(false), Some("LDIR")),
        "{json}"
    );
    assert_eq!(json["findings"][0]["record"].as_u64(), Some(e as u64));
    assert!(json["gb_per_s"].as_f64().unwrap() > 0.0, "an archive that opened was read: {json}");
    // A file that does not open as an archive was not read: no rate.
    let (code, out) = cli(d, &good[..64], true);
    assert_eq!(code, Some(4));
    let json: serde_json::Value =
        serde_json::from_str(out.lines().take_while(|l| !l.starts_with("illumnet:")).collect::<String>().as_str())
            .unwrap();
    assert!(json["findings"][0]["section"] == "file" && json["gb_per_s"].is_null(), "{json}");

    // A weight changed at one end only: the ends do not pair up.
    // (One ray fewer, so that no patch carries more rays than cross it.)
    let mut weight = good.clone();
    let lcnt = entry(&good, tag::LINK_COUNT);
    let e2 = still.link_weight.iter().position(|&w| (2.0..=255.0).contains(&w) && w.fract() == 0.0).unwrap();
    weight[lcnt.offset as usize + e2] -= 1;
    archive::reseal(&mut weight);
    let f = findings(d, &weight);
    assert!(f.iter().any(|x| x.starts_with("LOTH[-]: link ends do not pair up")), "{f:?}");

    // A sequence: frame 2's records drive a weight negative.
    let seq = contents(&format!("{ROOM}{MOVING}"), d);
    let a = Archive::from_bytes(&archive::write_to_vec(&seq).unwrap()).unwrap();
    let s = a.view().sequence.unwrap();
    let mut frames: Vec<Vec<layout::DeltaRecord>> = (0..s.frames()).map(|k| s.frame_delta(k).unwrap()).collect();
    assert!(!frames[2].is_empty());
    frames[2][0].count = -(1 << 20);
    let mut forged = seq.clone();
    forged.sequence.as_mut().unwrap().deltas = archive::deltas::EncodedDeltas::from_frames(&frames).unwrap();
    let forged = archive::write_to_vec(&forged).unwrap();
    let f = findings(d, &forged);
    assert!(f.len() == 1 && f[0].starts_with("DELT[2]: frame 2:") && f[0].contains("record 0: count"), "{f:?}");
    // inspect --histograms --json counts every frame's changes; it does
    // not apply them (verify and the distribution do), so it answers.
    let (code, json) = inspect_json(d, &forged, &["--histograms"]);
    assert_eq!(code, Some(0), "{json}");
    let frames: u64 = json["histograms"]["delta_records_per_frame"]["bins"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b["count"].as_u64().unwrap())
        .sum();
    assert_eq!(frames, 4, "{json}");

    // A truncated frame: frame 1's stored bytes one short (DIDX resealed).
    let mut cut = archive::write_to_vec(&seq).unwrap();
    let didx = entry(&cut, tag::DELTA_INDEX);
    let size = std::mem::size_of::<DeltaIndexRecord>();
    let at = didx.offset as usize + size;
    let mut rec: DeltaIndexRecord = bytemuck::pod_read_unaligned(&cut[at..at + size]);
    assert!(rec.stored_length > 1);
    rec.stored_length -= 1;
    cut[at..at + size].copy_from_slice(bytemuck::bytes_of(&rec));
    archive::reseal(&mut cut);
    // Opening takes the shorter range (the gap is not checked); decoding
    // frame 1 finds it cut.
    let f = findings(d, &cut);
    assert!(f.len() == 1 && f[0].starts_with("DELT[1]: frame 1:") && f[0].contains("whole zstd frames"), "{f:?}");
    // inspect takes each frame's record count from DIDX and decodes none:
    // it answers, and only verify finds the frame cut.
    let (code, json) = inspect_json(d, &cut, &["--histograms"]);
    assert!(code == Some(0) && json["error"].is_null(), "{json}");
}

#[test]
fn a_prototype_table_that_is_not_reciprocal_is_found() {
    // One factor of the glossy plate's table halved: the row still
    // conserves energy (opening accepts it), but T(i→o)/(cos θ_o·Ω_o) no
    // longer equals T(o→i)/(cos θ_i·Ω_i).
    let dir = tempfile::tempdir().unwrap();
    let mut c = contents(&format!("{ROOM}{GLOSSY}"), dir.path());
    let r = c.reflectance.as_mut().unwrap();
    let t = r.prototypes.iter().position(|p| p.model == layout::table_model::GGX).unwrap();
    let (p, bands) = (r.prototypes[t], r.prototypes[t].bands as usize);
    let row = |i: usize| {
        let (a, b) = (r.rows[p.first_row as usize + i] as usize, r.rows[p.first_row as usize + i + 1] as usize);
        (a, &r.outgoing[p.first_entry as usize + a..p.first_entry as usize + b])
    };
    let n = c.directions.len();
    // The first pair i < o whose entries are both kept.
    let (factor, i, o) = (0..n)
        .find_map(|i| {
            let (a, outs) = row(i);
            outs.iter().enumerate().find_map(|(k, &o)| {
                (o as usize > i && row(o as usize).1.contains(&(i as u32))).then_some((a + k, i, o as usize))
            })
        })
        .unwrap();
    let at = p.first_factor as usize + factor * bands;
    r.factors[at] *= 0.5;
    let f = findings(dir.path(), &archive::write_to_vec(&c).unwrap());
    assert_eq!(f.len(), 1, "{f:?}");
    assert!(f[0].starts_with(&format!("PFAC[{at}]: table {t}: T({i}→{o}) and T({o}→{i}) are not reciprocal")), "{f:?}");
}
