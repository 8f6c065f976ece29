//! Reflectance models, evaluated in a surface's local frame.
//!
//! Local frame: `t` along the grain (the surface's tangent), `n` the normal,
//! `b = n × t`; a direction `ω` has coordinates `(ω·t, ω·b, ω·n)`. Both
//! directions point away from the surface (`ω_i` towards where light comes
//! from). The prototype orientation of §3.6.1 is `n = +y`, `t = +x`.
//!
//! The models are defined exactly so that a path tracer renders the same
//! scene (`format-spec/scene.md`):
//!
//! - *diffuse*: `f = k_d/π`;
//! - *rough conductor*: `f = k_s·F·D(h)·G₁(i)·G₁(o) / (4 cos θᵢ cos θₒ)`, `D`
//!   the anisotropic GGX (Trowbridge–Reitz) distribution with roughness `α_u`
//!   along the grain and `α_v` across it, `G₁` its separable Smith shadowing
//!   term, `F = 1` or Schlick's approximation for a given index of refraction
//!   (Mitsuba 3's `roughconductor`, `distribution = ggx`, `material = none`);
//! - *broad specular*: the sum of the two.
//!
//! A [`Lobe`] is the rough-conductor term without its colour `k_s`: what a
//! prototype table stores (the colour multiplies the table's generic factors).

use std::f64::consts::PI;

/// Strata per axis of the albedo quadrature used for tables: 128² normals
/// give the albedo to 1e-3 (tested against brute force), and keep a table of
/// 1 442 directions under half a second.
pub const ALBEDO_STRATA: usize = 128;

/// The GGX rough-conductor lobe without its colour `k_s`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lobe {
    /// Roughness along the grain (the tangent), > 0.
    pub alpha_u: f32,
    /// Roughness across the grain, > 0.
    pub alpha_v: f32,
    /// Per-band index of refraction for Schlick's Fresnel term; `None`: F = 1.
    pub ior: Option<[f32; 3]>,
}

/// What a prototype table tabulates: a reflectance function without colour.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TableModel {
    /// `f = 1/π` (a white Lambertian surface): the reference for testing
    /// tables; diffuse surfaces themselves take the cheap diffuse path.
    Lambertian,
    /// The GGX lobe.
    Ggx(Lobe),
}

impl Lobe {
    /// Whether the three bands reflect differently (per-band index of
    /// refraction): the table then stores three factors per entry.
    pub fn bands(&self) -> usize {
        match self.ior {
            Some(n) if n[0] != n[1] || n[1] != n[2] => 3,
            _ => 1,
        }
    }

    /// The GGX normal distribution `D(h)` for a local half vector.
    pub fn distribution(&self, h: [f64; 3]) -> f64 {
        let (au, av) = (self.alpha_u as f64, self.alpha_v as f64);
        if h[2] <= 0.0 {
            return 0.0;
        }
        let s = (h[0] / au).powi(2) + (h[1] / av).powi(2) + h[2] * h[2];
        1.0 / (PI * au * av * s * s)
    }

    /// Smith's shadowing-masking term for one direction.
    pub fn g1(&self, w: [f64; 3]) -> f64 {
        let (au, av) = (self.alpha_u as f64, self.alpha_v as f64);
        if w[2] <= 0.0 {
            return 0.0;
        }
        let a2_tan2 = ((w[0] * au).powi(2) + (w[1] * av).powi(2)) / (w[2] * w[2]);
        2.0 / (1.0 + (1.0 + a2_tan2).sqrt())
    }

    /// Fresnel reflectance for band `c` at `cos θ_d = ω_i·h`.
    pub fn fresnel(&self, c: usize, cos_d: f64) -> f64 {
        match self.ior {
            None => 1.0,
            Some(n) => {
                let n = n[c] as f64;
                let f0 = ((n - 1.0) / (n + 1.0)).powi(2);
                f0 + (1.0 - f0) * (1.0 - cos_d.clamp(0.0, 1.0)).powi(5)
            }
        }
    }

    /// `f(ω_i, ω_o)` for band `c`, without `k_s`; zero unless both
    /// directions are above the surface.
    pub fn eval(&self, c: usize, wi: [f64; 3], wo: [f64; 3]) -> f64 {
        if wi[2] <= 0.0 || wo[2] <= 0.0 {
            return 0.0;
        }
        let h = normalize([wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]]);
        let d = self.distribution(h);
        let cos_d = dot(wi, h);
        d * self.g1(wi) * self.g1(wo) * self.fresnel(c, cos_d) / (4.0 * wi[2] * wo[2])
    }

    /// Directional albedo `∫ f(ω_i, ω_o) cos θ_o dω_o` for band `c`, by
    /// stratified quadrature over microfacet normals distributed as
    /// `D(h)·cos θ_h` (`m × m` strata; see [`ALBEDO_STRATA`]).
    pub fn albedo(&self, c: usize, wi: [f64; 3], m: usize) -> f64 {
        if wi[2] <= 0.0 {
            return 0.0;
        }
        let (au, av) = (self.alpha_u as f64, self.alpha_v as f64);
        let g1i = self.g1(wi);
        let mut sum = 0.0;
        for a in 0..m {
            let u1 = (a as f64 + 0.5) / m as f64;
            let r = (u1 / (1.0 - u1)).sqrt();
            for b in 0..m {
                let phi = 2.0 * PI * (b as f64 + 0.5) / m as f64;
                // Slopes of the stretched GGX; the normal has density D(h)·cos θ_h.
                let h = normalize([-au * r * phi.cos(), -av * r * phi.sin(), 1.0]);
                let ih = dot(wi, h);
                if ih <= 0.0 {
                    continue;
                }
                let wo = [2.0 * ih * h[0] - wi[0], 2.0 * ih * h[1] - wi[1], 2.0 * ih * h[2] - wi[2]];
                if wo[2] <= 0.0 {
                    continue;
                }
                // f·cos θ_o·|dω_o/dω_h| / (D cos θ_h) with |dω_o/dω_h| = 4 (ω_i·h).
                sum += g1i * self.g1(wo) * self.fresnel(c, ih) * ih / (wi[2] * h[2]);
            }
        }
        sum / (m * m) as f64
    }
}

