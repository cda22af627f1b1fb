//! Small deterministic random numbers (xorshift64*, Vigna 2016) for tests, fuzzing and
//! generated scenes: the same seed gives the same sequence on every machine, so failures
//! reproduce exactly. Not for sampling in the renderer, which hashes (pixel, sample) instead.

use glam::{DVec3, Vec3};

/// xorshift64* generator ("An experimental exploration of Marsaglia's xorshift generators,
/// scrambled", S. Vigna, 2016).
#[derive(Debug, Clone)]
pub struct Rng(pub u64);

impl Rng {
    /// A generator from any seed (0 included).
    pub fn new(seed: u64) -> Self {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in [0, 1), with 53 random bits.
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [0, 1) as f32, with 24 random bits.
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in [lo, hi) as f32.
    pub fn range_f32(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.next_f32()
    }

    /// A vector with each component uniform in [lo, hi).
    pub fn vec3_in(&mut self, lo: f32, hi: f32) -> Vec3 {
        Vec3::new(
            self.range_f32(lo, hi),
            self.range_f32(lo, hi),
            self.range_f32(lo, hi),
        )
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }

    /// Uniform integer in [0, n) (n > 0).
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n
    }

    /// True with probability p.
    pub fn chance(&mut self, p: f64) -> bool {
        self.uniform() < p
    }

    /// Uniform in the cube [−half, half]³.
    pub fn in_cube(&mut self, half: f64) -> DVec3 {
        DVec3::new(
            self.range(-half, half),
            self.range(-half, half),
            self.range(-half, half),
        )
    }

    /// Uniform unit vector (rejection sampling in the unit ball).
    pub fn direction_f64(&mut self) -> DVec3 {
        loop {
            let v = self.in_cube(1.0);
            let l2 = v.length_squared();
            if l2 > 1e-4 && l2 <= 1.0 {
                return v / l2.sqrt();
            }
        }
    }

    /// Uniform in the box [lo, hi].
    pub fn in_box(&mut self, lo: Vec3, hi: Vec3) -> Vec3 {
        let t = Vec3::new(self.next_f32(), self.next_f32(), self.next_f32());
        lo + (hi - lo) * t
    }

    /// Uniform unit vector, f32.
    pub fn direction(&mut self) -> Vec3 {
        self.direction_f64().as_vec3().normalize()
    }
}
