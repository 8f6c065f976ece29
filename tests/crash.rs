//! Crash safety (issue 14): a build killed (SIGKILL) at each stage leaves
//! the archive already at its path intact, byte for byte, and the next
//! build of that path removes what the killed one left.

use std::os::unix::process::ExitStatusExt;
use std::path::Path;
use std::process::Command;

/// Runs illumnet with `args`, killed at `stop_at`; with `ulimit -n 48`
/// when `args` starts with "few-files" (in its place).
fn illumnet(args: &[&str], stop_at: Option<&str>) -> std::process::Output {
    let mut c = match args.split_first() {
        Some((&"few-files", rest)) => {
            let mut c = Command::new("sh");
            c.args(["-c", "ulimit -n 48 && exec \"$0\" \"$@\"", env!("CARGO_BIN_EXE_illumnet")]).args(rest);
            c
        }
        _ => {
            let mut c = Command::new(env!("CARGO_BIN_EXE_illumnet"));
            c.args(args);
            c
        }
    };
    c.env_remove("ILLUMNET_TEST_STOP_AT");
    if let Some(s) = stop_at {
        c.env("ILLUMNET_TEST_STOP_AT", s);
    }
    c.output().unwrap()
}

fn leftovers(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(".illumnet-"))
        .collect()
}

#[test]
fn a_build_killed_at_any_stage_keeps_the_old_archive_and_the_next_build_cleans_up() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("box.inet");
    let out_s = out.to_str().unwrap();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell_box.toml");
    let scene = scene.to_str().unwrap();
    let first = illumnet(&["build", "-q", scene, "-o", out_s, "--quality", "draft"], None);
    assert!(first.status.success(), "{}", String::from_utf8_lossy(&first.stderr));
    let old = std::fs::read(&out).unwrap();
    // Each stage with the build that reaches it: in memory, or spilling
    // under a budget (the default quality's 174 MiB archive under 40 MiB).
    let unbounded: &[&str] = &["build", "-q", scene, "-o", out_s, "--quality", "draft", "--frequency", "9"];
    let bounded: &[&str] = &["build", "-q", scene, "-o", out_s, "--memory-budget", "40M"];
    // Its runs merged in passes of 8 (48 open files).
    let passes: &[&str] = &["few-files", "build", "-q", scene, "-o", out_s, "--memory-budget", "40M"];
    for (stage, args, leaves) in [
        ("trace", unbounded, false),
        ("links", unbounded, false),
        ("write", unbounded, true),
        ("spill", bounded, true),
        ("merge", bounded, true),
        ("merge pass", passes, true),
        ("write", bounded, true),
    ] {
        let killed = illumnet(args, Some(stage));
        assert_eq!(
            killed.status.signal(),
            Some(9),
            "{stage}: {:?} {}",
            killed.status,
            String::from_utf8_lossy(&killed.stderr)
        );
        assert!(std::fs::read(&out).unwrap() == old, "{stage}: the archive at the path changed");
        let left = leftovers(dir.path());
        assert_eq!(!left.is_empty(), leaves, "{stage}: left {left:?}");
        // The next build of the path removes them, and only then writes.
        let next = illumnet(args, None);
        assert!(next.status.success(), "{stage}: {}", String::from_utf8_lossy(&next.stderr));
        assert!(leftovers(dir.path()).is_empty(), "{stage}: {:?} after the next build", leftovers(dir.path()));
        if leaves {
            let said = String::from_utf8_lossy(&next.stdout);
            assert!(said.contains("left next to") && said.contains("by an interrupted build"), "{stage}: {said}");
        }
        assert!(std::fs::read(&out).unwrap() != old, "{stage}: the next build wrote nothing");
        // Back to the first archive for the next stage.
        std::fs::write(&out, &old).unwrap();
    }
}

