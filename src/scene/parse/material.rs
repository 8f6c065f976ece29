//! `[[material]]`: a material's type and fields, checked, into a
//! [`ReflectanceModel`]; over a `[gltf]` scene, a material of the file's
//! name overrides it.

use toml::Spanned;

use super::errors::Ctx;
use super::raw::{Ior, RawMaterial, V3};
use crate::reflectance::Lobe;
use crate::scene::{Material, ReflectanceModel, SceneError, Surface};

/// Adds the `i`-th `[[material]]` to `materials`, whose first `from_gltf`
/// came from a glTF file: one of those of its name takes its model, else
/// it is new (a name given twice in this file is an error).
pub(super) fn add_material(
    cx: &Ctx<'_>,
    i: usize,
    m: &RawMaterial,
    materials: &mut Vec<Material>,
    from_gltf: usize,
) -> Result<(), SceneError> {
    let field = |f: &str| format!("material[{i}].{f}");
    if materials[from_gltf..].iter().any(|x| x.name == *m.name.get_ref()) {
        return Err(cx.err(m.name.span(), field("name"), format!("duplicate material name `{}`", m.name.get_ref())));
    }
    let model = model_of(cx, i, m)?;
    match materials[..from_gltf].iter_mut().find(|x| x.name == *m.name.get_ref()) {
        Some(overridden) => overridden.model = model,
        None => materials.push(Material { name: m.name.get_ref().clone(), model }),
    }
    Ok(())
}

/// The reflectance model the `i`-th `[[material]]` describes: its `type`
/// and the fields that type needs (and no others).
fn model_of(cx: &Ctx<'_>, i: usize, m: &RawMaterial) -> Result<ReflectanceModel, SceneError> {
    let field = |f: &str| format!("material[{i}].{f}");
    let unit_rgb = |v: &Option<Spanned<V3>>, key: &str, what: &str| -> Result<[f32; 3], SceneError> {
        let r = v.as_ref().ok_or_else(|| {
            cx.err(m.kind.span(), field(key), format!("a {} material needs `{key} = [r, g, b]`", m.kind.get_ref()))
        })?;
        if !r.get_ref().iter().all(|x| (0.0..=1.0).contains(x)) {
            return Err(cx.err(r.span(), field(key), format!("each component of {what} must be in [0, 1]")));
        }
        Ok(r.get_ref().0)
    };
    let unused = |present: bool, key: &str| -> Result<(), SceneError> {
        if present {
            Err(cx.err(m.kind.span(), field(key), format!("a {} material has no `{key}`", m.kind.get_ref())))
        } else {
            Ok(())
        }
    };
    let model = match m.kind.get_ref().as_str() {
        "diffuse" => {
            unused(m.specular.is_some(), "specular")?;
            unused(m.alpha.is_some() || m.alpha_u.is_some() || m.alpha_v.is_some(), "alpha")?;
            unused(m.ior.is_some(), "ior")?;
            ReflectanceModel::Diffuse { reflectance: unit_rgb(&m.reflectance, "reflectance", "a reflectance")? }
        }
        "rough_conductor" => {
            unused(m.reflectance.is_some(), "reflectance")?;
            ReflectanceModel::RoughConductor {
                specular: unit_rgb(&m.specular, "specular", "a specular colour")?,
                lobe: lobe_of(cx, i, m)?,
            }
        }
        "broad_specular" => {
            let kd = unit_rgb(&m.reflectance, "reflectance", "a reflectance")?;
            let ks = unit_rgb(&m.specular, "specular", "a specular colour")?;
            if !crate::limits::conserves_energy(kd, ks) {
                return Err(cx.err(
                    m.specular.as_ref().map_or(m.kind.span(), |s| s.span()),
                    field("specular"),
                    "reflectance + specular must not exceed 1 in any band (the surface would create energy)",
                ));
            }
            ReflectanceModel::BroadSpecular { reflectance: kd, specular: ks, lobe: lobe_of(cx, i, m)? }
        }
        other => {
            return Err(cx.err(
                m.kind.span(),
                field("type"),
                format!("unknown material type `{other}` (known: diffuse, rough_conductor, broad_specular)"),
            ));
        }
    };
    Ok(model)
}

/// A glossy material's lobe: `alpha` (isotropic) or `alpha_u` and
/// `alpha_v`, and an optional index of refraction.
fn lobe_of(cx: &Ctx<'_>, i: usize, m: &RawMaterial) -> Result<Lobe, SceneError> {
    let field = |f: &str| format!("material[{i}].{f}");
    let check = |a: &Spanned<f32>, key: &str| {
        let x = *a.get_ref();
        if (0.01..=1.0).contains(&x) {
            Ok(x)
        } else {
            Err(cx.err(a.span(), field(key), "roughness must be in [0.01, 1]"))
        }
    };
    let (au, av) = match (&m.alpha, &m.alpha_u, &m.alpha_v) {
        (Some(a), None, None) => (check(a, "alpha")?, check(a, "alpha")?),
        (None, Some(u), Some(v)) => (check(u, "alpha_u")?, check(v, "alpha_v")?),
        (Some(a), _, _) => {
            return Err(cx.err(a.span(), field("alpha"), "give `alpha` or `alpha_u` and `alpha_v`, not both"));
        }
        _ => {
            return Err(cx.err(
                m.kind.span(),
                field("alpha"),
                "a glossy material needs `alpha = a` (isotropic) or `alpha_u` and `alpha_v`",
            ));
        }
    };
    let ior = match &m.ior {
        None => None,
        Some(i) => {
            let v = match i.get_ref() {
                Ior::One(x) => [*x; 3],
                Ior::Bands(b) => b.0,
            };
            if !v.iter().all(|x| x.is_finite() && *x > 0.0) {
                return Err(cx.err(i.span(), field("ior"), "an index of refraction must be positive"));
            }
            Some(v)
        }
    };
    Ok(Lobe { alpha_u: au, alpha_v: av, ior })
}

/// Over a glTF scene, a material of this file overrides the glTF's of
/// its name, or is new for this file's surfaces: one that does neither
/// is a misspelt override, which would change nothing.
pub(super) fn check_overrides(
    cx: &Ctx<'_>,
    raw: &[Spanned<RawMaterial>],
    materials: &[Material],
    from_gltf: usize,
    surfaces: &[Surface],
) -> Result<(), SceneError> {
    for (i, m) in raw.iter().enumerate() {
        let name = m.get_ref().name.get_ref();
        let at = materials.iter().position(|x| x.name == *name).expect("every material was added");
        if at >= from_gltf && !surfaces.iter().any(|s| s.material as usize == at) {
            let known: Vec<&str> = materials[..from_gltf].iter().map(|x| x.name.as_str()).collect();
            return Err(cx.err(
                m.get_ref().name.span(),
                format!("material[{i}].name"),
                format!(
                    "`{name}` names no material of the glTF file ({}) and no surface uses it: a misspelt override?",
                    if known.is_empty() { "it has none".to_string() } else { known.join(", ") }
                ),
            ));
        }
    }
    Ok(())
}
