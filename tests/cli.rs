//! The `illumnet` binary end to end on the Cornell box.

mod common;

use std::path::Path;
use std::process::Command;

use illumnet::render::image_io::read_exr;

fn illumnet(args: &[&str]) -> std::process::Output {
    let out = Command::new(env!("CARGO_BIN_EXE_illumnet")).args(args).output().unwrap();
    assert!(
        out.status.success(),
        "illumnet {args:?} failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

#[test]
fn demo_shows_colour_bleeding_and_an_indirectly_lit_ceiling() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let out = illumnet(&["demo", "-q", "-o", d]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("energy balance: emitted"), "{stdout}");
    assert!(dir.path().join("cornell_box.png").exists());
    let img = read_exr(&dir.path().join("cornell_box.exr")).unwrap();
    assert_eq!((img.width, img.height), (256, 256));
    // The back wall spans x ≈ 55..201 px, y ≈ 55..200; its upper part is clear of blocks.
    // Red wall on the left of the image, green on the right.
    let near_red = img.mean(58, 60, 70, 90);
    let near_green = img.mean(186, 60, 198, 90);
    let rg = |c: [f32; 3]| c[0] / c[1];
    assert!(rg(near_red) > 1.1 * rg(near_green), "red bleeding: {near_red:?} vs {near_green:?}");
    assert!(near_green[1] / near_green[0] > 1.1 * near_red[1] / near_red[0], "green bleeding");
    let red_wall = img.mean(10, 100, 30, 150);
    assert!(red_wall[0] > 3.0 * red_wall[1], "red wall is red: {red_wall:?}");
    // The ceiling (y ≈ 5..55 px) sees no direct light, yet is clearly lit.
    let ceiling = img.mean(70, 10, 95, 20);
    let back = img.mean(90, 60, 170, 90);
    assert!(luminance(ceiling) > 0.15 * luminance(back), "ceiling {ceiling:?}, back wall {back:?}");
    assert!(luminance(ceiling) < luminance(back), "ceiling {ceiling:?} brighter than the lit back wall {back:?}");
    // The light (rows ≈ 32..41) shows its emitted radiance (18.4, 14.0, 6.8) and more.
    let light = img.at(128, 36);
    assert!(light[0] > 18.0 && light[1] > 13.5, "light pixel {light:?}");
}

#[test]
fn build_inspect_render_with_json() {
    let dir = tempfile::tempdir().unwrap();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell_box.toml");
    let archive = dir.path().join("box.inet");
    let a = archive.to_str().unwrap();
    illumnet(&["build", "-q", scene.to_str().unwrap(), "-o", a, "--frequency", "6", "--patch-size", "0.05"]);
    let out = illumnet(&["inspect", a, "--json"]);
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["format_version"], 11);
    assert_eq!(json["version_read"], 11, "a still numbers its patches in a spatial order");
    assert_eq!(json["directions"], 362);
    assert!(json["patches"].as_u64().unwrap() > 500);
    assert!(json["links"].as_u64().unwrap() > 1000);
    assert!(json["sections"].as_array().unwrap().iter().any(|s| s["tag"] == "LOTH"));
    assert_eq!(json["camera"]["width"], 256);
    assert_eq!(json["material_models"][1], "diffuse");
    let light = &json["surface_details"].as_array().unwrap().iter().find(|s| s["name"] == "light").unwrap().clone();
    assert!(light["power_w"][0].as_f64().unwrap() > 0.0 && light["area_m2"].as_f64().unwrap() > 0.0);
    // One patch explained: the floor's first, its ends carrying no more
    // rays than cross it, every other patch it reaches on another surface.
    // (Patches are numbered along a spatial curve: find its id.)
    let floor = {
        let archive = illumnet::archive::Archive::open(Path::new(a)).unwrap();
        let v = archive.view();
        let s = archive.meta().surface_names.iter().position(|n| n == "floor").unwrap();
        v.primitives[v.surfaces[s].first_primitive as usize].first_patch.to_string()
    };
    let out = illumnet(&["inspect", a, "--patch", &floor, "--json"]);
    let p: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!((p["surface"].as_str(), p["kind"].as_str()), (Some("floor"), Some("quad")), "{p}");
    let (ends, rays, hits) =
        (p["link_ends"].as_u64().unwrap(), p["rays"].as_f64().unwrap(), p["hits"].as_f64().unwrap());
    assert!(ends > 10 && rays >= ends as f64 && rays <= hits, "{p}");
    let heaviest = p["heaviest"].as_array().unwrap();
    assert!(!heaviest.is_empty() && heaviest.iter().all(|h| h["surface"] != "floor"), "{p}");
    assert!(heaviest.windows(2).all(|w| w[0]["rays"].as_f64() >= w[1]["rays"].as_f64()), "{p}");
    let text = String::from_utf8_lossy(&illumnet(&["inspect", a, "--patch", &floor]).stdout).to_string();
    assert!(text.contains("surface floor (white)") && text.contains("heaviest:"), "{text}");
    let out =
        Command::new(env!("CARGO_BIN_EXE_illumnet")).args(["inspect", a, "--patch", "99999999"]).output().unwrap();
    assert_eq!(out.status.code(), Some(3), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--patch 99999999: the archive has patches 0.."));
    let png = dir.path().join("img.png");
    let render = illumnet(&["render", "-q", a, "-o", png.to_str().unwrap(), "--samples", "1"]);
    assert!(png.exists());
    // The text view names the camera, materials, surfaces and emitters, and
    // its emitted power (π·L·area) is the energy balance's.
    let text = String::from_utf8(illumnet(&["inspect", a]).stdout).unwrap();
    for needle in
        ["camera: at [0.278, 0.273, -0.8]", "red: diffuse", "tall_block: white, 5 primitives", "emitters: 1 surface"]
    {
        assert!(text.contains(needle), "{needle}: {text}");
    }
    let number_after = |text: &str, key: &str| -> f64 {
        let rest = &text[text.find(key).unwrap_or_else(|| panic!("{key}: {text}")) + key.len()..];
        rest.split_whitespace().next().unwrap().parse().unwrap()
    };
    let listed = number_after(&text, "emitting ");
    let balance = number_after(&String::from_utf8_lossy(&render.stdout), "emitted ");
    assert!((listed - balance).abs() < 1e-3 * balance, "inspect {listed} W vs energy balance {balance} W");
    let json_w = json["emitted_w"].as_f64().unwrap();
    assert!((json_w - balance).abs() < 1e-3 * balance, "--json {json_w} W vs energy balance {balance} W");
}

#[test]
fn bad_input_gives_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("bad.toml");
    std::fs::write(&scene, "[camera]\nposition = [0, 0, -1]\nlook_at = [0, 0, 0]\nfov_y_deg = 40\nwidth = 8\nheight = 8\n[[material]]\nname = 'w'\ntype = 'glass'\n").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_illumnet"))
        .args(["build", scene.to_str().unwrap(), "-o", dir.path().join("x.inet").to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.toml:9:") && err.contains("material[0].type") && err.contains("glass"), "{err}");
    assert!(!dir.path().join("x.inet").exists());

    let junk = dir.path().join("junk.inet");
    std::fs::write(&junk, b"hello").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_illumnet")).args(["inspect", junk.to_str().unwrap()]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("corrupt archive"));
}

/// Runs illumnet expecting failure; returns its exit code and stderr.
fn failing(args: &[&str]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_illumnet")).args(args).output().unwrap();
    assert!(!out.status.success(), "illumnet {args:?} succeeded");
    (out.status.code().unwrap_or(-1), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn exit_codes_tell_the_kind_of_failure() {
    // The codes the README documents: 2 usage, 3 bad input, 4 corrupt
    // archive, 5 I/O.
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell_box.toml");
    let scene = scene.to_str().unwrap();
    assert_eq!(failing(&["render", "--no-such-option", "x.inet"]).0, 2);
    std::fs::write(path("bad.toml"), "[camera]\nposition = [0, 0]\n").unwrap();
    assert_eq!(failing(&["build", &path("bad.toml"), "-o", &path("x.inet")]).0, 3);
    // A scene that cannot be read at all: I/O, as for an archive.
    assert_eq!(failing(&["build", &path("none.toml"), "-o", &path("x.inet")]).0, 5);
    assert_eq!(failing(&["build", scene, "-o", &path("x.inet"), "--frame", "3"]).0, 3);
    assert_eq!(failing(&["build", scene, "-o", &path("x.inet"), "--turn", "nothing"]).0, 3);
    std::fs::write(path("junk.inet"), b"hello").unwrap();
    assert_eq!(failing(&["inspect", &path("junk.inet")]).0, 4);
    let (code, err) = failing(&["render", &path("missing.inet"), "-o", &path("x.png")]);
    assert_eq!(code, 5, "{err}");
    illumnet(&["build", "-q", scene, "-o", &path("box.inet"), "--frequency", "4", "--patch-size", "0.1"]);
    assert_eq!(failing(&["render", &path("box.inet"), "-o", &path("x.png"), "--frames", "1..3"]).0, 3);
    assert_eq!(failing(&["render", &path("box.inet"), "-o", &path("x.png"), "--set", "nobody.emission=1,1,1"]).0, 3);
    // An option's value out of range.
    let (code, err) = failing(&["render", &path("box.inet"), "-o", &path("x.png"), "--tolerance", "2"]);
    assert_eq!(code, 3, "{err}");
    // An output that cannot be written.
    std::fs::write(path("file"), b"").unwrap();
    let (code, err) = failing(&["render", &path("box.inet"), "-q", "-o", &format!("{}/x.png", path("file"))]);
    assert_eq!(code, 5, "{err}");
    // Not converged: an error (nothing written) unless allowed.
    let (code, err) =
        failing(&["render", &path("box.inet"), "-q", "-o", &path("u.png"), "--max-iterations", "1", "--anderson", "0"]);
    assert_eq!(code, 7, "{err}");
    assert!(err.contains("did not converge in 1 iterations") && err.contains("--allow-unconverged"), "{err}");
    assert!(!dir.path().join("u.png").exists());
    illumnet(&[
        "render",
        &path("box.inet"),
        "-q",
        "-o",
        &path("u.png"),
        "--max-iterations",
        "1",
        "--anderson",
        "0",
        "--allow-unconverged",
    ]);
    assert!(dir.path().join("u.png").exists());
}

#[test]
fn sequence_archives_render_frame_ranges() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("anim.toml");
    std::fs::write(
        &scene,
        "[camera]\nposition = [1, 1, -2]\nlook_at = [1, 1, 1]\nfov_y_deg = 50\nwidth = 24\nheight = 16\n\
         [animation]\nframes = 4\n\
         [[material]]\nname = 'w'\ntype = 'diffuse'\nreflectance = [0.5, 0.5, 0.5]\n\
         [[surface]]\nname = 'room'\nmaterial = 'w'\nbox = { min = [0, 0, 0], max = [2, 2, 2], inward = true, omit = ['-z'] }\n\
         [[surface]]\nname = 'lamp'\nmaterial = 'w'\nemission = [4, 4, 4]\nbox = { min = [0.8, 1.6, 0.8], max = [1.2, 1.8, 1.2] }\n\
         keyframes = [{ frame = 0 }, { frame = 3, translate = [0.4, 0, 0.4] }]\n",
    )
    .unwrap();
    let a = dir.path().join("anim.inet");
    let (s, a) = (scene.to_str().unwrap(), a.to_str().unwrap());
    let built = illumnet(&["build", "-q", s, "-o", a, "--frequency", "4", "--patch-size", "0.25"]);
    let built = String::from_utf8_lossy(&built.stdout);
    assert!(built.contains("sequence: 4 frames, 4 instances of moving surfaces"), "{built}");
    // `inspect` counts the lamp once (its instance at frame 0), not once per
    // frame: a 0.4 × 0.2 × 0.4 m box, 0.64 m², emitting π·4·0.64 W in each
    // of three channels.
    let text = String::from_utf8(illumnet(&["inspect", a]).stdout).unwrap();
    let lamp = text.lines().find(|l| l.trim_start().starts_with("lamp:")).unwrap_or_else(|| panic!("{text}"));
    assert!(lamp.contains("6 primitives") && lamp.contains("over 0.6400 m²"), "{lamp}");
    let watts: f64 = lamp.rsplit(": ").next().unwrap().trim_end_matches(" W").parse().unwrap();
    assert!((watts - std::f64::consts::PI * 4.0 * 0.64 * 3.0).abs() < 1e-3, "{lamp}");
    let json: serde_json::Value =
        serde_json::from_slice(&illumnet(&["inspect", a, "--surface", "lamp", "--json"]).stdout).unwrap();
    assert!((json["area_m2"].as_f64().unwrap() - 0.64).abs() < 1e-5, "{json}");
    assert_eq!(json["primitives"], 6, "{json}");
    let pattern = dir.path().join("f_%03d.png");
    let gif = dir.path().join("preview.gif");
    let sheet = dir.path().join("sheet.png");
    illumnet(&[
        "render",
        "-q",
        a,
        "--frames",
        "1..4",
        "-o",
        pattern.to_str().unwrap(),
        "--samples",
        "1",
        "--gif",
        gif.to_str().unwrap(),
        "--contact-sheet",
        sheet.to_str().unwrap(),
    ]);
    for f in 1..4 {
        assert!(dir.path().join(format!("f_{f:03}.png")).exists(), "frame {f}");
    }
    assert_eq!(&std::fs::read(&gif).unwrap()[..6], b"GIF89a");
    let sheet = image::open(&sheet).unwrap();
    assert_eq!((sheet.width(), sheet.height()), (3 * 24, 16), "three frames in one row");
    assert!(!dir.path().join("f_000.png").exists());
    let fail = |args: &[&str], needle: &str| {
        let out = Command::new(env!("CARGO_BIN_EXE_illumnet")).args(args).output().unwrap();
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(needle), "{args:?}: {err}");
    };
    fail(&["render", a, "--frames", "2..9", "-o", pattern.to_str().unwrap()], "outside the archive's sequence 0..4");
    fail(&["render", a, "--frames", "0..2", "-o", dir.path().join("x.png").to_str().unwrap()], "frame number pattern");
    fail(&["build", s, "--frame", "4", "-o", a], "outside the sequence 0..4");
    // Without --frames a sequence renders all its frames, so one file name
    // without a pattern is refused, saying how many frames there are.
    fail(&["render", a, "-o", dir.path().join("x.png").to_str().unwrap()], "the 4 frames 0..4");
    let all = dir.path().join("all_%d.png");
    illumnet(&["render", "-q", a, "-o", all.to_str().unwrap(), "--samples", "1"]);
    assert!((0..4).all(|f| dir.path().join(format!("all_{f}.png")).exists()));
    // Open and inclusive ranges.
    for (range, want) in [("2..", vec![2, 3]), ("0..=1", vec![0, 1]), ("..1", vec![0])] {
        let sub = dir.path().join(range.replace('.', "d").replace('=', "e"));
        std::fs::create_dir(&sub).unwrap();
        let pattern = sub.join("f_%d.png");
        illumnet(&["render", "-q", a, "--frames", range, "-o", pattern.to_str().unwrap(), "--samples", "1"]);
        let got: Vec<u32> = (0..4).filter(|f| sub.join(format!("f_{f}.png")).exists()).collect();
        assert_eq!(got, want, "--frames {range}");
    }
    // A frame farm: frames rendered in a range of their own are, with
    // --cold, the whole sequence's frames byte for byte; warm (each range's
    // first frame then starts from zero) within one 8-bit level, the
    // tolerance's order. Default shading: per-pixel direct light, sampled.
    let render = |range: &str, name: &str, cold: bool| {
        let sub = dir.path().join(name);
        std::fs::create_dir(&sub).unwrap();
        let pattern = sub.join("f_%d.png");
        let mut args = vec!["render", "-q", a, "--frames", range, "-o", pattern.to_str().unwrap(), "--samples", "2"];
        args.extend(cold.then_some("--cold"));
        illumnet(&args);
        (2..4).map(|f| image::open(sub.join(format!("f_{f}.png"))).unwrap().to_rgb8().into_raw()).collect::<Vec<_>>()
    };
    assert_eq!(render("0..4", "cold_whole", true), render("2..4", "cold_part", true), "--cold: the same bytes");
    let (whole, part) = (render("0..4", "warm_whole", false), render("2..4", "warm_part", false));
    let worst = whole.iter().flatten().zip(part.iter().flatten()).map(|(x, y)| x.abs_diff(*y)).max();
    assert!(worst.is_some_and(|w| w <= 1), "warm: frames 2 and 3 differ by {worst:?} levels");
    fail(&["render", a, "--frames", "3..=2", "-o", pattern.to_str().unwrap()], "is empty");
    fail(&["render", a, "--frames", "two", "-o", pattern.to_str().unwrap()], "expected a range like 0..60");
    fail(&["render", a, "--frames", "4294967295", "-o", pattern.to_str().unwrap()], "out of range");
    fail(
        &["render", a, "--frames", "0..2", "-o", dir.path().join("f_%0999999d.png").to_str().unwrap()],
        "frame number pattern",
    );
}

#[test]
fn relighting_changes_light_without_a_rebuild() {
    let dir = tempfile::tempdir().unwrap();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell_box.toml");
    let a = dir.path().join("box.inet");
    let a = a.to_str().unwrap();
    illumnet(&["build", "-q", scene.to_str().unwrap(), "-o", a, "--frequency", "6", "--patch-size", "0.05"]);
    let render = |name: &str, sets: &[&str]| {
        let png = dir.path().join(format!("{name}.png"));
        let exr = dir.path().join(format!("{name}.exr"));
        let mut args =
            vec!["render", "-q", a, "-o", png.to_str().unwrap(), "--exr", exr.to_str().unwrap(), "--samples", "1"];
        for s in sets {
            args.extend(["--set", s]);
        }
        illumnet(&args);
        read_exr(&exr).unwrap()
    };
    let base = render("base", &[]);
    // Twice the light: everything lit doubles (the light is the only emitter).
    let double = render("double", &["light.emission=36.774,27.9746,13.50714"]);
    let (b, d) = (base.mean(60, 60, 200, 200), double.mean(60, 60, 200, 200));
    for c in 0..3 {
        assert!((d[c] / b[c] - 2.0).abs() < 1e-3, "band {c}: {} vs {}", d[c], b[c]);
    }
    // A grey red wall: no more red bleeding onto the back wall near it.
    let grey = render("grey", &["red_wall.reflectance=0.5,0.5,0.5"]);
    let rg = |img: &illumnet::render::Image| {
        let m = img.mean(58, 60, 70, 90);
        m[0] / m[1]
    };
    assert!(rg(&grey) < rg(&base) * 0.9, "bleeding {} vs {}", rg(&grey), rg(&base));
    // Unknown names and bad values are clear errors.
    for (set, needle) in [
        ("lamp.emission=1,1,1", "no surface named `lamp`"),
        ("light.colour=1,1,1", "unknown field `colour`"),
        ("white.reflectance=2,0,0", "in [0, 1]"),
        ("light.emission=1,1", "three numbers"),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_illumnet"))
            .args(["render", a, "-o", dir.path().join("x.png").to_str().unwrap(), "--set", set])
            .output()
            .unwrap();
        assert!(!out.status.success());
        assert!(
            String::from_utf8_lossy(&out.stderr).contains(needle),
            "{set}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

#[test]
fn brushed_plate_turns_relights_and_reports_its_reflectance() {
    let dir = tempfile::tempdir().unwrap();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/brushed_plate.toml");
    let lib = dir.path().join("protos");
    let archive = dir.path().join("plate.inet");
    let (s, a, l) = (scene.to_str().unwrap(), archive.to_str().unwrap(), lib.to_str().unwrap());
    let out = illumnet(&["build", "-q", s, "-o", a, "--turn", "plate=45", "--prototype-library", l]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("364 non-diffuse patches, 1 prototype table (0 from the library)"), "{text}");
    let out = illumnet(&["build", "-q", s, "-o", a, "--turn", "plate=45", "--prototype-library", l]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("(1 from the library)"));
    let json: serde_json::Value = serde_json::from_slice(&illumnet(&["inspect", a, "--json"]).stdout).unwrap();
    // Its two quads lie along the curve already: primitive order, version 10.
    assert_eq!((json["format_version"].as_u64(), json["version_read"].as_u64()), (Some(11), Some(10)));
    assert_eq!((json["prototype_tables"].as_u64(), json["nondiffuse_patches"].as_u64()), (Some(1), Some(364)));
    // Its rays per glossy patch and direction pair: one count for each of
    // the 364 patches × N/2 pairs, and as many rays as NDHC holds in all.
    let h: serde_json::Value =
        serde_json::from_slice(&illumnet(&["inspect", a, "--histograms", "--json"]).stdout).unwrap();
    let bins = h["histograms"]["rays_per_glossy_patch_direction"]["bins"].as_array().unwrap();
    let counted: u64 = bins.iter().map(|b| b["count"].as_u64().unwrap()).sum();
    assert_eq!(counted, 364 * json["directions"].as_u64().unwrap() / 2);
    assert!(bins.iter().skip(1).any(|b| b["count"].as_u64().unwrap() > 0), "some pairs carry rays");
    // Relighting the specular colour: a dimmer plate, same archive.
    let (bright, dim) = (dir.path().join("bright.exr"), dir.path().join("dim.exr"));
    let png = dir.path().join("p.png");
    let p = png.to_str().unwrap();
    illumnet(&["render", "-q", a, "-o", p, "--exr", bright.to_str().unwrap()]);
    illumnet(&["render", "-q", a, "-o", p, "--exr", dim.to_str().unwrap(), "--set", "brushed.specular=0.3,0.3,0.3"]);
    let total = |path: &Path| read_exr(path).unwrap().pixels.iter().map(|&c| luminance(c).min(1.0) as f64).sum::<f64>();
    let (b, d) = (total(&bright), total(&dim));
    assert!(d < 0.5 * b && d > 0.0, "relit plate {d} vs {b}");
    // Clear errors.
    let fail = |args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_illumnet")).args(args).output().unwrap();
        assert!(!out.status.success(), "{args:?} succeeded");
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let e = fail(&["build", "-q", s, "-o", a, "--turn", "plank=45"]);
    assert!(e.contains("no surface named `plank`") && e.contains("plate"), "{e}");
    let e = fail(&["render", "-q", a, "-o", p, "--set", "lamp.specular=1,1,1"]);
    assert!(e.contains("diffuse"), "{e}");
    let e = fail(&["render", "-q", a, "-o", p, "--set", "brushed.specular=2,1,1"]);
    assert!(e.contains("[0, 1]"), "{e}");
}

#[test]
fn a_new_users_mistakes_get_plain_answers() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell_box.toml");
    let scene = scene.to_str().unwrap();
    // A scene given to render or inspect: say to build it.
    let (code, err) = failing(&["render", scene, "-o", &path("x.png")]);
    assert_eq!(code, 3, "{err}");
    assert!(err.contains("is a scene, not an archive") && err.contains("illumnet build"), "{err}");
    std::fs::copy(scene, path("room.txt")).unwrap();
    let (code, err) = failing(&["inspect", &path("room.txt")]);
    assert!(code == 3 && err.contains("is a scene"), "{err}");
    // And to verify.
    let (code, err) = failing(&["verify", scene]);
    assert!(code == 3 && err.contains("is a scene, not an archive"), "{err}");
    illumnet(&["build", "-q", scene, "-o", &path("box.inet"), "--frequency", "4", "--patch-size", "0.1"]);
    // An archive given to build: say what to do with it.
    let (code, err) = failing(&["build", &path("box.inet"), "-o", &path("again.inet")]);
    assert!(code == 3 && err.contains("is an archive, not a scene"), "{err}");
    // A missing archive: the OS error, naming the file once.
    let (code, err) = failing(&["inspect", &path("nope.inet")]);
    assert!(code == 5 && err.matches("nope.inet").count() == 1, "{err}");
    // Image formats follow the option, not the file name: refused, not mislabelled.
    let (code, err) = failing(&["render", &path("box.inet"), "-o", &path("x.exr")]);
    assert!(code == 3 && err.contains("--exr"), "{err}");
    assert!(!dir.path().join("x.exr").exists());
    let (code, err) = failing(&["render", &path("box.inet"), "-o", &path("x.png"), "--exr", &path("y.png")]);
    assert!(code == 3 && err.contains("name it .exr"), "{err}");
    // --set of a field fixed at build time, or of no field.
    let (code, err) = failing(&["render", &path("box.inet"), "-o", &path("x.png"), "--set", "light.alpha=0.5"]);
    assert!(code == 3 && err.contains("rebuild"), "{err}");
    let (code, err) = failing(&["render", &path("box.inet"), "-o", &path("x.png"), "--set", "light.colour=1,1,1"]);
    assert!(code == 3 && err.contains("unknown field `colour`"), "{err}");
    // A negative number is a value (not an option), and out of range here.
    let (code, err) = failing(&["render", &path("box.inet"), "-o", &path("x.png"), "--exposure", "-1"]);
    assert!(code == 3 && err.contains("--exposure") && err.contains("positive"), "{err}");
    // compare judges linear radiance only.
    illumnet(&["render", "-q", &path("box.inet"), "-o", &path("a.png"), "--exr", &path("a.exr"), "--samples", "1"]);
    let (code, err) = failing(&["compare", &path("a.png"), &path("a.exr")]);
    assert!(code == 3 && err.contains("sRGB"), "{err}");
    let (code, err) = failing(&["compare", &path("box.inet"), &path("a.exr")]);
    assert!(code == 3 && err.contains("OpenEXR") && !err.contains("sRGB"), "{err}");
    // An archive named as an image, and demo into a file: refused.
    let (code, err) = failing(&["build", scene, "-o", &path("box.png")]);
    assert!(code == 3 && err.contains("name it .inet") && !dir.path().join("box.png").exists(), "{err}");
    let (code, err) = failing(&["demo", "-o", &path("a.png")]);
    assert!(code == 3 && err.contains("folder"), "{err}");
    // demo checks its render options before it builds.
    let (code, err) = failing(&["demo", "-o", &path("d"), "--exposure", "0"]);
    assert!(code == 3 && err.contains("--exposure") && !dir.path().join("d/cornell_box.inet").exists(), "{err}");
    illumnet(&["compare", &path("a.exr"), &path("a.exr")]);
    // Brighter pixels judged with --below (the emitters too, above their radiance).
    let all = illumnet(&["compare", &path("a.exr"), &path("a.exr"), "--below", "1000"]);
    let all = String::from_utf8_lossy(&all.stdout);
    let (w, h) = image::image_dimensions(path("a.png")).unwrap();
    assert!(all.contains("relative L2 0.0000") && all.contains(&format!("over {} pixels", w * h)), "{all}");
    let (code, err) = failing(&["compare", &path("a.exr"), &path("a.exr"), "--below", "0"]);
    assert!(code == 3 && err.contains("--below"), "{err}");

    // A scene without light, and one whose lamp faces away: rendered, with
    // a warning that says why the picture is dark.
    let base = "[camera]\nposition = [0, 1, -3]\nlook_at = [0, 0, 0]\nfov_y_deg = 40\nwidth = 8\nheight = 8\n\
        [[material]]\nname = 'grey'\ntype = 'diffuse'\nreflectance = [0.5, 0.5, 0.5]\n\
        [[surface]]\nname = 'floor'\nmaterial = 'grey'\nquad = [[-1, 0, -1], [-1, 0, 1], [1, 0, 1], [1, 0, -1]]\n";
    let lamp_up = "[[surface]]\nname = 'lamp'\nmaterial = 'grey'\nemission = [5, 5, 5]\n\
        quad = [[-0.2, 1, 0.2], [0.2, 1, 0.2], [0.2, 1, -0.2], [-0.2, 1, -0.2]]\n";
    // A lamp under a ceiling turned the wrong way: its light goes into the
    // ceiling's black back, which absorbs it (not "escapes").
    let wrong_ceiling = "[[surface]]\nname = 'ceiling'\nmaterial = 'grey'\n\
        quad = [[-2, 1.1, 2], [2, 1.1, 2], [2, 1.1, -2], [-2, 1.1, -2]]\n";
    for (name, text, needle) in [
        ("dark", base.to_string(), "emits no light"),
        ("away", format!("{base}{lamp_up}"), "face away"),
        ("behind", format!("{base}{lamp_up}{wrong_ceiling}"), "into the back faces"),
    ] {
        std::fs::write(path(&format!("{name}.toml")), text).unwrap();
        let archive = path(&format!("{name}.inet"));
        illumnet(&["build", "-q", &path(&format!("{name}.toml")), "-o", &archive, "--frequency", "4"]);
        let out = illumnet(&["render", "-q", &archive, "-o", &path(&format!("{name}.png")), "--samples", "1"]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("warning") && err.contains(needle), "{name}: {err}");
    }
    // Seen from below, the floor and lamp show their backs: said so.
    let below = base
        .replace("position = [0, 1, -3]", "position = [0, -1, -0.5]")
        .replace("look_at = [0, 0, 0]", "look_at = [0, 0, 0.1]");
    std::fs::write(
        path("below.toml"),
        format!(
            "{below}{}",
            lamp_up.replace(
                "[-0.2, 1, 0.2], [0.2, 1, 0.2], [0.2, 1, -0.2], [-0.2, 1, -0.2]",
                "[-0.2, 1, -0.2], [0.2, 1, -0.2], [0.2, 1, 0.2], [-0.2, 1, 0.2]"
            )
        ),
    )
    .unwrap();
    illumnet(&["build", "-q", &path("below.toml"), "-o", &path("below.inet"), "--frequency", "4"]);
    let out = illumnet(&["render", "-q", &path("below.inet"), "-o", &path("below.png"), "--samples", "1"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("back faces"), "{err}");
    // A lit scene gives no such warning.
    let out = illumnet(&["render", "-q", &path("box.inet"), "-o", &path("b.png"), "--samples", "1"]);
    assert!(!String::from_utf8_lossy(&out.stderr).contains("warning"));
    // A camera behind the box sees the back of its far wall (a third of
    // the image) and the background: a black image, said so.
    let (a, png) = (path("box.inet"), path("behind.png"));
    for shading in ["direct", "inet"] {
        let out = illumnet(&[
            "render",
            "-q",
            &a,
            "-o",
            &png,
            "--samples",
            "1",
            "--camera-position",
            "0.278,0.2744,1.879",
            "--look-at",
            "0.278,0.2744,0.2796",
            "--shading",
            shading,
        ]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("sees almost no surface's front") && err.contains("% nothing"), "{shading}: {err}");
    }
}

/// Any view from one archive: the same camera given at build time and at
/// render time gives the same image (a diffuse box and a glossy plate, whose
/// highlights follow the eye), from a file or field by field; a walkthrough
/// over a still archive solves the light once.
#[test]
fn any_view_from_one_archive() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let moved = |scene: &str, from: &str, to: &str| {
        let text = std::fs::read_to_string(root.join("scenes").join(scene)).unwrap();
        assert!(text.contains(from), "{scene} has no `{from}`");
        let text = text.replace(from, to).replace("width = 256", "width = 64").replace("height = 256", "height = 48");
        let text = text.replace("width = 192", "width = 64").replace("height = 192", "height = 48");
        std::fs::write(path(&format!("moved_{scene}")), text).unwrap();
    };
    moved("cornell_box.toml", "position = [0.278, 0.273, -0.800]", "position = [0.45, 0.40, -0.55]");
    moved("glossy_floor.toml", "position = [0.278, 0.273, -0.800]", "position = [0.45, 0.40, -0.55]");
    for (scene, fields) in [
        ("cornell_box.toml", ["--camera-position", "0.45,0.40,-0.55", "--size", "64x48"]),
        ("glossy_floor.toml", ["--camera-position", "0.45,0.40,-0.55", "--size", "64x48"]),
    ] {
        let quality = ["--frequency", "8", "--patch-size", "0.05"];
        let original = root.join("scenes").join(scene);
        let a = path(&format!("a_{scene}.inet"));
        illumnet(&[&["build", "-q", original.to_str().unwrap(), "-o", &a][..], &quality[..]].concat());
        let m = path(&format!("moved_{scene}"));
        illumnet(&[&["build", "-q", &m, "-o", &path("m.inet")][..], &quality[..]].concat());
        illumnet(&["render", "-q", &path("m.inet"), "-o", &path("built.png"), "--exr", &path("built.exr")]);
        let built = read_exr(Path::new(&path("built.exr"))).unwrap();
        assert_eq!((built.width, built.height), (64, 48));
        for how in [vec!["--camera-from", m.as_str()], fields.to_vec()] {
            let mut args = vec!["render", "-q", a.as_str()];
            let (png, exr) = (path("given.png"), path("given.exr"));
            args.extend(["-o", &png, "--exr", &exr]);
            args.extend(how.iter().copied());
            illumnet(&args);
            let given = read_exr(Path::new(&exr)).unwrap();
            assert!(given == built, "{scene}: the camera given at render time ({how:?}) changed the image");
        }
    }
    // A walkthrough of three frames over the still box: the light is solved
    // once; frame 0 is the view from the path's first key.
    std::fs::write(
        path("walk.toml"),
        "[animation]\nframes = 3\n[camera]\nposition = [0.278, 0.273, -0.8]\nlook_at = [0.278, 0.273, 0.0]\n\
         fov_y_deg = 39.3\nwidth = 32\nheight = 32\nkeyframes = [\n\
         { frame = 0, position = [0.278, 0.273, -0.8], look_at = [0.278, 0.273, 0.0] },\n\
         { frame = 2, position = [0.2, 0.3, -0.3], look_at = [0.4, 0.2, 0.4] },\n]\n",
    )
    .unwrap();
    let boxed = path("a_cornell_box.toml.inet");
    let out = illumnet(&[
        "render",
        &boxed,
        "-o",
        &path("w_%d.png"),
        "--exr",
        &path("w_%d.exr"),
        "--camera-path",
        &path("walk.toml"),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(stdout.matches("the light is frame 0's: 0 iterations").count(), 2, "{stdout}");
    assert!(stdout.contains("rendered 3 frames"), "{stdout}");
    let frames: Vec<_> = (0..3).map(|f| read_exr(Path::new(&path(&format!("w_{f}.exr")))).unwrap()).collect();
    assert!(frames[0] != frames[1] && frames[1] != frames[2], "the camera moves");
    illumnet(&[
        "render",
        "-q",
        &boxed,
        "-o",
        &path("k.png"),
        "--exr",
        &path("k.exr"),
        "--size",
        "32x32",
        "--fov",
        "39.3",
        // A walkthrough does not gather nor sample edges finer by
        // default; one frame does.
        "--gather",
        "0",
        "--edge-samples",
        "0",
    ]);
    assert!(read_exr(Path::new(&path("k.exr"))).unwrap() == frames[0], "frame 0 is the first key's view");
    // Cameras that cannot be, refused before any work: a value out of its
    // range is bad input (3), one of the wrong form a usage error (2), a
    // file that cannot be read an I/O failure (5).
    for (bad, want) in [
        (vec!["--fov", "180"], 3),
        (vec!["--look-at", "0.278,0.9,-0.8"], 3),
        (vec!["--size", "0x10"], 3),
        (vec!["--camera-position", "1,2"], 2),
        (vec!["--camera-from", "nothing.toml"], 5),
    ] {
        let x = path("x.png");
        let mut args = vec!["render", boxed.as_str(), "-o", x.as_str()];
        args.extend(bad.iter().copied());
        let (code, err) = failing(&args);
        assert_eq!(code, want, "{bad:?}: {err}");
        assert!(!Path::new(&x).exists(), "{bad:?}: an image was written");
    }
}

/// PNGs through a tone curve, and every image saying what made it.
#[test]
fn tone_maps_and_metadata() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    common::coarse_box_archive(Path::new(&path("a.inet")));
    let mut light = Vec::new();
    for curve in ["clamp", "reinhard", "aces"] {
        let png = path(&format!("{curve}.png"));
        let exr = path(&format!("{curve}.exr"));
        illumnet(&["render", "-q", &path("a.inet"), "-o", &png, "--exr", &exr, "--tone-map", curve, "--samples", "1"]);
        let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&png).unwrap()));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        reader.next_frame(&mut buf).unwrap();
        let text = &reader.info().utf8_text;
        let get = |k: &str| text.iter().find(|t| t.keyword == k).map(|t| t.get_text().unwrap()).unwrap_or_default();
        assert!(get("illumnet.settings").contains(&format!("tone map {curve}")), "{}", get("illumnet.settings"));
        assert!(get("illumnet.archive").ends_with("a.inet"));
        // The light (radiance 17–18 in red) seen directly, at (128, 36),
        // and the back wall (radiance ~0.2), at (128, 80).
        light.push((buf[(36 * 256 + 128) * 3], buf[(80 * 256 + 128) * 3]));
    }
    let [clamp, reinhard, aces] = light[..] else { unreachable!() };
    assert_eq!(clamp.0, 255, "clamped");
    assert!(reinhard.0 < 255 && reinhard.0 > 200, "Reinhard never reaches white: {light:?}");
    // Mid-tones: Reinhard darkens them, the ACES curve lifts them.
    assert!(reinhard.1 < clamp.1 && clamp.1 < aces.1, "{light:?}");
}

/// `inspect --histograms`: every patch, link end and direction counted
/// once, in text and JSON; a sequence's frames too.
#[test]
fn inspect_histograms_count_everything_once() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    common::coarse_box_archive(Path::new(&path("a.inet")));
    let summary: serde_json::Value =
        serde_json::from_slice(&illumnet(&["inspect", &path("a.inet"), "--json"]).stdout).unwrap();
    let out = illumnet(&["inspect", &path("a.inet"), "--histograms", "--json"]);
    let h: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let total = |key: &str| -> u64 {
        h["histograms"][key]["bins"]
            .as_array()
            .unwrap_or_else(|| panic!("{key}"))
            .iter()
            .map(|b| b["count"].as_u64().unwrap())
            .sum()
    };
    assert_eq!(total("link_ends_per_patch"), summary["patches"].as_u64().unwrap());
    assert_eq!(total("hits_over_expected"), summary["patches"].as_u64().unwrap());
    assert_eq!(total("link_length_m"), summary["link_ends"].as_u64().unwrap());
    assert_eq!(total("link_ends_per_bucket"), summary["link_ends"].as_u64().unwrap());
    assert_eq!(total("link_ends_per_direction"), summary["directions"].as_u64().unwrap());
    assert!(h["histograms"].get("delta_records_per_frame").is_none(), "a still has no frames");
    // Link lengths lie within the box (0.56 m wide, diagonal under 1 m).
    let longest = h["histograms"]["link_length_m"]["bins"].as_array().unwrap().last().unwrap()["to"].as_f64().unwrap();
    assert!(longest <= 1.0, "{longest}");
    let text = String::from_utf8_lossy(&illumnet(&["inspect", &path("a.inet"), "--histograms"]).stdout).into_owned();
    assert!(text.contains("link ends per patch") && text.contains('#'), "{text}");
    let (code, _) = failing(&["inspect", &path("a.inet"), "--histograms", "--patch", "0"]);
    assert_eq!(code, 2, "one view at a time");

    // --charts: one PNG per histogram, bars in proportion to the counts.
    illumnet(&["inspect", &path("a.inet"), "--histograms", "--charts", &path("charts")]);
    for key in h["histograms"].as_object().unwrap().keys() {
        let img = image::open(dir.path().join("charts").join(format!("{key}.png"))).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (800, 480), "{key}");
        // Bar pixels (the chart's one dark purple): the tallest bar fills
        // most of the 400-pixel plot.
        let bar =
            |x: u32| (0..480).filter(|&y| img.get_pixel(x, y).0[0] < 120 && img.get_pixel(x, y).0[2] < 130).count();
        let heights: Vec<usize> = (0..800).map(bar).collect();
        assert!(heights.iter().any(|&n| n > 100), "{key}: no tall bar");
    }

    // inspect --surface: every surface's patches and link ends add up to
    // the archive's, and light exchange is reciprocal (each link is stored
    // at both its ends with one weight): rays A→B equal rays B→A.
    let names: Vec<String> =
        summary["surfaces"].as_array().unwrap().iter().map(|s| s.as_str().unwrap().to_string()).collect();
    let mut rays = std::collections::HashMap::new();
    let (mut patches, mut ends) = (0, 0);
    for n in &names {
        let out = illumnet(&["inspect", &path("a.inet"), "--surface", n, "--json"]);
        let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        patches += j["patches"].as_u64().unwrap();
        ends += j["link_ends"].as_u64().unwrap();
        for e in j["exchanges_with"].as_array().unwrap() {
            rays.insert((n.clone(), e["surface"].as_str().unwrap().to_string()), e["rays"].as_f64().unwrap());
        }
    }
    assert_eq!(patches, summary["patches"].as_u64().unwrap());
    assert_eq!(ends, summary["link_ends"].as_u64().unwrap());
    assert!(rays.len() > 20, "{rays:?}");
    for ((a, b), w) in &rays {
        let back = rays.get(&(b.clone(), a.clone())).copied().unwrap_or(0.0);
        assert!((back - w).abs() <= 1e-9 * w, "{a} → {b}: {w} rays, back {back}");
    }
    let text =
        String::from_utf8_lossy(&illumnet(&["inspect", &path("a.inet"), "--surface", "light"]).stdout).into_owned();
    assert!(text.contains("emits") && text.contains("light exchanged with"), "{text}");
    let (code, msg) = failing(&["inspect", &path("a.inet"), "--surface", "lamp"]);
    assert!(code == 3 && msg.contains("known: floor"), "{code} {msg}");
}

