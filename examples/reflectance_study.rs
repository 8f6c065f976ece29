//! Measures prototype tables (build time, entries, bytes, albedo error
//! before/after the scaling) against the direction-set frequency, and the
//! angular error of both actual-to-prototype map constructions over a set
//! of orientations. Numbers for `docs/ACCURACY.md` and `docs/PERFORMANCE.md`:
//!
//! ```text
//! cargo run --release --example reflectance_study
//! ```

use illumnet::geodesic::DirectionSet;
use illumnet::reflectance::{Frame, Lobe, MapMethod, OrientationMap, TableModel, prototype};

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
}
