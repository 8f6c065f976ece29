//! The render's deterministic sampling: seeds hashed from frame, pixel
//! and primitive (splitmix64), points of the R2 sequence (a shifted
//! rank-1 lattice) and key-chosen permutations of a pixel's rays. The
//! direct light, the glossy highlights and the gather all draw from
//! here, so images do not depend on the thread count.

use glam::Vec2;

/// Point `i` of the R2 sequence (Roberts' generalised golden ratio, the
/// best-spread additive recurrence in two dimensions) shifted by `shift`.
pub(super) fn r2_point(i: u32, shift: Vec2) -> Vec2 {
    const A: Vec2 = Vec2::new(0.754_877_7, 0.569_840_3);
    let p = shift + A * i as f32;
    p - p.floor()
}

/// splitmix64: a well-mixed 64-bit hash.
pub(super) fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The top 24 bits of `h` as a float in [0, 1).
pub(super) fn unit(h: u64) -> f32 {
    ((h as u32) >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

/// The seed of pixel `(x, y)`'s light samples at `frame`.
pub fn pixel_key(frame: u32, x: u32, y: u32) -> u64 {
    mix(mix(((frame as u64) << 32) | y as u64) ^ ((x as u64) << 32))
}

/// `i ↦ (a·i + b) mod n`, a permutation of `0..n` chosen by a key (`a`
/// odd and coprime with `n`): made once, applied to every ray.
#[derive(Clone, Copy)]
pub(super) struct Permutation {
    a: u64,
    b: u64,
    n: u64,
}

impl Permutation {
    pub(super) fn new(n: u32, key: u64) -> Self {
        let h = mix(key);
        let (n64, b) = (n as u64, (h >> 32) % n.max(1) as u64);
        let mut a = ((h as u32) % n.max(1)) as u64 | 1;
        while gcd(a, n64) != 1 {
            a += 2;
        }
        Self { a, b, n: n64.max(1) }
    }

    #[inline]
    pub(super) fn apply(&self, i: u32) -> u32 {
        ((self.a * i as u64 + self.b) % self.n) as u32
    }
}

fn gcd(mut a: u64, mut b: u64) -> u64 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}
