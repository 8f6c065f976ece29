//! What an iteration's received totals become once the loop stops: the
//! solution's received power, per-patch residual and radiance, made a
//! block of patches at a time so that spilled totals (`spill.rs`) are
//! read back a block at a time too.

use rayon::prelude::*;

use super::Distributor;
use super::kernels::BLOCK;
use super::setup::FrameSetup;
use super::spill::PatchVec;

/// The received totals: what hit each patch itself (bucket 0) and what
/// was spread onto it.
pub(super) type Totals<'a> = (&'a PatchVec<[f32; 3]>, &'a PatchVec<[f32; 3]>);

/// Per patch, the power received over the iterations, and the power left
/// unshot (`unshot`) over it, summed over bands (0 where it received
/// none): where the distribution has not converged.
pub(super) fn received_and_residual(
    unshot: &[[f32; 3]],
    (direct, spread): Totals<'_>,
) -> std::io::Result<(Vec<[f32; 3]>, Vec<f32>)> {
    let n = unshot.len();
    let mut received = vec![[0.0f32; 3]; n];
    let mut residual = vec![0.0f32; n];
    received.par_chunks_mut(BLOCK).zip(residual.par_chunks_mut(BLOCK)).enumerate().try_for_each_init(
        || (Vec::new(), Vec::new()),
        |(bd, bs), (block, (rec, res))| {
            let range = block * BLOCK..block * BLOCK + rec.len();
            let (td, ts) = (direct.range(range.clone(), bd)?, spread.range(range, bs)?);
            for (i, (r, x)) in rec.iter_mut().zip(res.iter_mut()).enumerate() {
                let u = unshot[block * BLOCK + i];
                *r = [0, 1, 2].map(|c| td[i][c] + ts[i][c]);
                let got = r[0] + r[1] + r[2];
                *x = if got > 0.0 { (u[0].abs() + u[1].abs() + u[2].abs()) / got } else { 0.0 };
            }
            Ok::<(), std::io::Error>(())
        },
    )?;
    Ok((received, residual))
}

/// Per patch, the radiance its emission and what it received make: `E +
/// ρ·(direct/A_eff + spread/A)/π` (the direct light's density follows the
/// patch's hit count, §3.4).
pub(super) fn radiance(
    d: &Distributor<'_>,
    s: &FrameSetup<'_>,
    (direct, spread): Totals<'_>,
) -> std::io::Result<Vec<[f32; 3]>> {
    let (v, inv_pi) = (&d.v, 1.0 / std::f32::consts::PI);
    let mut radiance = vec![[0.0f32; 3]; v.patch_count()];
    radiance.par_chunks_mut(BLOCK).enumerate().try_for_each_init(
        || (Vec::new(), Vec::new()),
        |(bd, bs), (block, rad)| {
            let range = block * BLOCK..block * BLOCK + rad.len();
            let (td, ts) = (direct.range(range.clone(), bd)?, spread.range(range, bs)?);
            for (i, l) in rad.iter_mut().enumerate() {
                let p = block * BLOCK + i;
                let (area_eff, rho, emit) = (d.area_eff(p), d.rho(p), s.emit(p));
                let kd = if area_eff > 0.0 { inv_pi / area_eff } else { 0.0 };
                let ks = if v.patch_area[p] > 0.0 { inv_pi / v.patch_area[p] } else { 0.0 };
                *l = [0, 1, 2].map(|c| emit[c] + rho[c] * (td[i][c] * kd + ts[i][c] * ks));
            }
            Ok::<(), std::io::Error>(())
        },
    )?;
    Ok(radiance)
}
