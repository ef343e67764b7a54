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

// ---- Correctly rounded f64 division from + − × alone ----
//
// The host divides in IEEE f64, correctly rounded. Vulkan promises that of f64 +, − and × (and
// nothing of / or of an unfused fma), so `div_rn` rebuilds the quotient from those: Newton steps
// on the device's own quotient with exact residuals (Dekker's product), then the rounding decided
// between the three neighbours by the sign and size of their exact residuals. `precise` keeps the
// compiler from contracting or reassociating any of it. Valid for the normal, finite operands
// and quotients the end-of-order kernels divide (anything else returns the device's a / b).

// Veltkamp's split: x = hi + lo with hi holding the top 26 bits, both exact.
void split_f64(double x, out double hi, out double lo) {
    precise double c = 134217729.0 * x;  // 2^27 + 1
    precise double h = c - (c - x);
    hi = h;
    lo = x - h;
}

// a − q·b, exactly when it is representable (q within an ulp or so of a / b: then a − q·b rounds
// to nothing, Sterbenz makes a − p exact and Dekker's e is q·b − p exactly); otherwise to within
// a rounding, which is all a Newton step needs.
double div_residual(double a, double b, double q) {
    double qh, ql, bh, bl;
    split_f64(q, qh, ql);
    split_f64(b, bh, bl);
    precise double p = q * b;
    precise double e = ((qh * bh - p) + qh * bl + ql * bh) + ql * bl;
    precise double r = (a - p) - e;
    return r;
}

// The f64 next to `q` away from zero (up = true) or toward it.
double f64_step(double q, bool up) {
    uint64_t bits = doubleBitsToUint64(q);
    return uint64BitsToDouble(up ? bits + 1UL : bits - 1UL);
}

// a / b correctly rounded to nearest even, starting from the approximation q0 (any quotient within
// a relative 2^-20 of the true one; the device's own a / b is far better than that).
double div_rn_from(double a, double b, double q0) {
    double magnitude = abs(q0);
    // Zeros, infinities, NaN, and quotients or operands near the ends of the range (where the
    // split or the residual could overflow or underflow) keep the device's quotient.
    if (!(magnitude > 1e-280 && magnitude < 1e280) || !(abs(a) > 1e-280 && abs(a) < 1e280)
        || !(abs(b) > 1e-280 && abs(b) < 1e280)) {
        return q0;
    }
    precise double q = q0;
    // Each step squares the relative error (2^-20 → 2^-40 → below an ulp).
    for (int i = 0; i < 2; i++) {
        precise double step = div_residual(a, b, q) / b;
        q = q + step;
    }
    // q is within an ulp or two of a / b: of q and its neighbours, the one with the smallest exact
    // residual is the correctly rounded quotient; on a tie (a / b half-way), the even one.
    double best = q;
    double best_r = abs(div_residual(a, b, q));
    for (int k = 0; k < 4; k++) {
        double candidate = f64_step(q, k % 2 == 0);
        if (k >= 2) {
            candidate = f64_step(candidate, k % 2 == 0);
        }
        double r = abs(div_residual(a, b, candidate));
        bool even = (doubleBitsToUint64(candidate) & 1UL) == 0UL;
        if (r < best_r || (r == best_r && even)) {
            best = candidate;
            best_r = r;
        }
    }
    return best;
}

// a / b, bitwise the host's (IEEE f64 division) on any conformant device.
double div_rn(double a, double b) {
    return div_rn_from(a, b, a / b);
}
