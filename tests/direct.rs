//! Direct light per pixel against closed forms: a square emitter over a
//! floor (the point-to-rectangle form factor), with and without a blocker,
//! and in a black room; the direct part of the solution; determinism.

mod common;

use glam::Vec3;
use illumnet::distribute::{self, DistributeOptions};
use illumnet::progress::NoProgress;
use illumnet::render::{self, DirectLight, PinholeCamera, RenderOptions, Renderer};
use illumnet::scene::BuildHints;

/// The grey (ρ 0.5) and black materials and the 4 m grey floor of both
/// scenes below.
const FLOOR: &str = r#"
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
quad = [[-2, 0, -2], [-2, 0, 2], [2, 0, 2], [2, 0, -2]]
"#;

/// A 1 m² emitter (radiance 10, facing down) 1 m over a 4 m grey floor
/// (ρ 0.5), open to the sky, and a black 0.2 m blocker at half height.
fn scene(blocker: bool) -> String {
    let mut s = format!(
        r#"
[camera]
position = [0, 0.6, -2.2]
look_at = [0.1, 0, 0.3]
fov_y_deg = 40
width = 64
height = 64
{FLOOR}
[[surface]]
name = "light"
material = "black"
emission = [10, 10, 10]
quad = [[-0.5, 1, -0.5], [0.5, 1, -0.5], [0.5, 1, 0.5], [-0.5, 1, 0.5]]
"#,
    );
    if blocker {
        s += "\n[[surface]]\nname = \"blocker\"\nmaterial = \"black\"\nquad = [[0.1, 0.5, 0.1], [0.1, 0.5, 0.3], [0.3, 0.5, 0.3], [0.3, 0.5, 0.1]]\n";
    }
    s
}

/// Irradiance at the origin (normal +y) of unit radiance from the
/// rectangle `[x0, x1] × [z0, z1]` at height `c` facing down: signed sums
/// of the corner form factor (Howell's catalogue, B-3), times π.
fn rectangle_irradiance(x0: f64, x1: f64, z0: f64, z1: f64, c: f64) -> f64 {
    let corner = |a: f64, b: f64| {
        let (x, y) = (a.abs() / c, b.abs() / c);
        let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
        let f = (x / sx * (y / sx).atan() + y / sy * (x / sy).atan()) / (2.0 * std::f64::consts::PI);
        a.signum() * b.signum() * f
    };
    std::f64::consts::PI * (corner(x1, z1) - corner(x0, z1) - corner(x1, z0) + corner(x0, z0))
}

/// Exact floor radiance at `p`: ρ/π · L · E, less the part of the light
/// the blocker hides (its shadow on the light's plane, seen from `p`).
fn exact_floor_radiance(p: Vec3, blocker: bool) -> f64 {
    let (px, pz) = (p.x as f64, p.z as f64);
    let mut e = rectangle_irradiance(-0.5 - px, 0.5 - px, -0.5 - pz, 0.5 - pz, 1.0);
    if blocker {
        // From p, the blocker at height 0.5 covers twice its extent at 1.
        let proj = |a: f64, q: f64| q + 2.0 * (a - q);
        let (x0, x1) = (proj(0.1, px).max(-0.5), proj(0.3, px).min(0.5));
        let (z0, z1) = (proj(0.1, pz).max(-0.5), proj(0.3, pz).min(0.5));
        if x0 < x1 && z0 < z1 {
            e -= rectangle_irradiance(x0 - px, x1 - px, z0 - pz, z1 - pz, 1.0);
        }
    }
    0.5 / std::f64::consts::PI * 10.0 * e
}

/// Rendered floor pixels (green), each with its image samples' floor
/// points (4 × 4, where the renderer puts them).
fn floor_pixels(blocker: bool, shading_direct: bool) -> Vec<(Vec<Vec3>, f64)> {
    let hints =
        BuildHints { frequency: Some(12), patch_size: Some(0.1), ray_spacing: Some(0.02), ..Default::default() };
    floor_pixels_of(&scene(blocker), hints, shading_direct, 1.8)
}

