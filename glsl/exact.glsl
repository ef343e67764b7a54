// exact.glsl: f32 arithmetic the host's to the bit, whatever the device does with denormals.
//
// The end-of-order passes of the device-resident mode (commit.comp, block_sums.comp,
// remaining.comp, to_half.comp) must give bitwise what the host's passes give in the streamed mode
// (src/solver/passes.rs): f32 sums `t + l`, f64 sums of |l| in a fixed order, f16 rounding of the
// source. A device may flush f32 denormals to zero in arithmetic (llvmpipe does, and Vulkan lets
// it), the host never does. So f32 values are read from their bits into f64 exactly (every f32,
// denormals included, is a normal f64), added there, and rounded back to f32 (or f16) from the
// bits, to nearest even: the sum of two f32 values is exact in f64 unless one is below 2^-28 of
// the other, and then it rounds to the larger as the f32 sum does. f64 additions and
// multiplications are correctly rounded on every Vulkan device, and their values here are never
// f64 denormals.
#extension GL_ARB_gpu_shader_int64 : require

// The f32 with bits `b`, exactly, as a double.
double f64_of_f32_bits(uint b) {
    uint64_t sign = uint64_t(b >> 31) << 63;
    uint e = (b >> 23) & 0xffu;
    uint m = b & 0x7fffffu;
    uint64_t bits;
    if (e == 0xffu) {
        bits = m == 0u ? 0x7ff0000000000000UL : 0x7ff8000000000000UL | (uint64_t(m) << 29);
    } else if (e != 0u) {
        // Rebias 127 → 1023.
        bits = (uint64_t(e + 896u) << 52) | (uint64_t(m) << 29);
    } else if (m == 0u) {
        bits = 0UL;
    } else {
        // A denormal m·2^-149 = 1.f·2^(top − 149).
        int top = findMSB(m);
        bits = (uint64_t(top - 149 + 1023) << 52) | ((uint64_t(m) << uint(52 - top)) & 0xfffffffffffffUL);
    }
    return uint64BitsToDouble(bits | sign);
}

// `d` rounded to the nearest f32 (ties to even), denormals included, as bits.
uint f32_bits_of(double d) {
    uint64_t b = doubleBitsToUint64(d);
    uint sign = uint(b >> 63) << 31;
    int e = int((b >> 52) & 0x7ffUL);
    uint64_t m = b & 0xfffffffffffffUL;
    if (e == 0x7ff) {
        return sign | 0x7f800000u | (m != 0UL ? 0x400000u | uint(m >> 29) : 0u);
    }
    if (e == 0) {
        return sign;
    }
    int e32 = e - 1023 + 127;
    if (e32 >= 255) {
        return sign | 0x7f800000u;
    }
    uint64_t sig = m | (1UL << 52);
    int drop = 29 + (e32 >= 1 ? 0 : 1 - e32);
    if (drop > 54) {
        return sign;
    }
    uint64_t kept = sig >> uint(drop);
    uint64_t rest = sig & ((1UL << uint(drop)) - 1UL);
    uint64_t half_way = 1UL << uint(drop - 1);
    if (rest > half_way || (rest == half_way && (kept & 1UL) != 0UL)) {
        kept += 1UL;
    }
    if (e32 < 1) {
        // A denormal; 2^23 after rounding up is the smallest normal, whose bits these are.
        return sign | uint(kept);
    }
    // kept ∈ [2^23, 2^24]: rounding up to 2^24 carries into the exponent.
    uint bits = (uint(e32) << 23) + uint(kept) - 0x800000u;
    return sign | min(bits, 0x7f800000u);
}

// The f32 sum a + b of two f32 bit patterns, as the host computes it (IEEE, to nearest even).
uint f32_add_bits(uint a, uint b) {
    precise double s = f64_of_f32_bits(a) + f64_of_f32_bits(b);
    return f32_bits_of(s);
}

// The f32 with bits `b` times 2^s, rounded to the nearest f16 (ties to even), as the host's copy
// workers round the previous source (`half::f16::from_f32(v * 2^s)`: v·2^s is exact in f32 unless
// it falls among the f32 denormals, which round to an f16 zero either way).
uint f16_bits_scaled(uint b, int s) {
    uint sign = (b >> 16) & 0x8000u;
    uint e = (b >> 23) & 0xffu;
    uint m = b & 0x7fffffu;
    if (e == 0xffu) {
        return sign | 0x7c00u | (m != 0u ? 0x200u | (m >> 13) : 0u);
    }
    if (e == 0u && m == 0u) {
        return sign;
    }
    // The value is sig·2^p, in [2^l, 2^(l+1)).
    uint sig = e != 0u ? m | 0x800000u : m;
    int p = (e != 0u ? int(e) : 1) - 150 + s;
    int l = findMSB(sig) + p;
    if (l >= 16) {
        return sign | 0x7c00u;
    }
    // The f16 spacing there is 2^q: 2^(l−10) among the normals, 2^-24 among the denormals.
    int q = max(l - 10, -24);
    int drop = q - p;
    uint kept;
    if (drop <= 0) {
        kept = sig << uint(-drop);
    } else if (drop > 25) {
        kept = 0u;
    } else {
        kept = sig >> uint(drop);
        uint rest = sig & ((1u << uint(drop)) - 1u);
        uint half_way = 1u << uint(drop - 1);
        if (rest > half_way || (rest == half_way && (kept & 1u) != 0u)) {
            kept += 1u;
        }
    }
    if (q == -24) {
        // A denormal (1024 after rounding up: the smallest normal, whose bits these are).
        return sign | kept;
    }
    // kept ∈ [1024, 2048]: rounding up to 2048 carries into the exponent (to infinity past 15).
    uint bits = (uint(l + 15) << 10) + kept - 1024u;
    return sign | min(bits, 0x7c00u);
}
