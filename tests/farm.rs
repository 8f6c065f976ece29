//! A restartable frame farm (issue 39, item 2): `render --frames auto/K`
//! takes an array task's share, `--skip-done` skips complete frames and
//! redoes partial, stale and foreign ones, and `frames check` reports each
//! class with exit 8 so a dependent job can gate on it.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A 7-frame sequence of a lamp moving in a box, small enough for tests;
/// `emission` changes the scene (another archive).
fn build_sequence(dir: &Path, name: &str, emission: f32) -> PathBuf {
    let scene = dir.join(format!("{name}.toml"));
    std::fs::write(
        &scene,
        format!(
            "[camera]\nposition = [1, 1, -2]\nlook_at = [1, 1, 1]\nfov_y_deg = 50\nwidth = 24\nheight = 16\n\
             [animation]\nframes = 7\n\
             [[material]]\nname = 'w'\ntype = 'diffuse'\nreflectance = [0.5, 0.5, 0.5]\n\
             [[surface]]\nname = 'room'\nmaterial = 'w'\nbox = {{ min = [0, 0, 0], max = [2, 2, 2], inward = true, omit = ['-z'] }}\n\
             [[surface]]\nname = 'lamp'\nmaterial = 'w'\nemission = [{emission}, {emission}, {emission}]\n\
             box = {{ min = [0.8, 1.6, 0.8], max = [1.2, 1.8, 1.2] }}\n\
             keyframes = [{{ frame = 0 }}, {{ frame = 6, translate = [0.4, 0, 0.4] }}]\n"
        ),
    )
    .unwrap();
    let archive = dir.join(format!("{name}.inet"));
    let out =
        run(&["build", "-q", scene.to_str().unwrap(), "-o", archive.to_str().unwrap(), "--patch-size", "0.25"], &[]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    archive
}

/// Runs illumnet with `env` set and no array index inherited (the tests
/// may run inside a Slurm job).
fn run(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_illumnet"));
    for v in ["SLURM_ARRAY_TASK_ID", "SLURM_ARRAY_TASK_MIN", "JOB_COMPLETION_INDEX"] {
        c.env_remove(v);
    }
    c.args(args).envs(env.iter().copied()).output().unwrap()
}

fn ok(out: Output) -> String {
    assert!(
        out.status.success(),
        "failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// `frames check --json`'s counts, and its exit code.
fn check(archive: &Path, pattern: &Path, extra: &[&str]) -> (i32, serde_json::Value) {
    let mut args = vec!["frames", "check", archive.to_str().unwrap(), "-o", pattern.to_str().unwrap(), "--json"];
    args.extend_from_slice(extra);
    let out = run(&args, &[]);
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!("{e}: {}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr))
    });
    (out.status.code().unwrap(), json)
}

fn counts(json: &serde_json::Value) -> [u64; 5] {
    ["complete", "missing", "partial", "stale", "foreign"].map(|c| json["counts"][c].as_u64().unwrap())
}

#[test]
fn a_three_task_farm_renders_each_frame_once_and_the_check_gates_on_it() {
    let dir = tempfile::tempdir().unwrap();
    let archive = build_sequence(dir.path(), "anim", 4.0);
    let a = archive.to_str().unwrap();
    let pattern = dir.path().join("farm/frame_%04d.png");
    let exr = dir.path().join("farm/frame_%04d.exr");
    let (p, e) = (pattern.to_str().unwrap(), exr.to_str().unwrap());
    // Before the farm: every frame missing, exit 8.
    let (code, json) = check(&archive, &pattern, &["--exr", e]);
    assert_eq!((code, counts(&json)), (8, [0, 7, 0, 0, 0]), "{json}");
    // Three tasks of `--frames auto/3`: 7 frames as 2, 2 and 3.
    for (task, frames) in [("0", "frames 0 and 1"), ("1", "2 and 3"), ("2", "4, 5 and 6")] {
        let env = [("SLURM_ARRAY_TASK_ID", task)];
        let text = ok(run(&["render", "-q", a, "--frames", "auto/3", "--cold", "-o", p, "--exr", e], &env));
        let n = if task == "2" { 3 } else { 2 };
        assert!(text.contains(&format!("rendered {n} frames")), "task {task} ({frames}): {text}");
    }
    // Kubernetes' index too: task 1 of 3 again, all skipped.
    let text = ok(run(
        &["render", "-q", a, "--frames", "auto/3", "--cold", "--skip-done", "-o", p, "--exr", e],
        &[("JOB_COMPLETION_INDEX", "1")],
    ));
    assert!(text.contains("skip-done: 2 frames complete and skipped, 0 redone"), "{text}");
    let (code, json) = check(&archive, &pattern, &["--exr", e]);
    assert_eq!((code, counts(&json)), (0, [7, 0, 0, 0, 0]), "{json}");
    // The farm's frames are byte for byte one render's (--cold).
    let whole = dir.path().join("whole/frame_%04d.png");
    ok(run(&["render", "-q", a, "--cold", "-o", whole.to_str().unwrap()], &[]));
    for f in 0..7 {
        let name = format!("frame_{f:04}.png");
        let farm = std::fs::read(dir.path().join("farm").join(&name)).unwrap();
        assert!(farm == std::fs::read(dir.path().join("whole").join(&name)).unwrap(), "frame {f} differs");
    }
    // No index, or one beyond the shares: plain errors, exit 3.
    let out = run(&["render", "-q", a, "--frames", "auto/3", "-o", p], &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(err.contains("SLURM_ARRAY_TASK_ID") && err.contains("neither is set"), "{err}");
    let out = run(&["render", "-q", a, "--frames", "auto/3", "-o", p], &[("SLURM_ARRAY_TASK_ID", "3")]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(err.contains("this task's index 3 is not below 3"), "{err}");
    // An array numbered from 1 (`--array=1-3`): task 3 is the last share.
    let text = ok(run(
        &["render", "-q", a, "--frames", "auto/3", "--cold", "--skip-done", "-o", p],
        &[("SLURM_ARRAY_TASK_ID", "3"), ("SLURM_ARRAY_TASK_MIN", "1")],
    ));
    assert!(text.contains("skip-done: 3 frames complete and skipped"), "{text}");
}

#[test]
fn skip_done_redoes_partial_stale_foreign_and_missing_frames() {
    let dir = tempfile::tempdir().unwrap();
    let archive = build_sequence(dir.path(), "anim", 4.0);
    let other = build_sequence(dir.path(), "other", 3.0);
    let a = archive.to_str().unwrap();
    let pattern = dir.path().join("out/f_%02d.png");
    let p = pattern.to_str().unwrap();
    let file = |f: u32| dir.path().join(format!("out/f_{f:02}.png"));
    ok(run(&["render", "-q", a, "--frames", "0..6", "--cold", "-o", p], &[]));
    let good = std::fs::read(file(1)).unwrap();
    // Frame 1 truncated (what a writer without temp + rename would leave),
    // frame 2 rendered with another exposure, frame 3 from another archive,
    // frame 4 gone; frames 0 and 5 complete.
    std::fs::write(file(1), &good[..good.len() / 2]).unwrap();
    ok(run(&["render", "-q", a, "--frames", "2", "--cold", "--exposure", "2", "-o", file(2).to_str().unwrap()], &[]));
    let o = other.to_str().unwrap();
    ok(run(&["render", "-q", o, "--frames", "3..4", "--cold", "-o", p], &[]));
    std::fs::remove_file(file(4)).unwrap();
    let (code, json) = check(&archive, &pattern, &["--frames", "0..6"]);
    assert_eq!((code, counts(&json)), (8, [2, 1, 1, 1, 1]), "{json}");
    let states: Vec<&str> = json["report"].as_array().unwrap().iter().map(|r| r["state"].as_str().unwrap()).collect();
    assert_eq!(states, ["complete", "partial", "stale", "foreign", "missing", "complete"], "{json}");
    let why = json["report"][2]["why"].as_str().unwrap();
    assert!(why.contains("exposure 2") && why.contains("exposure 1"), "{why}");
    let why = json["report"][3]["why"].as_str().unwrap();
    assert!(why.starts_with("was rendered from another archive"), "{why}");
    // The text report names each frame, and exits 8.
    let out = run(&["frames", "check", a, "-o", p, "--frames", "0..6"], &[]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(8), "{text}");
    assert!(text.contains("frame 4: missing:") && text.contains("frame 1: partial:"), "{text}");
    assert!(text.ends_with("2 complete, 1 missing, 1 partial, 1 stale, 1 foreign\n"), "{text}");
    // --skip-done renders the four again, and the set is whole.
    let text = ok(run(&["render", "-q", a, "--frames", "0..6", "--cold", "--skip-done", "-o", p], &[]));
    assert!(
        text.contains(
            "skip-done: 2 frames complete and skipped, 3 redone (1 partial, 1 stale, 1 foreign), 1 missing rendered"
        ),
        "{text}"
    );
    assert!(text.contains("rendered 4 frames"), "{text}");
    assert_eq!(std::fs::read(file(1)).unwrap(), good, "a --cold frame redone is the same bytes");
    let (code, json) = check(&archive, &pattern, &["--frames", "0..6"]);
    assert_eq!((code, counts(&json)), (0, [6, 0, 0, 0, 0]), "{json}");
    // Previews need every frame: refused with --skip-done.
    let gif = dir.path().join("p.gif");
    let out = run(&["render", "-q", a, "--skip-done", "--gif", gif.to_str().unwrap(), "-o", p], &[]);
    assert_eq!(out.status.code(), Some(3), "{}", String::from_utf8_lossy(&out.stderr));
}

#[test]
fn a_render_killed_mid_sequence_leaves_no_partial_frame_and_skip_done_completes_it() {
    let dir = tempfile::tempdir().unwrap();
    let archive = build_sequence(dir.path(), "anim", 4.0);
    let a = archive.to_str().unwrap();
    let out = dir.path().join("out");
    let pattern = out.join("f_%02d.png");
    let p = pattern.to_str().unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_illumnet"))
        .args(["render", "-q", a, "--cold", "--samples", "8", "-o", p])
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // Killed (SIGKILL) once the first frame is in place.
    let start = std::time::Instant::now();
    while !out.join("f_00.png").exists() && start.elapsed().as_secs() < 120 {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    // Every file under a final name decodes (none is partial), whatever
    // moment the kill came at; only a temporary may be left beside them.
    let (code, json) = check(&archive, &pattern, &[]);
    let [complete, missing, partial, stale, foreign] = counts(&json);
    assert_eq!((partial, stale, foreign), (0, 0, 0), "{json}");
    assert!(complete >= 1 && complete + missing == 7, "{json}");
    for entry in std::fs::read_dir(&out).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        assert!(name.starts_with("f_") || (name.starts_with(".illumnet-f_") && name.ends_with(".tmp")), "{name}");
    }
    if missing == 0 {
        eprintln!("the render finished before the kill: nothing to resume");
    }
    let text = ok(run(&["render", "-q", a, "--cold", "--samples", "8", "--skip-done", "-o", p], &[]));
    assert!(
        text.contains(&format!("{complete} frame")) && text.contains(&format!("{missing} missing rendered")),
        "{text}"
    );
    let (code2, json) = check(&archive, &pattern, &[]);
    assert_eq!((code, code2, counts(&json)), (if missing > 0 { 8 } else { 0 }, 0, [7, 0, 0, 0, 0]), "{json}");
}
