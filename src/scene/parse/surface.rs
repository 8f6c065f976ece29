//! `[[surface]]`: a surface's primitives (a quad, quads, a box or an OBJ
//! mesh, placed by its transform), material, emission, keys and grain.

use std::ops::Range;
use std::path::Path;

use glam::{Mat3, Vec3};
use toml::Spanned;

use super::errors::Ctx;
use super::motion::{emission_keys, parse_motion};
use super::raw::{Exact, RawAnimation, RawBox, RawSurface, RawTransform};
use crate::geometry::{Primitive, PrimitiveKind};
use crate::scene::check::check_primitive;
use crate::scene::{Material, SceneError, Surface};

/// The `i`-th `[[surface]]` (`spanned`), checked: its name new among
/// `surfaces` (the glTF file's and those read before it), its material
/// one of `materials`, its emission, primitives, keys and grain.
#[allow(clippy::too_many_arguments)]
pub(super) fn surface_of(
    cx: &Ctx<'_>,
    i: usize,
    spanned: &Spanned<RawSurface>,
    materials: &[Material],
    surfaces: &[Surface],
    animation: &Option<Spanned<RawAnimation>>,
    base_dir: &Path,
) -> Result<Surface, SceneError> {
    let sspan = spanned.span();
    let s = spanned.get_ref();
    let field = |f: &str| format!("surface[{i}].{f}");
    let name = s.name.get_ref().clone();
    if surfaces.iter().any(|x| x.name == name) {
        return Err(cx.err(s.name.span(), field("name"), format!("duplicate surface name `{name}`")));
    }
    let material = materials.iter().position(|m| m.name == *s.material.get_ref()).ok_or_else(|| {
        let known: Vec<&str> = materials.iter().map(|m| m.name.as_str()).collect();
        cx.err(
            s.material.span(),
            field("material"),
            format!("no material named `{}` (known: {})", s.material.get_ref(), known.join(", ")),
        )
    })? as u32;
    let emission = match &s.emission {
        Some(e) => {
            if !e.get_ref().iter().all(|x| (0.0..=crate::limits::MAX_RADIANCE).contains(x)) {
                return Err(cx.err(e.span(), field("emission"), "each component must be in [0, 1e9] W·sr⁻¹·m⁻²"));
            }
            e.get_ref().0
        }
        None => [0.0; 3],
    };
    let prims = primitives_of(cx, s, sspan, &field, base_dir)?;
    let motion = parse_motion(cx, s, animation, &field)?;
    let emission_keys = emission_keys(cx, s, animation, &field)?;
    let grain = grain_of(cx, s, &field)?;
    Ok(Surface {
        name,
        material,
        emission,
        primitives: prims,
        motion,
        emission_keys,
        grain,
        moved: false,
        shading: Vec::new(),
    })
}

/// The surface's primitives: exactly one of `quad`, `quads`, `box` or
/// `mesh`, placed by its `transform`, each checked ([`check_primitive`]);
/// errors name the geometry's field (`sspan`: the whole surface's span).
fn primitives_of(
    cx: &Ctx<'_>,
    s: &RawSurface,
    sspan: Range<usize>,
    field: &dyn Fn(&str) -> String,
    base_dir: &Path,
) -> Result<Vec<Primitive>, SceneError> {
    let given = [s.quad.is_some(), s.quads.is_some(), s.cuboid.is_some(), s.mesh.is_some()];
    if given.iter().filter(|&&g| g).count() != 1 {
        return Err(cx.err(sspan, field("quad"), "give exactly one of `quad`, `quads`, `box` or `mesh`"));
    }
    let mut prims: Vec<Primitive> = Vec::new();
    let mut geometry_span = sspan.clone();
    let mut geometry_field = field("quad");
    if let Some(q) = &s.quad {
        prims.push(Primitive::quad(q.get_ref().0.map(Vec3::from)));
        geometry_span = q.span();
    }
    if let Some(qs) = &s.quads {
        prims.extend(qs.get_ref().iter().map(|q| Primitive::quad(q.map(Vec3::from))));
        geometry_span = qs.span();
        geometry_field = field("quads");
    }
    if let Some(b) = &s.cuboid {
        geometry_span = b.span();
        geometry_field = field("box");
        prims.extend(box_quads(b.get_ref()).map_err(|m| cx.err(b.span(), field("box"), m))?);
    }
    if let Some(m) = &s.mesh {
        geometry_span = m.span();
        geometry_field = field("mesh");
        let path = base_dir.join(m.get_ref());
        // (A file that is not there is an I/O failure, still named at
        // its field.)
        prims.extend(
            load_obj(&path)
                .map_err(|(msg, unreadable)| SceneError { unreadable, ..cx.err(m.span(), field("mesh"), msg) })?,
        );
    }
    if let Some(t) = &s.transform {
        let m = transform_matrix(t.get_ref()).map_err(|msg| cx.err(t.span(), field("transform"), msg))?;
        apply_transform(&mut prims, m);
    }
    for (k, p) in prims.iter().enumerate() {
        check_primitive(p)
            .map_err(|msg| cx.err(geometry_span.clone(), geometry_field.clone(), format!("primitive {k}: {msg}")))?;
    }
    if prims.is_empty() {
        return Err(cx.err(geometry_span, geometry_field, "the surface has no primitives"));
    }
    Ok(prims)
}

