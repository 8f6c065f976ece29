//! Mesh detail applied per image sample (format §5.15): base-colour
//! texels multiply what a surface reflects, around the mean albedo the
//! I-net used; shading normals turn the direct light a sample receives.
//! Each is checked against the same archive without the detail.

mod common;

use glam::{Vec2, Vec3};
use illumnet::distribute::{self, DistributeOptions};
use illumnet::progress::NoProgress;
use illumnet::render::{self, DirectLight, Image, PinholeCamera, RenderOptions, Renderer};
use illumnet::scene::texture::{Shading, TextureImage, Wrap};
use illumnet::scene::{BuildHints, Scene};

/// A 2 m grey floor (ρ 0.5, corners counter-clockwise from (−1, −1) seen
/// from above) under a small lamp 3 m up, seen from straight above.
const SCENE: &str = r#"
[camera]
position = [0, 2.5, 0]
look_at = [0, 0, 0]
up = [0, 0, 1]
fov_y_deg = 40
width = 48
height = 48

[[material]]
name = "grey"
type = "diffuse"
reflectance = [0.5, 0.5, 0.5]

[[material]]
name = "black"
type = "diffuse"
reflectance = [0, 0, 0]

[[surface]]
name = "floor"
material = "grey"
quad = [[-1, 0, -1], [-1, 0, 1], [1, 0, 1], [1, 0, -1]]

[[surface]]
name = "lamp"
material = "black"
emission = [50, 50, 50]
quad = [[-0.1, 3, -0.1], [0.1, 3, -0.1], [0.1, 3, 0.1], [-0.1, 3, 0.1]]
"#;

/// The scene's total and direct images.
fn render(scene: &Scene) -> (Image, Image) {
    let hints =
        BuildHints { frequency: Some(8), patch_size: Some(0.25), ray_spacing: Some(0.05), ..Default::default() };
    let a = common::build_archive(scene, hints);
    let v = a.view();
    let sol =
        distribute::distribute(&v, &DistributeOptions { tolerance: 1e-6, ..Default::default() }, &NoProgress).unwrap();
    let light = DirectLight::new(&v, &sol, render::direct::DEFAULT_LIGHT_SAMPLES);
    Renderer::new(&v, RenderOptions::default()).frame_direct(0, &render::indirect_frame_radiance(&v, 0, &sol), &light)
}

/// The floor's point under each pixel's centre, row by row.
fn floor_points(scene: &Scene) -> Vec<Vec3> {
    let a = common::build_archive(scene, BuildHints { frequency: Some(2), ..Default::default() });
    let cam = PinholeCamera::from_record(a.view().camera);
    let (w, h) = (cam.width, cam.height);
    (0..w * h)
        .map(|i| {
            let (o, d) = cam.ray((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
            o + d * (-o.y / d.y)
        })
        .collect()
}

#[test]
fn texels_multiply_the_light_around_the_mean_albedo() {
    texels_multiply(false);
    // Nearest-texel filtering: pure texels right up to the middle.
    texels_multiply(true);
}

fn texels_multiply(nearest: bool) {
    let flat = common::scene(SCENE);
    // Two texels along the floor's first edge (−1, −1) → (−1, 1): sRGB 255
    // (linear 1) and 128 (linear 0.2158), clamped at the edges, so the
    // floor is pure first texel for u < 1/4 and pure second for u > 3/4
    // (bilinear between the texel centres). The tint is one over the mean.
    let mut textured = flat.clone();
    let (bright, dark) = (1.0f32, 0.215_861_6);
    let mean = (bright + dark) / 2.0;
    textured.textures.push(TextureImage {
        width: 2,
        height: 1,
        wrap: [Wrap::Clamp, Wrap::Clamp],
        nearest,
        srgb: vec![255, 255, 255, 128, 128, 128],
    });
    let floor = &mut textured.surfaces[0];
    floor.shading = vec![Shading {
        // Corner k of the quad at texture coordinate: u along the first edge.
        uv: [Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(1.0, 1.0), Vec2::new(0.0, 1.0)],
        texture: 0,
        tint: [1.0 / mean; 3],
        ..Shading::FLAT
    }];
    let (a, _) = render(&flat);
    let (b, _) = render(&textured);
    // The first edge runs along +z: u = (z + 1)/2.
    let (mut low, mut high, mut checked) = (0.0f64, 0.0f64, 0);
    let points = floor_points(&flat);
    for y in 0..a.height {
        for x in 0..a.width {
            let p = points[(y * a.width + x) as usize];
            if p.x.abs() > 0.9 || p.z.abs() > 0.95 {
                continue;
            }
            let u = (p.z + 1.0) / 2.0;
            let edge = if nearest { 0.45 } else { 0.2 };
            let want = if u < edge {
                bright / mean
            } else if u > 1.0 - edge {
                dark / mean
            } else {
                continue;
            };
            let ratio = b.at(x, y)[1] as f64 / a.at(x, y)[1] as f64;
            let err = (ratio / want as f64 - 1.0).abs();
            if u < 0.5 {
                low = low.max(err)
            } else {
                high = high.max(err)
            }
            checked += 1;
        }
    }
    eprintln!(
        "texture (nearest {nearest}): {checked} pixels, worst ratio error {:.3}% (bright) {:.3}% (dark)",
        low * 100.0,
        high * 100.0
    );
    assert!(checked > if nearest { 600 } else { 200 }, "only {checked} pixels checked");
    assert!(low < 0.005 && high < 0.005, "ratios off by {low} and {high}");
}

#[test]
fn shading_normals_turn_the_direct_light() {
    let flat = common::scene(SCENE);
    // Every corner's normal tilted 30° about the floor's first edge (z):
    // straight under the lamp the direct light falls by cos 30°.
    let mut tilted = flat.clone();
    let tilt = 30f32.to_radians();
    let world = Vec3::new(tilt.sin(), tilt.cos(), 0.0);
    let floor = &mut tilted.surfaces[0];
    let prim = floor.primitives[0];
    floor.shading = vec![Shading { normal: Shading::to_local(&prim, [world; 4]), ..Shading::FLAT }];
    let (_, a) = render(&flat);
    let (_, b) = render(&tilted);
    let mut worst = 0.0f64;
    let mut checked = 0;
    let points = floor_points(&flat);
    for y in 0..a.height {
        for x in 0..a.width {
            let p = points[(y * a.width + x) as usize];
            if p.x.abs() > 0.1 || p.z.abs() > 0.1 {
                continue;
            }
            // Exact for a point lamp straight above; the lamp and the
            // pixel are small against its 3 m height.
            let to_lamp = (Vec3::new(0.0, 3.0, 0.0) - p).normalize();
            let want = (world.dot(to_lamp) / to_lamp.y) as f64;
            let ratio = b.at(x, y)[1] as f64 / a.at(x, y)[1] as f64;
            worst = worst.max((ratio / want - 1.0).abs());
            checked += 1;
        }
    }
    eprintln!("shading normal: {checked} pixels, worst ratio error {:.3}%", worst * 100.0);
    assert!(checked > 4, "only {checked} pixels checked");
    assert!(worst < 0.01, "direct light off by {worst} of cos-weighted");
}

#[test]
fn an_archive_without_detail_renders_as_before() {
    // Normals equal to the face normal and no texture: the same pixels.
    let flat = common::scene(SCENE);
    let mut same = flat.clone();
    let floor = &mut same.surfaces[0];
    let prim = floor.primitives[0];
    floor.shading = vec![Shading { normal: Shading::to_local(&prim, [prim.normal(); 4]), ..Shading::FLAT }];
    let (a, _) = render(&flat);
    let (b, _) = render(&same);
    let worst = a
        .pixels
        .iter()
        .zip(&b.pixels)
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c] - q[c]).abs() / p[c].max(1e-3)))
        .fold(0.0f32, f32::max);
    assert!(worst < 1e-5, "face normals given as vertex normals change pixels by {worst}");
}

