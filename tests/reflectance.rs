//! General reflectance (issue #4): the glossy Cornell box against a
//! path-traced reference, the brushed plate's highlight turning with the
//! grain, energy bookkeeping with glossy surfaces, the archive's reflectance
//! sections (validation, determinism) and the prototype library.

mod common;

use std::path::Path;

use illumnet::archive::{self, Archive, ArchiveContents};
use illumnet::bake::{self, BuildSettings};
use illumnet::distribute::{self, DistributeOptions};
use illumnet::progress::NoProgress;
use illumnet::render::{self, Image, RenderOptions, image_io};
use illumnet::scene::{BuildHints, Scene};

fn scene_file(name: &str) -> Scene {
    Scene::from_file(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes").join(name)).unwrap()
}

fn contents(scene: &Scene, hints: BuildHints) -> ArchiveContents {
    let mut settings = BuildSettings::resolve(scene, hints);
    settings.prototype_library = None;
    bake::build(scene, &settings, &NoProgress).unwrap().0
}

fn render_still(bytes: &[u8], samples: u32) -> Image {
    let archive = Archive::from_bytes(bytes).unwrap();
    let v = archive.view();
    let sol = distribute::distribute(&v, &DistributeOptions::default(), &NoProgress).unwrap();
    assert!(sol.balance.converged && sol.balance.imbalance().abs() < 1e-5, "{:?}", sol.balance);
    render::render(
        &v,
        &render::frame_radiance(&v, 0, &sol),
        &RenderOptions { samples_per_axis: samples, ..Default::default() },
    )
}

/// [`render_still`] with the default shading: direct light and glossy
/// highlights per image sample, the I-net's indirect light.
fn render_direct(bytes: &[u8], samples: u32) -> Image {
    let archive = Archive::from_bytes(bytes).unwrap();
    let v = archive.view();
    let sol = distribute::distribute(&v, &DistributeOptions::default(), &NoProgress).unwrap();
    assert!(sol.balance.converged && sol.balance.imbalance().abs() < 1e-5, "{:?}", sol.balance);
    let light = render::DirectLight::new(&v, &sol, render::direct::DEFAULT_LIGHT_SAMPLES);
    let mut renderer = render::Renderer::new(&v, RenderOptions { samples_per_axis: samples, ..Default::default() });
    renderer.frame_direct(0, &render::indirect_frame_radiance(&v, 0, &sol), &light).0
}

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(name)
}