impl TableModel {
    /// Bands the table stores per entry (1: one generic factor).
    pub fn bands(&self) -> usize {
        match self {
            TableModel::Lambertian => 1,
            TableModel::Ggx(l) => l.bands(),
        }
    }

    /// `f(ω_i, ω_o)` for band `c` in the local frame, without colour.
    pub fn eval(&self, c: usize, wi: [f64; 3], wo: [f64; 3]) -> f64 {
        match self {
            TableModel::Lambertian => {
                if wi[2] > 0.0 && wo[2] > 0.0 {
                    1.0 / PI
                } else {
                    0.0
                }
            }
            TableModel::Ggx(l) => l.eval(c, wi, wo),
        }
    }

    /// Directional albedo of the continuous function for band `c`.
    pub fn albedo(&self, c: usize, wi: [f64; 3]) -> f64 {
        match self {
            TableModel::Lambertian => {
                if wi[2] > 0.0 {
                    1.0
                } else {
                    0.0
                }
            }
            TableModel::Ggx(l) => l.albedo(c, wi, ALBEDO_STRATA),
        }
    }
}

pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub(crate) fn normalize(a: [f64; 3]) -> [f64; 3] {
    let l = dot(a, a).sqrt();
    [a[0] / l, a[1] / l, a[2] / l]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(theta: f64, phi: f64) -> [f64; 3] {
        [theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()]
    }

    /// Brute-force albedo over a fine (θ, φ) grid.
    fn brute_albedo(l: &Lobe, wi: [f64; 3], n: usize) -> f64 {
        let mut s = 0.0;
        for a in 0..n {
            let t = (a as f64 + 0.5) / n as f64 * PI / 2.0;
            for b in 0..4 * n {
                let p = (b as f64 + 0.5) / (4 * n) as f64 * 2.0 * PI;
                let wo = dir(t, p);
                s += l.eval(0, wi, wo) * wo[2] * t.sin() * (PI / 2.0 / n as f64) * (2.0 * PI / (4 * n) as f64);
            }
        }
        s
    }

    #[test]
    fn ggx_distribution_projects_to_one() {
        // ∫ D(h) cos θ_h dω_h = 1 for any roughness.
        for (au, av) in [(0.2, 0.2), (0.1, 0.4), (0.5, 0.3)] {
            let l = Lobe { alpha_u: au, alpha_v: av, ior: None };
            let n = 800;
            let mut s = 0.0;
            for a in 0..n {
                let t = (a as f64 + 0.5) / n as f64 * PI / 2.0;
                for b in 0..n {
                    let p = (b as f64 + 0.5) / n as f64 * 2.0 * PI;
                    let h = dir(t, p);
                    s += l.distribution(h) * h[2] * t.sin() * (PI / 2.0 / n as f64) * (2.0 * PI / n as f64);
                }
            }
            assert!((s - 1.0).abs() < 2e-3, "α = ({au}, {av}): ∫D cos = {s}");
        }
    }

    #[test]
    fn quadrature_albedo_matches_brute_force() {
        let l = Lobe { alpha_u: 0.3, alpha_v: 0.5, ior: None };
        for theta in [0.1f64, 0.7, 1.2] {
            let wi = dir(theta, 0.4);
            let (q, b) = (l.albedo(0, wi, ALBEDO_STRATA), brute_albedo(&l, wi, 600));
            assert!((q - b).abs() < 1e-3, "θ = {theta}: quadrature {q}, brute force {b}");
            assert!(q <= 1.0 && q > 0.5, "{q}");
        }
    }

    #[test]
    fn lobe_is_reciprocal_and_anisotropic() {
        let l = Lobe { alpha_u: 0.1, alpha_v: 0.4, ior: Some([1.5; 3]) };
        let (a, b) = (dir(0.5, 0.3), dir(0.9, 2.0));
        assert!((l.eval(0, a, b) - l.eval(0, b, a)).abs() < 1e-12);
        // A highlight stretches across the grain (where roughness is larger).
        let wi = dir(0.6, 0.0);
        let mirror = [-wi[0], -wi[1], wi[2]];
        let along = l.eval(0, wi, normalize([mirror[0] - 0.2, mirror[1], mirror[2]]));
        let across = l.eval(0, wi, normalize([mirror[0], mirror[1] + 0.2, mirror[2]]));
        assert!(across > 1.5 * along, "across {across}, along {along}");
    }
}