#[test]
fn gltf_scenes_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf");
    let glb = data.join("cornell_box.glb");
    let glb = glb.to_str().unwrap();
    let quality = ["--frequency", "8", "--patch-size", "0.05"];
    // build model.glb works with defaults; its camera is the file's.
    illumnet(&[&["build", "-q", glb, "-o", &path("g.inet")][..], &quality[..]].concat());
    let out = illumnet(&["inspect", &path("g.inet"), "--json"]);
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["surfaces"].as_array().unwrap().len(), 8, "{json}");
    // --camera-from takes a glTF file's camera: the same image as the archive's own.
    illumnet(&["render", "-q", &path("g.inet"), "--size", "48x48", "-o", &path("a.png"), "--exr", &path("a.exr")]);
    let args = ["render", "-q", &path("g.inet"), "--size", "48x48", "-o", &path("b.png"), "--exr", &path("b.exr")];
    illumnet(&[&args[..], &["--camera-from", glb]].concat());
    assert!(read_exr(Path::new(&path("a.exr"))).unwrap() == read_exr(Path::new(&path("b.exr"))).unwrap());
    // What cannot be mapped is said on stderr, once, by name.
    let f = data.join("features.gltf");
    let out = illumnet(&[&["build", "-q", f.to_str().unwrap(), "-o", &path("f.inet")][..], &quality[..]].concat());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.matches("light `sun`: directional lights are not supported").count(), 1, "{err}");
    // glTF options on a TOML scene are refused.
    let toml = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell_box.toml");
    let (code, msg) = failing(&["build", toml.to_str().unwrap(), "-o", &path("t.inet"), "--fps", "15"]);
    assert_eq!(code, 3, "bad input: {msg}");
    assert!(msg.contains("glTF scenes"), "{msg}");
}

