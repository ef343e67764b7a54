//! A small, self-contained random number generator: xoshiro256++ seeded through SplitMix64.
//!
//! Written here (the crate has no `rand` dependency) so that the reference's random streams are fully
//! determined by this file: a stream is keyed by `(seed, stream, channel, tag)` and nothing else.

/// SplitMix64 step: used to expand keys into xoshiro state and to mix keys together.
#[inline]
pub fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// xoshiro256++ (Blackman & Vigna). Period 2^256 − 1; streams from distinct keys are decorrelated by
/// the SplitMix64 seeding.
#[derive(Clone, Debug)]
pub struct Rng {
    s: [u64; 4],
}

impl Rng {
    /// A generator for the stream identified by `(seed, stream, channel, tag)`.
    pub fn new(seed: u64, stream: u64, channel: u64, tag: u64) -> Rng {
        let mut k = seed;
        let mut mix = splitmix64(&mut k);
        for part in [stream, channel, tag] {
            let mut m = mix ^ part.wrapping_mul(0xD1B5_4A32_D192_ED03);
            mix = splitmix64(&mut m);
        }
        let mut sm = mix;
        let mut s = [0u64; 4];
        for v in s.iter_mut() {
            *v = splitmix64(&mut sm);
        }
        if s == [0; 4] {
            s[0] = 1; // the all-zero state is the one fixed point
        }
        Rng { s }
    }

    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.s;
        let result = s[0].wrapping_add(s[3]).rotate_left(23).wrapping_add(s[0]);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        result
    }

    /// Uniform in [0, 1), 53 random bits.
    #[inline]
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in (0, 1]: safe to take the logarithm of.
    #[inline]
    pub fn uniform_open0(&mut self) -> f64 {
        ((self.next_u64() >> 11) + 1) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// An exponential variate of rate 1.
    #[inline]
    pub fn exponential(&mut self) -> f64 {
        -self.uniform_open0().ln()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_key_same_stream_and_keys_differ() {
        let mut a = Rng::new(7, 3, 1, 0);
        let mut b = Rng::new(7, 3, 1, 0);
        let va: Vec<u64> = (0..64).map(|_| a.next_u64()).collect();
        let vb: Vec<u64> = (0..64).map(|_| b.next_u64()).collect();
        assert_eq!(va, vb);
        for (s, st, c) in [(8, 3, 1), (7, 4, 1), (7, 3, 2)] {
            let mut o = Rng::new(s, st, c, 0);
            let vo: Vec<u64> = (0..64).map(|_| o.next_u64()).collect();
            assert_ne!(va, vo);
        }
    }

    #[test]
    fn uniform_ranges_and_mean() {
        let mut r = Rng::new(1, 2, 3, 4);
        let n = 200_000;
        let mut sum = 0.0;
        for _ in 0..n {
            let u = r.uniform();
            assert!((0.0..1.0).contains(&u));
            let v = r.uniform_open0();
            assert!(v > 0.0 && v <= 1.0);
            sum += u;
        }
        let mean = sum / n as f64;
        // σ of the mean: sqrt(1/12 / n) ≈ 6.5e-4.
        assert!((mean - 0.5).abs() < 4.0 * (1.0f64 / 12.0 / n as f64).sqrt(), "mean {mean}");
    }
}