/// Rendered floor pixels of the scene `text` (its floor the plane y = 0),
/// those whose samples all fall within `extent` of the origin in x and z.
fn floor_pixels_of(text: &str, hints: BuildHints, shading_direct: bool, extent: f32) -> Vec<(Vec<Vec3>, f64)> {
    let s = common::scene(text);
    let a = common::build_archive(&s, hints);
    let v = a.view();
    let sol =
        distribute::distribute(&v, &DistributeOptions { tolerance: 1e-6, ..Default::default() }, &NoProgress).unwrap();
    let mut renderer = Renderer::new(&v, RenderOptions::default());
    let image = if shading_direct {
        let light = DirectLight::new(&v, &sol, render::direct::DEFAULT_LIGHT_SAMPLES);
        renderer.frame_direct(0, &render::indirect_frame_radiance(&v, 0, &sol), &light).0
    } else {
        renderer.frame(0, &render::frame_radiance(&v, 0, &sol))
    };
    let camera = PinholeCamera::from_record(v.camera);
    let n = RenderOptions::default().samples_per_axis;
    let mut out = Vec::new();
    for y in 0..image.height {
        for x in 0..image.width {
            let points: Vec<Vec3> = (0..n * n)
                .filter_map(|k| {
                    let (sx, sy) = ((k % n) as f32 + 0.5, (k / n) as f32 + 0.5);
                    let (o, d) = camera.ray(x as f32 + sx / n as f32, y as f32 + sy / n as f32);
                    (d.y < -1e-3).then(|| o + d * (-o.y / d.y))
                })
                .filter(|p| p.x.abs() < extent && p.z.abs() < extent)
                .collect();
            if points.len() == (n * n) as usize {
                out.push((points, image.at(x, y)[1] as f64));
            }
        }
    }
    out
}

/// The pixel mean of the exact floor radiance at its sample points.
fn exact_pixel(points: &[Vec3], blocker: bool) -> f64 {
    points.iter().map(|&p| exact_floor_radiance(p, blocker)).sum::<f64>() / points.len() as f64
}

#[test]
fn direct_light_from_a_square_emitter_matches_the_closed_form() {
    let pixels = floor_pixels(false, true);
    assert!(pixels.len() > 1000, "{} floor pixels", pixels.len());
    let worst = |pixels: &[(Vec<Vec3>, f64)]| {
        pixels
            .iter()
            .map(|(points, got)| (got - exact_pixel(points, false)).abs() / exact_pixel(points, false))
            .fold(0.0, f64::max)
    };
    // Unshadowed, the closed form is the answer.
    let direct = worst(&pixels);
    eprintln!("unshadowed: worst pixel {direct:.2e} off the closed form");
    // The renderer takes the closed form at the centre of a pixel's
    // samples for its mean over them (exact to second order in the
    // footprint): measured 3.2e-4 at the far, oblique end of the floor.
    assert!(direct < 1e-3, "worst floor pixel {:.3}% off the closed form", 100.0 * direct);
    // The paper's shading of the same archive is further off (measured 2.8%).
    let inet = worst(&floor_pixels(false, false));
    assert!(inet > 0.01, "inet {inet:.4} vs direct {direct:.4}");
}

/// The issue's analytic case (CIE 171 test 5.3 style): a 1 m² emitter of
/// radiance 10 flush in the ceiling of a 4 × 4 × 3 m room with black
/// walls and ceiling over a grey floor (ρ 0.5), seen from above. Nothing
/// but the floor reflects, so its radiance is ρ/π · L · π·F exactly.
#[test]
fn a_ceiling_light_in_a_black_room_gives_the_exact_floor_radiance() {
    let camera = r#"
[camera]
position = [0.3, 2.6, -1.2]
look_at = [0, 0, 0.3]
fov_y_deg = 70
width = 48
height = 48
"#;
    let room = r#"
[[surface]]
name = "room"
material = "black"
box = { min = [-2, 0, -2], max = [2, 3, 2], inward = true, omit = ["-y"] }

[[surface]]
name = "light"
material = "black"
emission = [10, 10, 10]
quad = [[-0.5, 2.999, -0.5], [0.5, 2.999, -0.5], [0.5, 2.999, 0.5], [-0.5, 2.999, 0.5]]
"#;
    let text = format!("{camera}{FLOOR}{room}");
    let exact = |points: &[Vec3]| {
        let e = |p: &Vec3| {
            let (px, pz) = (p.x as f64, p.z as f64);
            0.5 / std::f64::consts::PI * 10.0 * rectangle_irradiance(-0.5 - px, 0.5 - px, -0.5 - pz, 0.5 - pz, 2.999)
        };
        points.iter().map(e).sum::<f64>() / points.len() as f64
    };
    let hints = BuildHints { frequency: Some(8), patch_size: Some(0.25), ..Default::default() };
    let pixels = floor_pixels_of(&text, hints, true, 1.95);
    assert!(pixels.len() > 1000, "{} floor pixels", pixels.len());
    let (mut num, mut den, mut worst) = (0.0f64, 0.0f64, 0.0f64);
    for (points, got) in &pixels {
        let want = exact(points);
        num += (got - want).powi(2);
        den += want * want;
        worst = worst.max((got - want).abs() / want);
    }
    let l2 = (num / den).sqrt();
    // The issue asks for 0.5%; measured 1.6e-4 (relative L2) and 3.0e-4
    // (worst: the closed form at each pixel's centre, see above).
    eprintln!("black room: relative L2 {l2:.2e}, worst pixel {worst:.2e}");
    assert!(l2 < 0.005, "relative L2 {:.3}% off the exact floor radiance", 100.0 * l2);
    assert!(worst < 1e-3, "worst floor pixel {:.3}% off", 100.0 * worst);
}