#[test]
fn a_full_disk_is_one_clear_error_that_leaves_nothing_behind() {
    use std::os::unix::process::CommandExt;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("box.inet");
    std::fs::write(&out, b"the previous archive").unwrap();
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    // 10 MB: the archive's write fails; 1 MB: a spilled run's does first;
    // the fan room's 54 MiB of spilled per-frame link changes (in an
    // unnamed file) fail at 40 MB, before its archive is written.
    for (scene, budget, limit, what) in [
        ("cornell_box.toml", None, 10u64 << 20, "box.inet: File too large"),
        ("cornell_box.toml", Some("40M"), 10 << 20, "box.inet: File too large"),
        ("cornell_box.toml", Some("40M"), 1 << 20, "cannot spill link ends"),
        ("fan_room.toml", Some("48M"), 40 << 20, "cannot spill per-frame link changes"),
    ] {
        let scene = scenes.join(scene);
        let mut c = Command::new(env!("CARGO_BIN_EXE_illumnet"));
        c.args(["build", "-q", scene.to_str().unwrap(), "-o", out.to_str().unwrap()]);
        if let Some(b) = budget {
            c.args(["--memory-budget", b]);
        }
        // A file-size limit stands for a disk that fills up (the default
        // archive is 99 MB; under 40M its 79 spilled runs are 1.5 MiB on average).
        // SAFETY: setrlimit is async-signal-safe; nothing else runs in the child.
        unsafe {
            c.pre_exec(move || {
                let limit = libc::rlimit { rlim_cur: limit, rlim_max: limit };
                if libc::setrlimit(libc::RLIMIT_FSIZE, &limit) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
        let o = c.output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(5), "{budget:?}: {:?} {err}", o.status);
        assert_eq!(err.matches("File too large").count(), 1, "{budget:?}: {err}");
        assert!(err.contains(what), "{budget:?}: {err}");
        assert_eq!(std::fs::read(&out).unwrap(), b"the previous archive");
        assert!(leftovers(dir.path()).is_empty(), "{budget:?}: {:?}", leftovers(dir.path()));
    }
}

#[test]
fn a_large_build_says_what_it_will_cost_before_it_starts() {
    // Killed once the first pair is traced: the estimate came before.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("big.inet");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell_box.toml");
    let args = ["build", "-q", scene.to_str().unwrap(), "-o", out.to_str().unwrap(), "--frequency", "40"];
    let o = illumnet(&[&args[..], &["--ray-spacing", "0.0015"]].concat(), Some("trace"));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.signal(), Some(9), "{err}");
    assert!(err.contains("note: this build traces 2.23e9 rays over 8001 direction pairs"), "{err}");
    // A small one says nothing.
    let o = illumnet(&[&args[..], &["--ray-spacing", "0.02"]].concat(), Some("trace"));
    assert!(!String::from_utf8_lossy(&o.stderr).contains("note:"));
}

#[test]
fn a_large_render_says_what_it_will_cost_before_it_starts() {
    use std::io::{BufRead, BufReader};
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("wide.toml");
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell_box.toml"))
        .unwrap()
        .replace("width = 256", "width = 16384")
        .replace("height = 256", "height = 16384");
    assert!(text.contains("width = 16384") && text.contains("height = 16384"));
    std::fs::write(&scene, text).unwrap();
    let archive = dir.path().join("wide.inet");
    let b = illumnet(
        &["build", "-q", scene.to_str().unwrap(), "-o", archive.to_str().unwrap(), "--quality", "draft"],
        None,
    );
    assert!(b.status.success(), "{}", String::from_utf8_lossy(&b.stderr));
    let mut child = Command::new(env!("CARGO_BIN_EXE_illumnet"))
        .args(["render", "-q", archive.to_str().unwrap(), "-o", dir.path().join("w.png").to_str().unwrap()])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let first = BufReader::new(child.stderr.take().unwrap()).lines().next().unwrap().unwrap();
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(
        first.contains("note: this render shades 4.29e9 image samples (16384×16384 pixels, 4×4 samples each"),
        "{first}"
    );
}

#[test]
fn a_really_full_filesystem_is_one_clear_error_that_leaves_nothing_behind() {
    // A 16 MiB tmpfs mounted in a private mount namespace (root, or an
    // unprivileged user namespace where the kernel allows one): the build
    // of the default Cornell box (140 MB), the same under a budget that
    // spills runs, and a render whose EXR does not fit all fail with one
    // "No space left on device" each and leave no file behind. Where no
    // filesystem can be mounted (a container without the privilege), the
    // test says so and checks nothing: `a_full_disk_is_one_clear_error_…`
    // covers the same code paths with a file-size limit everywhere.
    let bin = env!("CARGO_BIN_EXE_illumnet");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell_box.toml");
    let dir = tempfile::tempdir().unwrap();
    let (small, mnt) = (dir.path().join("small.inet"), dir.path().join("mnt"));
    std::fs::create_dir(&mnt).unwrap();
    let built =
        illumnet(&["build", "-q", scene.to_str().unwrap(), "-o", small.to_str().unwrap(), "--frequency", "4"], None);
    assert!(built.status.success());
    let script = format!(
        "mount -t tmpfs -o size=16m tmpfs {m} || exit 99\n\
         {bin} build -q {s} -o {m}/box.inet >/dev/null; echo \"build=$?\"; ls -A {m}\n\
         {bin} build -q {s} -o {m}/box.inet --memory-budget 40M >/dev/null; echo \"bounded=$?\"; ls -A {m}\n\
         head -c 16500000 /dev/zero > {m}/fill\n\
         {bin} render -q {a} -o {m}/x.png --exr {m}/x.exr >/dev/null; echo \"render=$?\"; ls -A {m}\n",
        m = mnt.display(),
        s = scene.display(),
        a = small.display(),
    );
    let root = unsafe { libc::geteuid() } == 0;
    let mut c = Command::new("unshare");
    c.args(if root { vec!["--mount"] } else { vec!["--mount", "--map-root-user"] }).args(["sh", "-c", &script]);
    let Ok(o) = c.output() else {
        eprintln!("skipped: no `unshare` here");
        return;
    };
    if o.status.code() == Some(99) || (!o.status.success() && o.stdout.is_empty()) {
        eprintln!("skipped: cannot mount a filesystem here ({})", String::from_utf8_lossy(&o.stderr).trim());
        return;
    }
    let (stdout, stderr) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    eprintln!("{stdout}{stderr}");
    let lines: Vec<&str> = stdout.lines().collect();
    // Each command's exit line is followed by what the mount holds.
    assert_eq!(lines.first(), Some(&"build=5"), "{stdout}{stderr}");
    assert_eq!(lines.get(1), Some(&"bounded=5"), "nothing left after the build: {stdout}");
    assert_eq!(lines.get(2), Some(&"render=5"), "nothing left after the bounded build: {stdout}");
    // The PNG fitted; the EXR did not and left no temporary.
    assert_eq!(&lines[3..], ["fill", "x.png"], "{stdout}");
    assert_eq!(stderr.matches("No space left on device").count(), 3, "{stderr}");
    assert!(stderr.contains("cannot write") && stderr.contains("x.exr"), "{stderr}");
    assert!(stderr.contains("cannot spill link ends"), "{stderr}");
}

/// Runs illumnet with `args` under a file-size limit of `limit` bytes,
/// which stands for a disk that fills up (the CLI ignores SIGXFSZ, so a
/// write past it fails with EFBIG).
fn illumnet_with_file_limit(args: &[&str], limit: u64) -> std::process::Output {
    use std::os::unix::process::CommandExt;
    let mut c = Command::new(env!("CARGO_BIN_EXE_illumnet"));
    c.args(args).env_remove("ILLUMNET_TEST_STOP_AT");
    // SAFETY: setrlimit is async-signal-safe; nothing else runs in the child.
    unsafe {
        c.pre_exec(move || {
            let limit = libc::rlimit { rlim_cur: limit, rlim_max: limit };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    c.output().unwrap()
}

#[test]
fn a_chart_that_does_not_fit_leaves_no_truncated_png_and_no_folder() {
    // Issue 42, class 6: a full disk left a truncated PNG under its final
    // name. The charts are ~20 kB each: 4 kB lets none be written.
    let dir = tempfile::tempdir().unwrap();
    let archive = dir.path().join("box.inet");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell_box.toml");
    let args = ["build", "-q", scene.to_str().unwrap(), "-o", archive.to_str().unwrap(), "--frequency", "4"];
    let built = illumnet(&args, None);
    assert!(built.status.success(), "{}", String::from_utf8_lossy(&built.stderr));
    let charts = dir.path().join("charts");
    let o = illumnet_with_file_limit(
        &["inspect", archive.to_str().unwrap(), "--histograms", "--charts", charts.to_str().unwrap()],
        4096,
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(5), "{err}");
    assert_eq!(err.matches("File too large").count(), 1, "{err}");
    assert!(err.contains("cannot write") && err.contains(".png"), "{err}");
    // No chart under its final name, no temporary, and the folder it made is gone.
    assert!(!charts.exists(), "{:?}", std::fs::read_dir(&charts).map(|d| d.count()));
    // Into a folder that exists: it stays, with nothing in it.
    std::fs::create_dir(&charts).unwrap();
    let o = illumnet_with_file_limit(
        &["inspect", archive.to_str().unwrap(), "--histograms", "--charts", charts.to_str().unwrap()],
        4096,
    );
    assert_eq!(o.status.code(), Some(5), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(std::fs::read_dir(&charts).unwrap().count(), 0);
}

#[test]
fn a_demo_that_does_not_fit_leaves_no_folder() {
    // Issue 42, class 6: `demo -o` on a full disk left the folder it made.
    // Its archive (~1.6 MB at --frequency 4) does not fit in 512 kB.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("new/demo");
    let args = ["demo", "-q", "-o", out.to_str().unwrap(), "--frequency", "4", "--quality", "draft"];
    let o = illumnet_with_file_limit(&args, 512 << 10);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(5), "{err}");
    assert_eq!(err.matches("File too large").count(), 1, "{err}");
    assert!(!dir.path().join("new").exists(), "demo left the folder it made");
    // A folder that existed is left, as it was.
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("mine.txt"), b"x").unwrap();
    let o = illumnet_with_file_limit(&args, 512 << 10);
    assert_eq!(o.status.code(), Some(5), "{}", String::from_utf8_lossy(&o.stderr));
    let left: Vec<_> = std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left, ["mine.txt"]);
}

/// A mapped render (`--size 32x32 --samples 1`) of `archive`, stopped at
/// `stage` (`scratch::pause_point`), `change`d there, then continued.
fn render_changed_at(archive: &Path, stage: &str, change: impl FnOnce(&Path)) -> (Option<i32>, String) {
    let png = archive.with_extension("png");
    let child = Command::new(env!("CARGO_BIN_EXE_illumnet"))
        .args(["render", "-q", archive.to_str().unwrap(), "-o", png.to_str().unwrap()])
        .args(["--size", "32x32", "--samples", "1"])
        .env_remove("ILLUMNET_TEST_STOP_AT")
        .env("ILLUMNET_TEST_PAUSE_AT", stage)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id() as libc::pid_t;
    let mut status = 0;
    // SAFETY: waits for our own child to stop; it stays a child (reaped below).
    let waited = unsafe { libc::waitpid(pid, &mut status, libc::WUNTRACED) };
    assert!(waited == pid && libc::WIFSTOPPED(status), "the render did not stop at {stage}: {status:#x}");
    change(archive);
    // SAFETY: continues our own stopped child.
    unsafe { libc::kill(pid, libc::SIGCONT) };
    let o = child.wait_with_output().unwrap();
    let code = o.status.code();
    assert_eq!(png.exists(), code == Some(0), "{stage}: an image written, or none, against its exit code");
    let _ = std::fs::remove_file(&png);
    (code, String::from_utf8_lossy(&o.stderr).into_owned())
}

#[test]
fn a_mapped_archive_cut_short_or_rewritten_under_a_render_is_an_error_not_a_crash() {
    // Issue 42, class 2: SIGBUS (exit 135) for a file truncated under the
    // mapping, exit 0 for one rewritten in place.
    let dir = tempfile::tempdir().unwrap();
    let archive = dir.path().join("box.inet");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell_box.toml");
    let args = ["build", "-q", scene.to_str().unwrap(), "-o", archive.to_str().unwrap(), "--frequency", "4"];
    let built = illumnet(&args, None);
    assert!(built.status.success(), "{}", String::from_utf8_lossy(&built.stderr));
    let bytes = std::fs::read(&archive).unwrap();
    let cut = |p: &Path| std::fs::OpenOptions::new().write(true).open(p).unwrap().set_len(4096).unwrap();
    // Cut short before the distribution reads the link ends: the fault
    // in the mapping is exit 5, with the SIGBUS handler's message.
    let (code, err) = render_changed_at(&archive, "distribute", cut);
    assert_eq!(code, Some(5), "{err}");
    assert!(err.contains("box.inet: the archive was cut short while it was mapped"), "{err}");
    // Cut short after the light is solved (no page read since faults):
    // the fingerprint's "ended early", exit 5.
    std::fs::write(&archive, &bytes).unwrap();
    let (code, err) = render_changed_at(&archive, "write", cut);
    assert_eq!(code, Some(5), "{err}");
    assert!(err.contains("box.inet: the file ended early (truncated while in use?)"), "{err}");
    // Rewritten in place, the same length (here the same bytes): exit 4.
    std::fs::write(&archive, &bytes).unwrap();
    let (code, err) = render_changed_at(&archive, "write", |p| {
        use std::io::Write;
        std::fs::OpenOptions::new().write(true).open(p).unwrap().write_all(&bytes).unwrap();
    });
    assert_eq!(code, Some(4), "{err}");
    assert!(err.contains("box.inet: the file changed on disk while in use (was the archive rewritten?)"), "{err}");
    // Replaced by a rename (how illumnet writes archives): not a change.
    std::fs::write(&archive, &bytes).unwrap();
    let (code, err) = render_changed_at(&archive, "write", |p| {
        let other = p.with_extension("new");
        std::fs::write(&other, &bytes).unwrap();
        std::fs::rename(&other, p).unwrap();
    });
    assert_eq!(code, Some(0), "{err}");
}