#[test]
fn glossy_floor_is_within_ten_percent_of_the_path_traced_reference() {
    let reference =
        image_io::read_exr(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/glossy_floor_ref.exr")).unwrap();
    let bytes = archive::write_to_vec(&contents(&scene_file("glossy_floor.toml"), BuildHints::default())).unwrap();
    let image = render_still(&bytes, 4);
    let err = image_io::relative_l2(&image, &reference).unwrap();
    // Measured 0.031 at default settings (docs/ACCURACY.md); the bar is 10%,
    // the diffuse Cornell box's is 0.032.
    eprintln!("glossy floor relative L2 error against the reference: {err:.4}");
    assert!(err < 0.05, "relative L2 error {err:.4} ≥ 0.05");
    // With the highlights per image sample (the default shading): measured
    // 0.0186 (issue 12's bar is 2%).
    let image = render_direct(&bytes, 4);
    let err = image_io::relative_l2(&image, &reference).unwrap();
    eprintln!("glossy floor, direct shading: relative L2 error {err:.4}");
    assert!(err < 0.021, "direct shading: relative L2 error {err:.4} ≥ 0.021");
}

/// The brushed plate of issue 12 (`tests/data/brushed_metal.toml`: an
/// anisotropic plate, α 0.05 along the grain and 0.3 across, over a grey
/// ground, a small bright light in the camera's mirror direction), turned
/// 0° and 90° about its normal, against Mitsuba references (32 768 spp,
/// `tools/brushed_study.py`) over the pixels below 20 (the highlight
/// counts, the light does not). Measured with the paper's per-patch
/// shading: 46% and 22%; the bar is issue 12's 5%.
#[test]
fn brushed_plate_is_within_five_percent_of_the_path_traced_reference() {
    for degrees in [0u32, 90] {
        let mut scene = Scene::from_file(&data("brushed_metal.toml")).unwrap();
        scene.turn_surface("plate", degrees as f32).unwrap();
        let bytes = archive::write_to_vec(&contents(&scene, BuildHints::default())).unwrap();
        let reference = image_io::read_exr(&data(&format!("brushed_metal_{degrees}_ref.exr"))).unwrap();
        let image = render_direct(&bytes, 4);
        let err = image_io::relative_l2_below(&image, &reference, 20.0).unwrap();
        eprintln!("brushed plate turned {degrees}°: relative L2 error {err:.4}");
        assert!(err < 0.05, "plate turned {degrees}°: relative L2 error {err:.4} ≥ 0.05");
    }
}

/// A mirror-like rough conductor (α = 0.02) reflecting a small emitter
/// puts the highlight where geometry says: the camera ray to the mirror
/// image of the emitter's centre meets the plate within a pixel of the
/// highlight's centroid.
#[test]
fn a_mirror_like_highlight_is_where_geometry_puts_it() {
    let scene = common::scene(
        "[camera]
position = [0.1, 0.6, -1.2]
look_at = [0.0, 0.0, 0.0]
fov_y_deg = 40
width = 128
height = 128
[[material]]
name = 'mirror'
type = 'rough_conductor'
specular = [0.95, 0.95, 0.95]
alpha = 0.02
[[material]]
name = 'black'
type = 'diffuse'
reflectance = [0, 0, 0]
[[surface]]
name = 'plate'
material = 'mirror'
quad = [[-0.6, 0, 0.6], [0.6, 0, 0.6], [0.6, 0, -0.6], [-0.6, 0, -0.6]]
[[surface]]
name = 'lamp'
material = 'black'
emission = [40, 40, 40]
quad = [[-0.03, 0, -0.03], [0.03, 0, -0.03], [0.03, 0, 0.03], [-0.03, 0, 0.03]]
transform = { rotate_deg = [60, 0, 0], translate = [-0.15, 0.7, 1.0] }
",
    );
    let bytes = archive::write_to_vec(&contents(&scene, BuildHints::default())).unwrap();
    let image = render_direct(&bytes, 4);
    // The lamp's centre, mirrored in the plate (y = 0).
    let lamp = &scene.surfaces[1].primitives[0];
    let centre = lamp.p.iter().copied().sum::<glam::Vec3>() / 4.0;
    let eye = glam::Vec3::new(0.1, 0.6, -1.2);
    let mirrored = glam::Vec3::new(centre.x, -centre.y, centre.z);
    let t = eye.y / (eye.y - mirrored.y);
    let on_plate = eye + (mirrored - eye) * t;
    let camera = render::PinholeCamera::from_record(Archive::from_bytes(&bytes).unwrap().view().camera);
    let (px, py) = camera.project(on_plate).expect("in front of the camera");
    // The highlight: pixels above a tenth of the brightest (the lamp itself
    // is out of view).
    let lum = |p: [f32; 3]| (p[0] + p[1] + p[2]) as f64 / 3.0;
    let peak = image.pixels.iter().map(|&p| lum(p)).fold(0.0, f64::max);
    let (mut m, mut mx, mut my) = (0.0, 0.0, 0.0);
    for y in 0..image.height {
        for x in 0..image.width {
            let l = lum(image.at(x, y));
            if l > 0.1 * peak {
                m += l;
                mx += l * (x as f64 + 0.5);
                my += l * (y as f64 + 0.5);
            }
        }
    }
    let (cx, cy) = (mx / m, my / m);
    let off = ((cx - px as f64).powi(2) + (cy - py as f64).powi(2)).sqrt();
    eprintln!("highlight centroid ({cx:.2}, {cy:.2}), geometry ({px:.2}, {py:.2}): {off:.2} px apart, peak {peak:.1}");
    assert!(peak > 1.0, "no highlight (peak {peak})");
    assert!(off <= 1.0, "highlight {off:.2} px from where geometry puts it");
}

/// The distribution's split of the glossy patches' directional radiance:
/// with nothing but the emitter to light the plate (a black wall beside
/// it; the ground is below its plane), the directional radiance is all
/// direct, exactly; with a grey wall part of it is indirect, and the
/// direct part is the same.
#[test]
fn directional_radiance_splits_into_direct_and_indirect() {
    let mut direct_parts = Vec::new();
    for (grey, want_indirect) in [("0.0", false), ("0.5", true)] {
        let mut text = std::fs::read_to_string(data("brushed_metal.toml")).unwrap();
        text.push_str(&format!(
            "[[material]]\nname = 'wall'\ntype = 'diffuse'\nreflectance = [{grey}, {grey}, {grey}]\n\
             [[surface]]\nname = 'wall'\nmaterial = 'wall'\n\
             quad = [[-1, 0, -1.5], [-1, 1.5, -1.5], [-1, 1.5, 1.5], [-1, 0, 1.5]]\n"
        ));
        let scene = common::scene(&text);
        let archive = common::build_archive(&scene, BuildHints::default());
        let sol = common::solve(&archive);
        let d = sol.directional.as_ref().expect("a glossy plate");
        assert_eq!(d.direct.len(), d.radiance.len());
        let total: f64 = d.radiance.iter().map(|r| r[0] as f64).sum();
        let direct: f64 = d.direct.iter().map(|r| r[0] as f64).sum();
        let worst = d.radiance.iter().zip(&d.direct).map(|(r, x)| (r[0] - x[0]) as f64).fold(f64::MIN, f64::max);
        eprintln!("wall {grey}: directional total {total:.4e}, direct {direct:.4e}, largest indirect {worst:.3e}");
        assert!(direct > 0.0 && d.direct.iter().zip(&d.radiance).all(|(x, r)| x[0] <= r[0] * (1.0 + 1e-5) + 1e-9));
        if want_indirect {
            assert!(total - direct > 1e-3 * total, "a grey wall lights the plate: {total} vs {direct}");
        } else {
            assert!(worst <= 1e-6 * total / d.radiance.len() as f64, "a black wall: indirect {worst}");
        }
        direct_parts.push(direct);
    }
    assert!((direct_parts[0] - direct_parts[1]).abs() < 1e-4 * direct_parts[0], "{direct_parts:?}");
}

/// Angle (degrees, in [0, 180)) of the principal axis of the bright part of
/// `img`: pixels above `frac` of the brightest, weighted by brightness,
/// ignoring anything brighter than `cap` (the lamp seen directly).
fn highlight_axis(img: &Image, frac: f32, cap: f32) -> f64 {
    let lum = |p: [f32; 3]| (p[0] + p[1] + p[2]) / 3.0;
    let peak = img.pixels.iter().map(|&p| lum(p)).filter(|&l| l < cap).fold(0.0f32, f32::max);
    let (mut m, mut mx, mut my) = (0.0f64, 0.0f64, 0.0f64);
    let mut pts = Vec::new();
    for y in 0..img.height {
        for x in 0..img.width {
            let l = lum(img.at(x, y));
            if l >= frac * peak && l < cap {
                let w = l as f64;
                pts.push((x as f64, y as f64, w));
                m += w;
                mx += w * x as f64;
                my += w * y as f64;
            }
        }
    }
    let (cx, cy) = (mx / m, my / m);
    let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
    for (x, y, w) in pts {
        sxx += w * (x - cx) * (x - cx);
        syy += w * (y - cy) * (y - cy);
        sxy += w * (x - cx) * (y - cy);
    }
    (0.5 * (2.0 * sxy).atan2(sxx - syy)).to_degrees().rem_euclid(180.0)
}

#[test]
fn brushed_plate_highlight_turns_with_the_grain() {
    for shading in ["inet", "direct"] {
        let mut axes = Vec::new();
        for degrees in [0.0f32, 90.0] {
            let mut scene = scene_file("brushed_plate.toml");
            scene.turn_surface("plate", degrees).unwrap();
            let bytes = archive::write_to_vec(&contents(&scene, BuildHints::default())).unwrap();
            let img = if shading == "inet" { render_still(&bytes, 2) } else { render_direct(&bytes, 2) };
            // The lamp (radiance 20, 10 on its edge pixels) is seen directly: left out.
            let axis = highlight_axis(&img, 0.3, 5.0);
            eprintln!("{shading} shading, plate turned {degrees}°: highlight axis {axis:.1}° from the image's x axis");
            axes.push(axis);
        }
        // Rougher across the grain: at 0° (grain along x) the highlight runs
        // along z, towards the eye (vertical in the image); at 90°, across.
        let diff = (axes[0] - axes[1]).rem_euclid(180.0);
        let diff = diff.min(180.0 - diff);
        assert!((diff - 90.0).abs() <= 15.0, "{shading}: highlight axes {axes:?} differ by {diff:.1}°, want 90 ± 15");
    }
}

#[test]
fn energy_is_conserved_in_a_closed_glossy_room() {
    // A closed box of broad-specular and rough-conductor walls around a lamp:
    // nothing escapes and emitted = absorbed + residual.
    let archive = common::build_archive(&closed_glossy_room(), BuildHints::default());
    let v = archive.view();
    let r = v.reflectance.expect("glossy scenes have reflectance sections");
    assert_eq!(r.prototypes.len(), 2);
    assert_eq!(r.prototypes[1].bands, 3, "per-band ior makes a three-band table");
    let sol = common::solve(&archive);
    let b = sol.balance;
    let sum = |a: &[f64; 3]| a.iter().sum::<f64>();
    eprintln!("{b:?}");
    assert!(b.converged);
    assert!(b.imbalance().abs() < 1e-6, "imbalance {}", b.imbalance());
    // Only rays that meet the lamp's back or graze an edge escape.
    assert!(sum(&b.escaped) < 0.01 * sum(&b.emitted), "escaped {:?} of {:?}", b.escaped, b.emitted);
    assert!(sol.directional.as_ref().unwrap().radiance.iter().flatten().all(|x| x.is_finite() && *x >= 0.0));
}

/// Deferred glossy reflection (tables read only when what waits outweighs
/// the diffuse residual, Anderson between) reaches the balance that
/// reflecting every step reaches, in fewer table steps: in the glossy
/// Cornell box (one glossy floor among diffuse walls) and in a closed
/// room where every patch is glossy.
#[test]
fn deferred_glossy_reflection_reaches_the_same_balance_in_fewer_table_steps() {
    let cornell = scene_file("glossy_floor.toml");
    for (name, scene) in [("glossy Cornell box", cornell), ("closed glossy room", closed_glossy_room())] {
        let archive = common::build_archive(&scene, BuildHints::default());
        let v = archive.view();
        let solve = |defer_glossy: bool, tolerance: f64| {
            let opts = DistributeOptions { tolerance, defer_glossy, ..Default::default() };
            distribute::distribute(&v, &opts, &NoProgress).unwrap()
        };
        let (every, deferred) = (solve(false, 1e-7), solve(true, 1e-7));
        for s in [&every, &deferred] {
            assert!(s.balance.converged && s.balance.imbalance().abs() < 1e-6, "{name}: {:?}", s.balance);
        }
        // Same light: patch radiance and directional radiance, relative to
        // the largest value of each.
        let worst = |a: &[[f32; 3]], b: &[[f32; 3]]| {
            let top = a.iter().flatten().fold(0.0f32, |m, x| m.max(x.abs()));
            a.iter().flatten().zip(b.iter().flatten()).map(|(x, y)| (x - y).abs() / top).fold(0.0f32, f32::max)
        };
        let diffuse = worst(&every.radiance, &deferred.radiance);
        let (de, dd) = (every.directional.as_ref().unwrap(), deferred.directional.as_ref().unwrap());
        let directional = worst(&de.radiance, &dd.radiance);
        let direct = worst(&de.direct, &dd.direct);
        eprintln!(
            "{name}: largest difference {diffuse:.2e} (patches), {directional:.2e} (directions), {direct:.2e} (direct)"
        );
        assert!(diffuse < 1e-5 && directional < 1e-5, "{name}: {diffuse} {directional}");
        assert_eq!(direct, 0.0, "{name}: the direct highlights do not depend on the schedule");
        // At the default tolerance: where most light is diffuse, a table
        // step for several diffuse ones; where all of it is glossy there
        // is nothing to defer to, and no more table steps.
        let (every, deferred) = (solve(false, 1e-4).balance, solve(true, 1e-4).balance);
        eprintln!(
            "{name}: every step {} iterations; deferred {} iterations, {} reading tables",
            every.iterations, deferred.iterations, deferred.table_steps
        );
        assert_eq!(every.table_steps, every.iterations);
        let fewer = if name == "glossy Cornell box" { 3 } else { 1 };
        assert!(deferred.table_steps * fewer <= every.table_steps, "{name}: {deferred:?} vs {every:?}");
    }
}

fn closed_glossy_room() -> Scene {
    common::scene(&format!(
        "{}
[[material]]
name = 'gloss'
type = 'broad_specular'
reflectance = [0.3, 0.4, 0.5]
specular = [0.5, 0.4, 0.3]
alpha = 0.3
[[material]]
name = 'metal'
type = 'rough_conductor'
specular = [0.9, 0.8, 0.7]
alpha_u = 0.2
alpha_v = 0.5
ior = [1.5, 2.0, 2.5]
[[surface]]
name = 'room'
material = 'gloss'
box = {{ min = [0, 0, 0], max = [1, 1, 1], inward = true, omit = ['-y'] }}
[[surface]]
name = 'floor'
material = 'metal'
quad = [[0, 0, 0], [0, 0, 1], [1, 0, 1], [1, 0, 0]]
[[surface]]
name = 'lamp'
material = 'gloss'
emission = [5, 5, 5]
quad = [[0.4, 0.999, 0.4], [0.6, 0.999, 0.4], [0.6, 0.999, 0.6], [0.4, 0.999, 0.6]]
[build]
frequency = 6
patch_size = 0.1
ray_spacing = 0.02
",
        common::CAMERA
    ))
}

fn glossy_square() -> Scene {
    common::scene(&format!(
        "{}
[[material]]
name = 'gloss'
type = 'broad_specular'
reflectance = [0.3, 0.3, 0.3]
specular = [0.5, 0.5, 0.5]
alpha_u = 0.2
alpha_v = 0.4
[[material]]
name = 'white'
type = 'diffuse'
reflectance = [0.8, 0.8, 0.8]
[[surface]]
name = 'plate'
material = 'gloss'
quad = [[0, 0, 0], [0, 0, 1], [1, 0, 1], [1, 0, 0]]
[[surface]]
name = 'wall'
material = 'white'
emission = [1, 1, 1]
quad = [[0, 0, 1], [0, 1, 1], [1, 1, 1], [1, 0, 1]]
[build]
frequency = 5
patch_size = 0.25
ray_spacing = 0.05
",
        common::CAMERA
    ))
}

#[test]
fn reflectance_sections_are_validated() {
    let good = contents(&glossy_square(), BuildHints::default());
    assert_eq!(Archive::from_bytes(&archive::write_to_vec(&good).unwrap()).unwrap().header().version_read, 10);
    let expect = |c: &ArchiveContents, what: &str| {
        let err = Archive::from_bytes(&archive::write_to_vec(c).unwrap()).err().expect("must be rejected");
        assert!(err.to_string().contains(what), "{err} (expected {what})");
    };
    // A map that is not a bijection.
    let mut c = good.clone();
    let r = c.reflectance.as_mut().unwrap();
    r.maps[1] = r.maps[0];
    expect(&c, "OMAP");
    // A table row that reflects more than it receives.
    let mut c = good.clone();
    let r = c.reflectance.as_mut().unwrap();
    r.factors.iter_mut().for_each(|f| *f *= 10.0);
    expect(&c, "more than it receives");
    // A non-diffuse patch left out.
    let mut c = good.clone();
    let r = c.reflectance.as_mut().unwrap();
    r.patches.pop();
    r.hits.truncate(r.patches.len() * c.directions.len() / 2);
    expect(&c, "NDPA");
    // A glossy material without the sections.
    let mut c = good.clone();
    c.reflectance = None;
    expect(&c, "non-diffuse material needs the reflectance sections");
}

#[test]
fn glossy_builds_are_deterministic_and_reuse_the_prototype_library() {
    let scene = glossy_square();
    let dir = tempfile::tempdir().unwrap();
    let mut settings = BuildSettings::resolve(&scene, BuildHints::default());
    settings.prototype_library = Some(dir.path().to_path_buf());
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let seq = bake::build_sequence(&scene, &settings, &NoProgress).unwrap();
            (archive::write_to_vec(&seq.contents).unwrap(), seq.stats)
        })
    };
    let (first, s1) = run(1);
    let (second, s2) = run(2);
    assert_eq!((s1.tables, s1.tables_cached), (1, 0), "the first build makes the table");
    assert_eq!((s2.tables, s2.tables_cached), (1, 1), "the second reads it from the library");
    assert!(first == second, "archives differ between a fresh table, a cached one and thread counts");
    // Without the library, the same bytes again.
    let no_lib = archive::write_to_vec(&contents(&scene, BuildHints::default())).unwrap();
    assert!(no_lib == first);
}

