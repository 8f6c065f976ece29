//! A frame's energy balance: the line that reports it, the refusal of an
//! unconverged distribution (exit 7, after the line), and the warnings of
//! a frame that emits nothing or loses almost all its light.

use anyhow::Result;
use illumnet::archive;
use illumnet::distribute::EnergyBalance;

use crate::cli::exit::ResultRefused;

use super::options::RenderArgs;

/// The sum of a per-band quantity.
fn sum(a: &[f64; 3]) -> f64 {
    a.iter().sum::<f64>()
}

/// Prints frame `f`'s energy balance (its number first when the render
/// writes several frames).
pub fn print_balance(f: u32, b: &EnergyBalance, sequence_output: bool, view: &archive::InetView<'_>) {
    println!(
        "{}energy balance: emitted {:.4} W, absorbed {:.4} W, {}, residual {:.2e} W (imbalance {:.1e}), {} iterations{}{}",
        if sequence_output { format!("frame {f}: ") } else { String::new() },
        sum(&b.emitted),
        sum(&b.absorbed),
        match view.patch_back_hits {
            Some(_) => format!("absorbed by back faces {:.4} W, escaped {:.4} W", sum(&b.back_faces), sum(&b.escaped)),
            // Without PBAK (built before version 9, or upgraded):
            // the two are not told apart.
            None => format!("escaped or met back faces {:.4} W (rebuild to tell them apart)", sum(&b.escaped)),
        },
        sum(&b.residual),
        b.imbalance(),
        b.iterations,
        match b.table_steps {
            0 => String::new(),
            k => format!(" ({k} reading glossy tables)"),
        },
        if b.converged { "" } else { " (NOT converged)" }
    );
}

/// Refuses frame `f`'s light when its distribution stopped before the
/// tolerance, unless `--allow-unconverged`.
pub fn refuse_unconverged(f: u32, b: &EnergyBalance, args: &RenderArgs) -> Result<()> {
    if !b.converged && !args.allow_unconverged {
        return Err(anyhow::Error::new(ResultRefused(format!(
            "frame {f}: the distribution did not converge in {} iterations (unshot power {:.2e} of the {:.4} W \
             emitted, tolerance {:e}): raise --max-iterations or --tolerance, or write it anyway with \
             --allow-unconverged",
            b.iterations,
            sum(&b.residual) / sum(&b.emitted).max(f64::MIN_POSITIVE),
            sum(&b.emitted),
            args.tolerance
        ))));
    }
    Ok(())
}

/// Warns, once per render (`warned_dark`), of a frame that emits no
/// light, or whose light almost all goes into back faces or out of the
/// scene.
pub fn warn_if_dark(f: u32, b: &EnergyBalance, warned_dark: &mut bool) {
    let emitted = sum(&b.emitted);
    if emitted <= 0.0 && !*warned_dark {
        *warned_dark = true;
        eprintln!(
            "illumnet: warning: frame {f} emits no light (0 W), so only emitters seen directly will show: \
             the scene has no surface with `emission`, or --set made them black"
        );
    } else if emitted > 0.0 && sum(&b.escaped) + sum(&b.back_faces) > 0.999 * emitted && !*warned_dark {
        *warned_dark = true;
        let (escaped, back) = (sum(&b.escaped), sum(&b.back_faces));
        if back > escaped {
            eprintln!(
                "illumnet: warning: frame {f}: {:.1}% of the {emitted:.4} W emitted goes into the back faces of \
                 one-sided surfaces, which absorb it: does an emitter face a wall from behind it, or is a \
                 surface's front (the right-hand rule's normal) turned away from the room?",
                100.0 * back / emitted
            );
        } else {
            eprintln!(
                "illumnet: warning: frame {f}: {:.1}% of the {emitted:.4} W emitted escapes the scene without \
                 reaching a surface that absorbs it: does an emitter face away from the scene?",
                100.0 * (escaped + back) / emitted
            );
        }
    }
}