#[test]
fn a_lamp_facing_a_nearby_surface_is_warned_of() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    // A lamp hung 1 cm below the ceiling of a closed box; facing up, its
    // light lands on the ceiling within two patch sizes.
    let scene = |corners: &str| {
        format!(
            "[camera]\nposition = [0.5, 0.5, -1.0]\nlook_at = [0.5, 0.5, 0.0]\nfov_y_deg = 40\nwidth = 16\nheight = 16\n\
             [[material]]\nname = 'w'\ntype = 'diffuse'\nreflectance = [0.8, 0.8, 0.8]\n\
             [[surface]]\nname = 'room'\nmaterial = 'w'\nbox = {{ min = [0, 0, 0], max = [1, 1, 1], inward = true }}\n\
             [[surface]]\nname = 'lamp'\nmaterial = 'w'\nemission = [10, 10, 10]\nquad = {corners}\n"
        )
    };
    let up = "[[0.4, 0.99, 0.4], [0.4, 0.99, 0.6], [0.6, 0.99, 0.6], [0.6, 0.99, 0.4]]";
    let down = "[[0.4, 0.99, 0.4], [0.6, 0.99, 0.4], [0.6, 0.99, 0.6], [0.4, 0.99, 0.6]]";
    for (corners, warned) in [(up, true), (down, false)] {
        std::fs::write(path("s.toml"), scene(corners)).unwrap();
        let out = illumnet(&["build", "-q", &path("s.toml"), "-o", &path("s.inet"), "--quality", "draft"]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.contains("emitter `lamp` sends") && err.contains("facing a nearby surface"), warned, "{err}");
    }
}