#[test]
fn specular_colour_relights_without_rebuild() {
    let bytes = archive::write_to_vec(&contents(&glossy_square(), BuildHints::default())).unwrap();
    let archive = Archive::from_bytes(&bytes).unwrap();
    let v = archive.view();
    let opts = DistributeOptions::default();
    let base = distribute::Lighting::from_view(&v);
    let mut off = base.clone();
    off.specular[0] = [0.0; 3];
    let glossy = distribute::distribute_lit(&v, 0, &opts, &base, None, &NoProgress).unwrap();
    let matte = distribute::distribute_lit(&v, 0, &opts, &off, None, &NoProgress).unwrap();
    let total = |s: &distribute::Solution| s.directional.as_ref().unwrap().radiance.iter().flatten().sum::<f32>();
    assert!(total(&glossy) > 0.0);
    assert_eq!(total(&matte), 0.0, "k_s = 0 leaves no directional radiance");
    // The plate reflects less in all, so the lit wall receives less back.
    let wall: f32 = (0..v.patch_count()).filter(|&p| v.patch_centre[p][2] > 0.99).map(|p| matte.received[p][0]).sum();
    let wall_glossy: f32 =
        (0..v.patch_count()).filter(|&p| v.patch_centre[p][2] > 0.99).map(|p| glossy.received[p][0]).sum();
    assert!(wall_glossy > wall, "{wall_glossy} ≤ {wall}");
}