#[test]
fn a_blocker_casts_the_shadow_the_closed_form_gives() {
    let pixels = floor_pixels(true, true);
    // Pixels whose light the blocker dims: the mean relative error there
    // (the estimator is unbiased: penumbra noise averages out), its RMS,
    // and the worst pixel, relative to the unshadowed value.
    let (mut sum, mut sq, mut count, mut worst) = (0.0, 0.0, 0, 0.0f64);
    for (points, got) in &pixels {
        let (want, open) = (exact_pixel(points, true), exact_pixel(points, false));
        let err = (got - want) / open;
        worst = worst.max(err.abs());
        if want < 0.95 * open {
            sum += err;
            sq += err * err;
            count += 1;
        }
    }
    assert!(count > 200, "{count} shadowed pixels");
    let (mean, rms) = (sum / count as f64, (sq / count as f64).sqrt());
    eprintln!("shadowed pixels: mean {mean:.2e}, RMS {rms:.2e}, worst {worst:.2e}");
    // Measured: mean -0.12%, RMS 2.1%, worst 14.9% (a lone pixel whose own
    // four first rays, and none of its neighbours', met the blocker: its
    // estimate stays unbiased and noisy; 64 rays elsewhere in penumbrae).
    assert!(mean.abs() < 0.005, "shadowed pixels {:.2}% off on average", 100.0 * mean);
    assert!(rms < 0.035, "shadowed pixels {:.2}% RMS", 100.0 * rms);
    assert!(worst < 0.2, "worst pixel {:.2}% of the open-sky value off", 100.0 * worst);
}

#[test]
fn the_direct_part_is_the_first_reflection_of_the_emission() {
    let s = common::scene(&scene(true));
    let a = common::build_archive(&s, BuildHints { frequency: Some(6), patch_size: Some(0.2), ..Default::default() });
    let v = a.view();
    // One plain step from cold reflects exactly the emission's first bounce.
    let one = DistributeOptions { max_iterations: 1, anderson_depth: 0, ..Default::default() };
    let first = distribute::distribute(&v, &one, &NoProgress).unwrap();
    let full = distribute::distribute(&v, &DistributeOptions::default(), &NoProgress).unwrap();
    let direct = full.direct.as_ref().unwrap();
    let (patch_surface, emission) = (common::patch_surface(&v), &full.surface_emission);
    for p in 0..v.patch_count() {
        for c in 0..3 {
            let e = emission[patch_surface[p] as usize][c];
            let want = first.radiance[p][c] - e;
            assert!(
                (direct[p][c] - want).abs() <= 1e-5 * want.abs().max(1e-3),
                "patch {p}: {} vs {want}",
                direct[p][c]
            );
            assert!(direct[p][c] <= full.radiance[p][c] - e + 1e-6);
        }
    }
    assert!(direct.iter().any(|d| d[0] > 0.0));
    assert!(
        distribute::distribute(&v, &DistributeOptions { split_direct: false, ..Default::default() }, &NoProgress)
            .unwrap()
            .direct
            .is_none()
    );
}

#[test]
fn direct_images_do_not_depend_on_the_thread_count() {
    // A grey wall beside the floor gives them light to exchange.
    let wall =
        "\n[[surface]]\nname = \"wall\"\nmaterial = \"grey\"\nquad = [[-2, 0, 1], [-2, 2, 1], [2, 2, 1], [2, 0, 1]]\n";
    let s = common::scene(&(scene(true) + wall));
    let a = common::build_archive(&s, BuildHints { frequency: Some(6), patch_size: Some(0.2), ..Default::default() });
    let v = a.view();
    let sol = distribute::distribute(&v, &DistributeOptions::default(), &NoProgress).unwrap();
    let light = DirectLight::new(&v, &sol, render::direct::DEFAULT_LIGHT_SAMPLES);
    let indirect = render::indirect_frame_radiance(&v, 0, &sol);
    // With the one-bounce gather everywhere too (its rays are seeded per pixel).
    let gathering = light.clone().with_gather(&v, &sol, 32, f32::INFINITY);
    let render_with = |threads: usize, light: &DirectLight| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| Renderer::new(&v, RenderOptions::default()).frame_direct(0, &indirect, light))
    };
    let (g1, g3) = (render_with(1, &gathering), render_with(3, &gathering));
    assert!(g1.0.pixels == g3.0.pixels);
    let (a, b) = (render_with(1, &light), render_with(3, &light));
    assert!(a.0.pixels == b.0.pixels && a.1.pixels == b.1.pixels);
    assert!(a.0.pixels != g1.0.pixels);
    // The direct layer is part of the total.
    assert!(a.0.pixels.iter().zip(&a.1.pixels).all(|(t, d)| (0..3).all(|c| d[c] <= t[c] + 1e-6)));
}