#[test]
fn json_commands_answer_failures_in_json() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    common::coarse_box_archive(Path::new(&path("a.inet")));
    let bytes = std::fs::read(path("a.inet")).unwrap();
    std::fs::write(path("cut.inet"), &bytes[..bytes.len() / 2]).unwrap();
    let run = |args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_illumnet")).args(args).output().unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
        let json: serde_json::Value = serde_json::from_str(&stdout)
            .unwrap_or_else(|e| panic!("{args:?}: stdout is not one JSON value ({e}): {stdout}"));
        (out.status.code().unwrap(), json)
    };
    for (args, code, kind) in [
        (vec!["inspect", &path("cut.inet"), "--json"], 4, "corrupt_archive"),
        (vec!["inspect", &path("none.inet"), "--json"], 5, "io"),
        (vec!["inspect", &path("a.inet"), "--json", "--surface", "nope"], 3, "bad_input"),
        (vec!["verify", &path("none.inet"), "--json"], 5, "io"),
    ] {
        let (got, json) = run(&args);
        assert_eq!(got, code, "{args:?}: {json}");
        assert_eq!(json["error"]["exit_code"], code, "{args:?}: {json}");
        assert_eq!(json["error"]["kind"], kind, "{args:?}: {json}");
        assert!(!json["error"]["message"].as_str().unwrap().is_empty());
    }
    // verify's findings are its answer: one object, no error object after it.
    let (code, json) = run(&["verify", &path("cut.inet"), "--json"]);
    assert_eq!(code, 4);
    assert_eq!(json["sound"], false, "{json}");
}
