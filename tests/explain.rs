//! Pictures that explain an archive (`render --false-color`): the patch each
//! image sample sees, per-patch quantities, and the command line.

mod common;

use std::path::Path;
use std::process::Command;

use illumnet::render::false_colour::{self, Quantity};
use illumnet::render::{RenderOptions, Renderer};
use illumnet::scene::BuildHints;

/// The patch ids the renderer reports are where the camera looks: a wall
/// of 12 × 12 patches (numbered in 8 × 8 tiles) seen head on, each pixel's
/// patch centre within half a patch diagonal of the point its ray meets.
#[test]
fn samples_see_the_patch_under_them() {
    let scene = common::scene(
        "[camera]\nposition = [0.5, 0.5, -2]\nlook_at = [0.5, 0.5, 0]\nfov_y_deg = 40\nwidth = 40\nheight = 30\n\
         [[material]]\nname = 'grey'\ntype = 'diffuse'\nreflectance = [0.5, 0.5, 0.5]\n\
         [[surface]]\nname = 'wall'\nmaterial = 'grey'\nquad = [[0, 0, 0], [0, 1.2, 0], [1.2, 1.2, 0], [1.2, 0, 0]]\n\
         [[surface]]\nname = 'lamp'\nmaterial = 'grey'\nemission = [1, 1, 1]\n\
         quad = [[0, 2, -1], [1, 2, -1], [1, 2, -0.2], [0, 2, -0.2]]\n\
         [build]\nfrequency = 4\npatch_size = 0.1\nray_spacing = 0.05\n",
    );
    let archive = common::build_archive(&scene, BuildHints::default());
    let v = archive.view();
    let samples = Renderer::new(&v, RenderOptions { samples_per_axis: 1, ..Default::default() }).sample_patches(0);
    let camera = illumnet::render::PinholeCamera::from_record(v.camera);
    let (mut checked, mut worst) = (0, 0.0f32);
    for y in 0..30 {
        for x in 0..40 {
            let p = samples.patches[(y * 40 + x) as usize];
            let (o, d) = camera.ray(x as f32 + 0.5, y as f32 + 0.5);
            let at = o + d * (-o.z / d.z);
            if p == u32::MAX || !(0.001..1.199).contains(&at.x) || !(0.001..1.199).contains(&at.y) {
                continue;
            }
            let centre = glam::Vec3::from(v.patch_centre[p as usize]);
            worst = worst.max(centre.distance(at));
            checked += 1;
        }
    }
    eprintln!("{checked} pixels on the wall, farthest patch centre {worst:.4} m");
    assert!(checked > 300, "{checked}");
    assert!(worst <= 0.5 * 0.1 * 2f32.sqrt() + 1e-4, "a pixel's patch centre is {worst} m from where it looks");
    // Link ends and bucket shares are per patch, finite, in range.
    let links = false_colour::patch_values(&v, Quantity::Links, None).unwrap();
    let total: f64 = links.iter().map(|&x| x as f64).sum();
    assert_eq!(total as usize, v.link_end_count());
    let buckets = false_colour::patch_values(&v, Quantity::Buckets, None).unwrap();
    assert!(buckets.iter().all(|b| (0.0..=1.0).contains(b)));
}

fn illumnet(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_illumnet")).args(args).output().unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn render_draws_false_colour_pictures_with_their_scale() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    common::coarse_box_archive(Path::new(&path("a.inet")));
    let size = "--size";
    for (what, bar) in [("links", true), ("hits", true), ("buckets", true), ("residual", true), ("patches", false)] {
        let png = path(&format!("{what}.png"));
        let (code, out, err) = illumnet(&[
            "render",
            "-q",
            &path("a.inet"),
            "-o",
            &png,
            "--false-color",
            what,
            size,
            "64x48",
            "--samples",
            "1",
        ]);
        assert_eq!(code, 0, "{what}: {err}");
        assert!(out.contains(&format!("false colour {what}")), "{what}: {out}");
        let (w, h) = image::image_dimensions(&png).unwrap();
        assert_eq!((w, h), (64, if bar { 48 + 30 } else { 48 }), "{what}");
    }
    // Error against a reference: the render's own EXR is a perfect reference.
    let (code, _, err) = illumnet(&["render", "-q", &path("a.inet"), "-o", &path("x.png"), "--exr", &path("x.exr")]);
    assert_eq!(code, 0, "{err}");
    let (code, out, err) = illumnet(&[
        "render",
        "-q",
        &path("a.inet"),
        "-o",
        &path("err.png"),
        "--false-color",
        "error",
        "--reference",
        &path("x.exr"),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("false colour error"), "{out}");
    let picture = image::open(path("err.png")).unwrap().to_rgb8();
    // No error anywhere: every pixel of the picture is the bar's darkest
    // colour or black (emitters).
    let dark = picture.get_pixel(10, 10).0;
    assert!(picture.rows().take(picture.height() as usize - 30).flatten().all(|p| p.0 == dark || p.0 == [0, 0, 0]));
    // Mistakes, refused before any work.
    for bad in [
        vec!["--false-color", "error"],
        vec!["--reference", "x.exr"],
        vec!["--false-color", "error", "--reference", "x.png"],
        vec!["--false-color", "colours"],
    ] {
        let a = path("a.inet");
        let mut args = vec!["render", a.as_str(), "-o", "never.png"];
        args.extend(bad.iter().copied());
        let (code, _, err) = illumnet(&args);
        assert!(code == 2 || code == 3, "{bad:?}: exit {code}: {err}");
    }
    assert!(!Path::new("never.png").exists());
    // A picture other than the error's does not gather for its shaded
    // image by default, unless that image is written too (--exr): then it
    // is the image a plain render writes.
    let (code, _, err) = illumnet(&[
        "render",
        "-q",
        &path("a.inet"),
        "-o",
        &path("fc.png"),
        "--false-color",
        "patches",
        "--exr",
        &path("fc.exr"),
    ]);
    assert_eq!(code, 0, "{err}");
    let (code, out, err) = illumnet(&["compare", &path("fc.exr"), &path("x.exr"), "--below", "1e9"]);
    assert!(code == 0 && out.contains("relative L2 0.0000,"), "{out}{err}");
    // A reference of another size: refused before the distribution runs.
    let (a, r) = (path("a.inet"), path("x.exr"));
    let (code, out, err) =
        illumnet(&["render", &a, "-o", "never.png", "--false-color", "error", "--reference", &r, "--size", "32x24"]);
    assert!(code == 3 && err.contains("256×256") && err.contains("32×24"), "exit {code}: {err}");
    assert!(!out.contains("distribution"), "{out}");
    assert!(!Path::new("never.png").exists());
}
