//! Measures prototype tables (build time, entries, bytes, albedo error
//! before/after the scaling) against the direction-set frequency, and the
//! angular error of both actual-to-prototype map constructions over a set
//! of orientations. Numbers for `docs/ACCURACY.md` and `docs/PERFORMANCE.md`:
//!
//! ```text
//! cargo run --release --example reflectance_study
//! ```

use illumnet::archive::Archive;
use illumnet::bake::{self, BuildSettings};
use illumnet::distribute::{self, DistributeOptions};
use illumnet::geodesic::DirectionSet;
use illumnet::progress::NoProgress;
use illumnet::reflectance::{Frame, Lobe, MapMethod, OrientationMap, TableModel, prototype};
use illumnet::scene::{BuildHints, Scene};

/// A 1 m glossy square (GGX α = 0.2, k_s = 1, grain at `grain_deg` from x)
/// under a 0.6 m square lamp 2 m above; returns the mean and largest
/// relative error of the centre patch's directional radiance against the
/// lamp's reflection integrated exactly, over views 0°..80° in two planes:
/// `Σ|ours − exact| / Σ exact`, and the largest error relative to the
/// largest exact value.
fn rendered_error(method: MapMethod, grain_deg: f32) -> (f64, f64) {
    let g = grain_deg.to_radians();
    let text = format!(
        r#"
[camera]
position = [0.0, 1.0, -3.0]
look_at = [0.0, 0.0, 0.0]
fov_y_deg = 40.0
width = 16
height = 16
[[material]]
name = "metal"
type = "rough_conductor"
specular = [1.0, 1.0, 1.0]
alpha_u = 0.2
alpha_v = 0.2001
[[material]]
name = "black"
type = "diffuse"
reflectance = [0.0, 0.0, 0.0]
[[surface]]
name = "plate"
material = "metal"
quad = [[-0.5, 0.0, -0.5], [-0.5, 0.0, 0.5], [0.5, 0.0, 0.5], [0.5, 0.0, -0.5]]
grain = [{}, 0.0, {}]
[[surface]]
name = "light"
material = "black"
emission = [10.0, 10.0, 10.0]
quad = [[-0.3, 2.0, 0.7], [0.3, 2.0, 0.7], [0.3, 2.0, 1.3], [-0.3, 2.0, 1.3]]
[build]
patch_size = 0.1
ray_spacing = 0.004
frequency = 16
buckets = 0
"#,
        g.cos(),
        g.sin()
    );
    let scene = Scene::from_toml(&text, std::path::Path::new("study.toml"), std::path::Path::new(".")).unwrap();
    let mut s = BuildSettings::resolve(&scene, BuildHints::default());
    s.prototype_library = None;
    s.map_method = method;
    let (c, _) = bake::build(&scene, &s, &NoProgress).unwrap();
    let a = Archive::from_bytes(&illumnet::archive::write_to_vec(&c).unwrap()).unwrap();
    let v = a.view();
    let sol = distribute::distribute(&v, &DistributeOptions::default(), &NoProgress).unwrap();
    let d = sol.directional.as_ref().unwrap();
    let k = (0..d.patches.len())
        .min_by(|&a, &b| {
            let (ca, cb) = (v.patch_centre[d.patches[a] as usize], v.patch_centre[d.patches[b] as usize]);
            (ca[0].powi(2) + ca[2].powi(2)).total_cmp(&(cb[0].powi(2) + cb[2].powi(2)))
        })
        .unwrap();
    let c0 = glam::Vec3::from(v.patch_centre[d.patches[k] as usize]);
    // Exact (α_v differs by 1e-4 only to make the lobe take the grain).
    let lobe = Lobe { alpha_u: 0.2, alpha_v: 0.2001, ior: None };
    let frame = Frame::new([0.0, 1.0, 0.0], [g.cos(), 0.0, g.sin()]);
    let (mut sum, mut total, mut worst, mut peak) = (0.0, 0.0, 0.0f64, 0.0f64);
    for plane in [0.0f32, 90.0] {
        for deg in (0..=80).step_by(5) {
            let (th, ph) = ((deg as f32).to_radians(), plane.to_radians());
            let wo = glam::Vec3::new(th.sin() * ph.sin(), th.cos(), -th.sin() * ph.cos());
            let got = illumnet::render::view::interpolate(v.directions, d.of(k), wo)[0] as f64;
            let m = 48;
            let mut want = 0.0f64;
            for a in 0..m {
                for b in 0..m {
                    let p = glam::Vec3::new(
                        -0.3 + 0.6 * (a as f32 + 0.5) / m as f32,
                        2.0,
                        0.7 + 0.6 * (b as f32 + 0.5) / m as f32,
                    );
                    let w = (p - c0).normalize();
                    let r2 = (p - c0).length_squared() as f64;
                    let l = |x: glam::Vec3| frame.local([x.x as f64, x.y as f64, x.z as f64]);
                    want += lobe.eval(0, l(w), l(wo)) * 10.0 * (w.y as f64).powi(2) * 0.36 / (m * m) as f64 / r2;
                }
            }
            sum += (got - want).abs();
            total += want;
            worst = worst.max((got - want).abs());
            peak = peak.max(want);
        }
    }
    (sum / total, worst / peak)
}