/// `prims` moved by the matrix and translation `m`, each still facing
/// front.
fn apply_transform(prims: &mut [Primitive], m: (Mat3, Vec3)) {
    let mirrored = m.0.determinant() < 0.0;
    for p in prims {
        for v in &mut p.p {
            *v = m.0 * *v + m.1;
        }
        if mirrored {
            // A mirroring scale reverses the winding: restore the front side.
            *p = match p.kind {
                PrimitiveKind::Quad => Primitive::quad([p.p[3], p.p[2], p.p[1], p.p[0]]),
                PrimitiveKind::Triangle => Primitive::triangle(p.p[0], p.p[2], p.p[1]),
            };
        }
    }
}

/// The surface's grain in world space (its `transform` applied), unit
/// length; `None` when not given.
fn grain_of(cx: &Ctx<'_>, s: &RawSurface, field: &dyn Fn(&str) -> String) -> Result<Option<Vec3>, SceneError> {
    let grain = match &s.grain {
        None => None,
        Some(g) => {
            let v = Vec3::from(*g.get_ref());
            if !v.is_finite() || v.length() < 1e-6 {
                return Err(cx.err(g.span(), field("grain"), "the grain must be a non-zero direction"));
            }
            // Local coordinates: the surface's transform applies.
            let v = match &s.transform {
                Some(t) => transform_matrix(t.get_ref()).map(|m| m.0 * v).unwrap_or(v),
                None => v,
            };
            Some(v.normalize())
        }
    };
    Ok(grain)
}

/// The six faces of a `box` (less those `omit` names), facing out, or in
/// when `inward`.
fn box_quads(b: &RawBox) -> Result<Vec<Primitive>, String> {
    let (lo, hi) = (Vec3::from(b.min), Vec3::from(b.max));
    if !(lo.is_finite() && hi.is_finite()) || lo.cmpge(hi).any() {
        return Err("min must be below max on every axis".into());
    }
    const FACES: [&str; 6] = ["-x", "+x", "-y", "+y", "-z", "+z"];
    for o in &b.omit {
        if !FACES.contains(&o.as_str()) {
            return Err(format!("unknown face `{o}` in omit (known: {})", FACES.join(", ")));
        }
    }
    let mut out = Vec::new();
    for axis in 0..3 {
        for positive in [false, true] {
            let label = FACES[axis * 2 + positive as usize];
            if b.omit.iter().any(|o| o == label) {
                continue;
            }
            let (bx, cx) = ((axis + 1) % 3, (axis + 2) % 3);
            let corner = |s: bool, t: bool| {
                let mut v = Vec3::ZERO;
                v[axis] = if positive { hi[axis] } else { lo[axis] };
                v[bx] = if s { hi[bx] } else { lo[bx] };
                v[cx] = if t { hi[cx] } else { lo[cx] };
                v
            };
            // e_b × e_c = +e_axis: this order faces +axis.
            let mut q = [corner(false, false), corner(true, false), corner(true, true), corner(false, true)];
            if positive == b.inward {
                q.reverse();
            }
            out.push(Primitive::quad(q));
        }
    }
    Ok(out)
}

/// A `transform` as a matrix (rotation about z·y·x after scale) and a
/// translation.
fn transform_matrix(t: &RawTransform) -> Result<(Mat3, Vec3), String> {
    let s = Vec3::from(t.scale.unwrap_or(Exact([1.0; 3])));
    let r = Vec3::from(t.rotate_deg.unwrap_or(Exact([0.0; 3])));
    let tr = Vec3::from(t.translate.unwrap_or(Exact([0.0; 3])));
    if !(s.is_finite() && r.is_finite() && tr.is_finite()) || s.cmpeq(Vec3::ZERO).any() {
        return Err("scale must be non-zero; all values finite".into());
    }
    let rot = Mat3::from_rotation_z(r.z.to_radians())
        * Mat3::from_rotation_y(r.y.to_radians())
        * Mat3::from_rotation_x(r.x.to_radians());
    Ok((rot * Mat3::from_diagonal(s), tr))
}

/// The triangles of the OBJ file at `path` (a `mesh` surface): positions
/// only, materials ignored.
fn load_obj(path: &Path) -> Result<Vec<Primitive>, (String, bool)> {
    let (models, _, _) = crate::scene::obj::load_obj_file(path).map_err(|e| {
        let what = if e.file == path { "OBJ".to_string() } else { format!("OBJ `{}`: its MTL", path.display()) };
        let hint =
            if e.unreadable && e.file == path { " (a mesh path is taken from the scene file's folder)" } else { "" };
        (format!("cannot read {what} `{}`{hint}: {}", e.file.display(), e.message), e.unreadable)
    })?;
    let mut out = Vec::new();
    for m in models {
        let pos = &m.mesh.positions;
        let vert = |i: u32| -> Result<Vec3, (String, bool)> {
            let i = i as usize * 3;
            pos.get(i..i + 3)
                .map(|p| Vec3::new(p[0], p[1], p[2]))
                .ok_or_else(|| (format!("OBJ `{}`: face index out of range", path.display()), false))
        };
        for f in m.mesh.indices.chunks_exact(3) {
            out.push(Primitive::triangle(vert(f[0])?, vert(f[1])?, vert(f[2])?));
        }
    }
    if out.is_empty() {
        return Err((format!("OBJ `{}` has no faces", path.display()), false));
    }
    Ok(out)
}