#[test]
fn a_gltf_drum_with_vertex_normals_shades_smoothly_across_its_facets() {
    // tests/data/gltf/smooth.glb (tools/make_gltf.py): six flat facets
    // over 120° of a 1 m drum, each vertex's NORMAL pointing radially.
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf/smooth.glb");
    let smooth = Scene::from_file(&path).unwrap();
    let drum = smooth.surfaces.iter().find(|s| s.name == "drum").unwrap();
    assert_eq!((drum.primitives.len(), drum.shading.len()), (6, 6));
    for (p, sh) in drum.primitives.iter().zip(&drum.shading) {
        let [x, y, z] = p.own_frame();
        for k in 0..4 {
            let n = sh.normal[k];
            let world = x * n.x + y * n.y + z * n.z;
            let radial = Vec3::new(p.p[k].x, 0.0, p.p[k].z).normalize();
            assert!((world - radial).length() < 1e-5, "corner {k}: {world} vs radial {radial}");
        }
    }
    // The same drum without its normals: flat facets.
    let mut flat = smooth.clone();
    flat.surfaces.iter_mut().for_each(|s| s.shading.clear());
    let hints = BuildHints { frequency: Some(8), ..Default::default() };
    let jumps = |scene: &Scene| -> (f32, f32) {
        let a = common::build_archive(scene, hints);
        let v = a.view();
        let sol = distribute::distribute(&v, &DistributeOptions::default(), &NoProgress).unwrap();
        let light = DirectLight::new(&v, &sol, render::direct::DEFAULT_LIGHT_SAMPLES);
        let (_, d) = Renderer::new(&v, RenderOptions::default()).frame_direct(
            0,
            &render::indirect_frame_radiance(&v, 0, &sol),
            &light,
        );
        // Along the middle row, over the drum: the largest step between
        // neighbouring pixels, and the row's largest radiance.
        let y = d.height / 2;
        let row: Vec<f32> = (0..d.width).map(|x| d.at(x, y)[1]).collect();
        let inside: Vec<f32> = row.iter().copied().filter(|&l| l > 0.0).collect();
        let step = inside.windows(2).skip(2).take(inside.len().saturating_sub(5)).map(|w| (w[1] - w[0]).abs());
        (step.fold(0.0f32, f32::max), inside.iter().copied().fold(0.0f32, f32::max))
    };
    let (flat_step, flat_peak) = jumps(&flat);
    let (smooth_step, smooth_peak) = jumps(&smooth);
    eprintln!(
        "drum: largest step between neighbouring pixels {:.2}% of the peak flat, {:.2}% smooth",
        100.0 * flat_step / flat_peak,
        100.0 * smooth_step / smooth_peak
    );
    assert!(flat_step > 0.05 * flat_peak, "the flat facets should show: {flat_step} of {flat_peak}");
    assert!(smooth_step < 0.25 * flat_step, "steps {smooth_step} with normals vs {flat_step} without");
}