fn main() {
    let threshold: f64 =
        std::env::var("THRESHOLD").ok().and_then(|t| t.parse().ok()).unwrap_or(prototype::DEFAULT_THRESHOLD);
    println!("## Prototype tables (threshold {threshold:e})\n");
    println!(
        "| model | f | N | build s | entries | entries/row | MB | dropped (max) | albedo err before (max / mean) | after (max) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let models = [
        ("Lambertian", TableModel::Lambertian),
        ("GGX α=0.2", TableModel::Ggx(Lobe { alpha_u: 0.2, alpha_v: 0.2, ior: None })),
        ("GGX α=(0.15, 0.45)", TableModel::Ggx(Lobe { alpha_u: 0.15, alpha_v: 0.45, ior: None })),
    ];
    for f in [8u32, 12, 16, 24] {
        let dirs = DirectionSet::new(f).unwrap();
        for (name, model) in &models {
            let t0 = std::time::Instant::now();
            let (t, s) = prototype::build(*model, &dirs.directions, &dirs.solid_angle, threshold);
            let secs = t0.elapsed().as_secs_f64();
            let bytes = t.offsets.len() * 4 + t.outgoing.len() * 4 + t.factors.len() * 4;
            println!(
                "| {name} | {f} | {} | {secs:.2} | {} | {:.0} | {:.1} | {:.2}% | {:.2}% / {:.2}% | {:.1e} |",
                dirs.len(),
                s.entries,
                s.entries as f64 / s.rows as f64,
                bytes as f64 / 1e6,
                100.0 * s.dropped,
                100.0 * s.albedo_error_before,
                100.0 * s.albedo_error_before_mean,
                s.albedo_error_after
            );
        }
    }
    println!("\n## Actual-to-prototype maps\n");
    println!("| f | spacing ° | method | mean ° | max ° | worst-orientation mean ° | build ms |");
    println!("|---|---|---|---|---|---|---|");
    let mut frames = Vec::new();
    // Orientations: axis normals, and 40 pseudo-random normal/grain pairs.
    for n in [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]] {
        frames.push(Frame::new(n, [0.3, 0.5, 0.7]));
    }
    let mut x = 12345u64;
    let mut rnd = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x >> 11) as f32 / (1u64 << 53) as f32 * 2.0 - 1.0
    };
    for _ in 0..40 {
        frames.push(Frame::new([rnd(), rnd(), rnd()], [rnd(), rnd(), rnd()]));
    }
    for f in [12u32, 16] {
        let dirs = DirectionSet::new(f).unwrap();
        let spacing = dirs.uniformity().spacing_mean_rad.to_degrees();
        for method in [MapMethod::Rings, MapMethod::Nearest] {
            let (mut mean, mut max, mut worst) = (0.0, 0.0f64, 0.0f64);
            let t0 = std::time::Instant::now();
            for fr in &frames {
                let m = OrientationMap::new(&dirs.directions, &dirs.neighbours, fr, method);
                assert!(m.is_bijection());
                let s = m.stats(&dirs.directions, fr);
                mean += s.mean_rad.to_degrees() / frames.len() as f64;
                max = max.max(s.max_rad.to_degrees());
                worst = worst.max(s.mean_rad.to_degrees());
            }
            let ms = t0.elapsed().as_secs_f64() * 1e3 / frames.len() as f64;
            println!("| {f} | {spacing:.2} | {method:?} | {mean:.2} | {max:.2} | {worst:.2} | {ms:.1} |");
        }
    }
    println!("\n## Rendered error of the maps (glossy square, f = 16, lamp reflection vs exact)\n");
    println!("| grain | method | Σ|error| / Σ exact | worst / peak |");
    println!("|---|---|---|---|");
    for grain in [0.0f32, 30.0, 90.0] {
        for method in [MapMethod::Rings, MapMethod::Nearest] {
            let (mean, worst) = rendered_error(method, grain);
            println!("| {grain}° | {method:?} | {:.1}% | {:.1}% |", 100.0 * mean, 100.0 * worst);
        }
    }
}
