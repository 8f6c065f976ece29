//! Special files given where a file is read (issue 42, class 3): a FIFO,
//! `/dev/zero` and a directory as every path-taking option and scene
//! field. Each run is under a timeout: none may hang (a FIFO opened for
//! reading waits for a writer), grow without bound (`/dev/zero` never
//! ends) or abort; each exits 5 (I/O) naming the file.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Longest a refused run may take.
const TIMEOUT: Duration = Duration::from_secs(10);

/// Runs `illumnet args`, killed (and the test failed) past [`TIMEOUT`]:
/// its exit code and stderr.
fn run_bounded(args: &[&str]) -> (i32, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_illumnet"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut err = String::new();
            std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
            use std::os::unix::process::ExitStatusExt;
            let code =
                status.code().unwrap_or_else(|| panic!("illumnet {args:?} died of signal {:?}", status.signal()));
            return (code, err);
        }
        if start.elapsed() > TIMEOUT {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!("illumnet {args:?} still running after {TIMEOUT:?}: it hangs");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The three special files, in `dir`: a FIFO, `/dev/zero` and a
/// directory, each with the name the error must show. Named `stem.ext`
/// where a name is made, so that commands that look at the extension
/// read them.
fn specials(dir: &Path, stem: &str, ext: &str) -> Vec<PathBuf> {
    let fifo = dir.join(format!("{stem}-fifo.{ext}"));
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    // SAFETY: a NUL-terminated path; mkfifo only makes a file.
    #[allow(unsafe_code)]
    let made = unsafe { libc::mkfifo(c.as_ptr(), 0o600) };
    assert_eq!(made, 0, "mkfifo {}", fifo.display());
    let folder = dir.join(format!("{stem}-dir.{ext}"));
    std::fs::create_dir(&folder).unwrap();
    vec![fifo, PathBuf::from("/dev/zero"), folder]
}

/// Asserts that `args` with `{}` replaced by `special` exits 5 naming it.
fn refused(args: &[&str], special: &Path, what: &str) {
    let s = special.to_str().unwrap();
    let args: Vec<String> = args.iter().map(|a| a.replace("{}", s)).collect();
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let (code, err) = run_bounded(&args);
    assert_eq!(code, 5, "{what} = {s}: illumnet {args:?} exited {code}:\n{err}");
    assert!(err.contains(s), "{what} = {s}: stderr does not name the file:\n{err}");
}

/// A TOML scene's camera and material, before a surface.
const MESH_HEAD: &str = "[camera]\nposition = [0, 0, -3]\nlook_at = [0, 0, 0]\nfov_y_deg = 40\nwidth = 8\nheight = 8\n\n\
                         [[material]]\nname = 'white'\ntype = 'diffuse'\nreflectance = [0.5, 0.5, 0.5]\n\n";

/// A small archive of the Cornell box in `dir`.
fn archive(dir: &Path) -> PathBuf {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell_box.toml");
    let out = dir.join("box.inet");
    let status = Command::new(env!("CARGO_BIN_EXE_illumnet"))
        .args(["build", "-q", scene.to_str().unwrap(), "-o", out.to_str().unwrap()])
        .args(["--frequency", "4", "--patch-size", "0.2"])
        .status()
        .unwrap();
    assert!(status.success());
    out
}

#[test]
fn scene_files_and_scene_fields_refuse_special_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("out.inet");
    let o = out.to_str().unwrap();
    let mut cases = 0;
    // The scene file itself (TOML, OBJ, glTF by extension).
    for ext in ["toml", "obj", "gltf"] {
        for special in specials(d, "scene", ext) {
            refused(&["build", "-q", "{}", "-o", o], &special, &format!("scene file .{ext}"));
            cases += 1;
        }
    }
    for special in specials(d, "field", "obj") {
        let s = special.to_str().unwrap();
        // A TOML surface's `mesh`.
        let scene = d.join("mesh.toml");
        std::fs::write(
            &scene,
            format!(
                "{MESH_HEAD}[[surface]]\nname = \"m\"\nmaterial = \"white\"\n\
                 emission = [1, 1, 1]\nmesh = \"{s}\"\n"
            ),
        )
        .unwrap();
        refused(&["build", "-q", scene.to_str().unwrap(), "-o", o], &special, "mesh");
        // An OBJ's `mtllib`, also read for a `mesh` surface.
        let obj = d.join("mtllib.obj");
        std::fs::write(&obj, format!("mtllib {s}\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")).unwrap();
        refused(&["build", "-q", obj.to_str().unwrap(), "-o", o], &special, "mtllib");
        std::fs::write(
            &scene,
            format!(
                "{MESH_HEAD}[[surface]]\nname = \"m\"\nmaterial = \"white\"\nemission = [1, 1, 1]\nmesh = \"{}\"\n",
                obj.display()
            ),
        )
        .unwrap();
        refused(&["build", "-q", scene.to_str().unwrap(), "-o", o], &special, "mesh's mtllib");
        // An MTL's `map_Kd`.
        let mtl = d.join("tex.mtl");
        std::fs::write(&mtl, format!("newmtl lamp\nKd 0.5 0.5 0.5\nKe 1 1 1\nmap_Kd {s}\n")).unwrap();
        let obj = d.join("tex.obj");
        std::fs::write(
            &obj,
            "mtllib tex.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl lamp\nf 1/1 2/2 3/3\n",
        )
        .unwrap();
        refused(&["build", "-q", obj.to_str().unwrap(), "-o", o], &special, "map_Kd");
        // A glTF buffer's `uri`.
        let gltf = d.join("buffer.gltf");
        std::fs::write(
            &gltf,
            format!(r#"{{"asset": {{"version": "2.0"}}, "buffers": [{{"uri": "{s}", "byteLength": 36}}]}}"#),
        )
        .unwrap();
        refused(&["build", "-q", gltf.to_str().unwrap(), "-o", o], &special, "glTF buffer uri");
        cases += 5;
    }
    assert_eq!(cases, 24);
}

#[test]
fn archives_images_and_camera_files_refuse_special_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let png = d.join("out.png");
    let p = png.to_str().unwrap();
    let mut cases = 0;
    for special in specials(d, "archive", "inet") {
        refused(&["render", "-q", "{}", "-o", p], &special, "render's archive");
        refused(&["verify", "{}"], &special, "verify's archive");
        refused(&["inspect", "{}"], &special, "inspect's archive");
        refused(&["upgrade", "{}", "-o", d.join("up.inet").to_str().unwrap()], &special, "upgrade's archive");
        cases += 4;
    }
    let real = archive(d);
    let a = real.to_str().unwrap();
    let exr = d.join("real.exr");
    let status = Command::new(env!("CARGO_BIN_EXE_illumnet"))
        .args(["render", "-q", a, "-o", p, "--exr", exr.to_str().unwrap(), "--size", "16x16"])
        .status()
        .unwrap();
    assert!(status.success());
    let e = exr.to_str().unwrap();
    for special in specials(d, "camera", "toml") {
        refused(&["render", "-q", a, "-o", p, "--camera-from", "{}"], &special, "--camera-from");
        refused(&["render", "-q", a, "-o", p, "--camera-path", "{}"], &special, "--camera-path");
        cases += 2;
    }
    // compare takes `.exr` names only, so /dev/zero is refused by its name.
    for special in specials(d, "image", "exr").into_iter().filter(|s| s.extension().is_some()) {
        refused(&["compare", "{}", e], &special, "compare's image");
        refused(&["compare", e, "{}"], &special, "compare's reference");
        cases += 2;
    }
    assert_eq!(cases, 22);
}
