// The SIMD body of the tracker point objective (tracker.cpp), written once for a block of 8 poses
// with the Pack type of objective_kernel_body.inl and included after it, in each instruction set's
// namespace (objective_kernel.cpp): every variant performs the same IEEE operations in the same
// order on each lane, so the variants that fuse multiply-adds (AVX2, AVX-512) give the same bits, the
// SSE2 baseline (fma as a multiply and an add) the same to rounding.
// (No include guard: included several times on purpose.)

template <int KK>
IWR_FORCE_INLINE PackN<KK> operator/(const PackN<KK>& a, const PackN<KK>& b) {
    PackN<KK> p;
    for (int k = 0; k < KK; ++k) p.v[k] = r_div(a.v[k], b.v[k]);
    return p;
}

IWR_FORCE_INLINE Pack zero_pack() { return splat(0.0); }

// A mask of the lanes of KK registers (Mask: a block's 8); false for NaN in the comparisons.
template <int KK>
struct MaskN {
    M v[KK];
};
using Mask = MaskN<K>;
template <int KK>
IWR_FORCE_INLINE MaskN<KK> operator<=(const PackN<KK>& a, const PackN<KK>& b) {
    MaskN<KK> m;
    for (int k = 0; k < KK; ++k) m.v[k] = m_le(a.v[k], b.v[k]);
    return m;
}
template <int KK>
IWR_FORCE_INLINE MaskN<KK> operator<(const PackN<KK>& a, const PackN<KK>& b) {
    MaskN<KK> m;
    for (int k = 0; k < KK; ++k) m.v[k] = m_lt(a.v[k], b.v[k]);
    return m;
}
template <int KK>
IWR_FORCE_INLINE MaskN<KK> operator&(const MaskN<KK>& a, const MaskN<KK>& b) {
    MaskN<KK> m;
    for (int k = 0; k < KK; ++k) m.v[k] = m_and(a.v[k], b.v[k]);
    return m;
}
template <int KK>
IWR_FORCE_INLINE MaskN<KK> operator|(const MaskN<KK>& a, const MaskN<KK>& b) {
    MaskN<KK> m;
    for (int k = 0; k < KK; ++k) m.v[k] = m_or(a.v[k], b.v[k]);
    return m;
}
template <int KK>
IWR_FORCE_INLINE MaskN<KK> and_not(const MaskN<KK>& a, const MaskN<KK>& b) {  // a and not b
    MaskN<KK> m;
    for (int k = 0; k < KK; ++k) m.v[k] = m_andnot(a.v[k], b.v[k]);
    return m;
}
template <int KK = K>
IWR_FORCE_INLINE MaskN<KK> all_lanes(bool on) {
    MaskN<KK> m;
    for (int k = 0; k < KK; ++k) m.v[k] = m_all(on);
    return m;
}
template <int KK>
IWR_FORCE_INLINE int bits(const MaskN<KK>& m) {  // bit l: lane l
    int b = 0;
    for (int k = 0; k < KK; ++k) b |= m_bits(m.v[k]) << (k * kSubLanes);
    return b;
}
template <int KK>
IWR_FORCE_INLINE PackN<KK> select(const MaskN<KK>& m, const PackN<KK>& a, const PackN<KK>& b) {
    PackN<KK> p;
    for (int k = 0; k < KK; ++k) p.v[k] = m_select(m.v[k], a.v[k], b.v[k]);
    return p;
}

// J_ref^-1 v for the lanes of NB blocks (inv[b]: block b's 6 x 6 matrix row by row; v: 6 values,
// each 8 NB lanes, block after block), one register's lanes at a time, v in registers: each row's
// product reads only the matrix (with AVX2 the whole block's v would take 12 of the 16 registers,
// and reading it from memory made the product wait on loads: 4-5 % of the AVX2 tracker objective).
// With AVX-512 (K = 1: one register a block) v is read from memory in every row, as before (1.5 %
// faster than in registers). set(r, s[m].v[r], row m's product) stores the result of register r
// (block r / K, its register r % K). The same operations on each lane either way. Each row's
// product in two chains of three (n = 0..2 and 3..5) added at the end: a chain of six fused
// multiply-adds made each product wait 23 cycles on its last.
template <int NB, class Set>
IWR_FORCE_INLINE void inverse_times(const double* const (&inv)[NB], const double* v,
                                    PackN<K * NB> (&s)[6], Set set) {
    constexpr int B = kBlock, W = kSubLanes, L = kBlock * NB;
    for (int b = 0; b < NB; ++b) {
        const double* ib = reread(inv[b]);
        for (int h = 0; h < K; ++h) {
            const int r = b * K + h;
            R vh[6];
            for (int n = 0; n < 6; ++n) vh[n] = r_load(v + n * L + r * W);
            auto vn = [&](int n) IWR_FORCE_INLINE_LAMBDA {
                return K == 1 ? r_load(v + n * L + r * W) : vh[n];
            };
            for (int m = 0; m < 6; ++m) {
                const double* row = ib + 6 * m * B + h * W;
                R acc = r_mul(r_load(row), vn(0)), acc2 = r_mul(r_load(row + 3 * B), vn(3));
                for (int n = 1; n < 3; ++n) {
                    acc = r_fma(r_load(row + n * B), vn(n), acc);
                    acc2 = r_fma(r_load(row + (n + 3) * B), vn(n + 3), acc2);
                }
                set(r, s[m].v[r], r_add(acc, acc2));
            }
        }
    }
}

// The forward kinematics of the block's 8 poses, one per lane, from the reference solves stored in
// the block (blk: the inverse leg Jacobian J_ref^-1 36, P 3, R 9, leg readings 6, 1 / (2 L'_j) 6,
// each 8 lanes). Each lane computes exactly what it would alone: the decisions are per lane, and a
// lane that has converged (or must fall back) gets a zero step, which leaves its pose unchanged
// (bit for bit, but for the sign of an exact zero).
//
// The unknowns are the platform position P in {4} and the six platform joints d_j = R b_j relative
// to it, rotated together (d_j <- C(omega) d_j, C Cayley's rotation: orthogonal to rounding,
// Exp(omega) to second order; its factor 2 / (1 + |omega / 2|^2) by a series where that is within an
// ulp of it, below); R itself is not formed: the output is F = R B = [d_i, d_k, d_i x d_k] with
// B = [b_i, b_k, b_i x b_k] for the pair (i, k) of platform joints that spans the platform best,
// and the points take R r = F (B^-1 r) (B^-1 r per point once per vector: 27 multiply-adds and 9
// broadcasts a pose fewer than forming R).
// Leg j's residual is f_j = (|v_j|^2 - L_j^2) / (2 L'_j), v_j = P + d_j - a_j, L'_j the leg's
// length at the reference parameters (within a millimetre of L_j): the root of |v_j| - L_j, nearly
// the same derivative there (v_j . dv_j / L'_j), no square root, no division. Converged when
// |f|_2 <= tol. A step is the chord step s0 = -J_ref^-1 f; every step after the first, in a lane
// whose |f|_2 is above 300 tol, takes one iteration of iterative refinement towards Newton's
// step: s = s0 - J_ref^-1 (J s0 + f) with the
// current Jacobian J, whose row j applied to (dP, omega) is v_j . (dP + omega x d_j) / L'_j (exact
// for f). From the reference, in DE's search box, the chord step shrinks |f| about 400-fold and the
// refined step about 1e5-fold (from 3e-3 mm to 1e-8 mm): four residual evaluations where the chord
// alone needs five or six.
// status per lane: 0 solved, 1 not contracting (the caller's damped Newton fallback), 2 a leg
// length <= 0. Out: P (3 x 8) and F (9 x 8, row-major) of each lane.
// NB blocks at once (blk[b]; out: block b's P at pout + 24 b, F at fout + 72 b, status at
// status + 8 b): each lane computes exactly what it would in a block of its own (the same
// operations; a lane that has converged takes zero steps until the last of the NB blocks' lanes
// has), more independent chains in flight where the register file holds them.
// Lanes: the hexapod's constants (a, b, l0) per lane from lc[b] (LaneConsts: block b's lanes
// may belong to different parameter vectors), else tc's in every lane; each lane computes the same
// either way.
template <int NB, bool Lanes = false>
IWR_FORCE_INLINE void chord_blocks(const double* const (&blk)[NB], const TrackerConsts& tc,
                                   double* pout, double* fout, int* status,
                                   const LaneConsts* lc = nullptr) {
    constexpr int B = kBlock, W = kSubLanes, L = kBlock * NB, KN = K * NB;
    using P = PackN<KN>;
    using MK = MaskN<KN>;
    // Quantity q of every block (register b K + h: block b's register h).
    auto in = [&](int q) IWR_FORCE_INLINE_LAMBDA {
        P x;
        for (int b = 0; b < NB; ++b)
            for (int h = 0; h < K; ++h) x.v[b * K + h] = r_load(blk[b] + q * B + h * W);
        return x;
    };
    auto out = [&](double* base, int per_block, int q, const P& x) IWR_FORCE_INLINE_LAMBDA {
        for (int b = 0; b < NB; ++b)
            for (int h = 0; h < K; ++h) r_store(base + b * per_block + q * B + h * W, x.v[b * K + h]);
    };
    auto sp = [](double x) IWR_FORCE_INLINE_LAMBDA { return bcast<P>(x); };
    auto ldl = [](const double* ptr) IWR_FORCE_INLINE_LAMBDA { return ld<P>(ptr); };
    // The hexapod's constant q of LaneConsts (s: its value in tc).
    auto hex = [&](int q, double s) IWR_FORCE_INLINE_LAMBDA {
        if constexpr (Lanes) {
            P x;
            for (int b = 0; b < NB; ++b)
                for (int h = 0; h < K; ++h) x.v[b * K + h] = r_load(lc[b].v + q * B + h * W);
            return x;
        } else {
            (void)q;
            return sp(s);
        }
    };
    auto ha = [&](int j, int c) IWR_FORCE_INLINE_LAMBDA {
        return hex(LaneConsts::kA + 3 * j + c, tc.ec.a[j][c]);
    };
    auto hb = [&](int j, int c) IWR_FORCE_INLINE_LAMBDA {
        return hex(LaneConsts::kB + 3 * j + c, tc.ec.b[j][c]);
    };
    // Per-lane constants, residuals and the platform joints live in memory (loads are cheap and
    // the registers few), the position in registers. In memory the NB blocks' lanes of a
    // quantity follow each other (L doubles).
    alignas(64) double d[18 * L], nl2[6 * L], f[6 * L], g[6 * L];
    // 1 / (2 L_j) at the reference: quantity 54 + j of each block.
    const double* inv[NB];
    for (int b = 0; b < NB; ++b) inv[b] = blk[b];
    P p[3];
    for (int c = 0; c < 3; ++c) p[c] = in(36 + c);
    // Pairs (AVX-512) move the joints in the residuals' pass over them: d_j = R_ref b_j in the
    // first, and in each later one the previous step's rotation (its C in cm), where a block alone
    // has passes of their own for them (AVX2 ran 2.5 % slower joined; BENCHMARKS.md, eighteenth
    // round). The same operations on each lane either way.
    constexpr bool kJoined = NB == 2;
    alignas(64) double cm[9 * L];
    // A row of a 3 x 3 matrix times a vector, as every joint is moved (R_ref b_j, C d_j).
    auto row_times = [](const P& a0, const P& a1, const P& a2, const P& x0, const P& x1,
                        const P& x2) IWR_FORCE_INLINE_LAMBDA {
        return fma(a2, x2, fma(a1, x1, a0 * x0));
    };
    // Row c of R_ref times b_j.
    auto reference_row = [&](int c, const P& b0, const P& b1, const P& b2) IWR_FORCE_INLINE_LAMBDA {
        const int rr = 39 + 3 * c;
        return row_times(in(rr), in(rr + 1), in(rr + 2), b0, b1, b2);
    };
    for (int j = 0; j < 6 && !kJoined; ++j) {
        const P b0 = hb(j, 0), b1 = hb(j, 1), b2 = hb(j, 2);
        for (int c = 0; c < 3; ++c) store(d + (3 * j + c) * L, reference_row(c, b0, b1, b2));
    }
    MK act = all_lanes<KN>(true);
    for (int j = 0; j < 6; ++j) {
        const P len = in(48 + j) + hex(LaneConsts::kL0 + j, tc.ec.l0[j]);
        store(nl2 + j * L, sp(0.0) - len * len);
        act = act & (sp(0.0) < len);  // false for a length <= 0 (or NaN)
    }
    const MK short_leg = and_not(all_lanes<KN>(true), act);
    MK stalled_lanes = all_lanes<KN>(false);
    // Refined steps while a lane's |f| is above 300 tol: the plain chord, some 400-fold a step,
    // might not reach tol in one more.
    const P tol2 = sp(tc.tol * tc.tol), quarter = sp(0.25), zero = sp(0.0);
    const P refine_above = sp(9e4 * tc.tol * tc.tol);
    P prev = sp(std::numeric_limits<double>::infinity());
    for (int it = 0;; ++it) {
        P err = zero;  // |f|^2, NaN when a residual is: not converged
#pragma GCC unroll 1
        for (int j = 0; j < 6; ++j) {
            double* dj = d + 3 * j * L;
            P dx, dy, dz;
            if (kJoined && it == 0) {  // R_ref b_j
                const P b0 = hb(j, 0), b1 = hb(j, 1), b2 = hb(j, 2);
                dx = reference_row(0, b0, b1, b2);
                dy = reference_row(1, b0, b1, b2);
                dz = reference_row(2, b0, b1, b2);
            } else {
                dx = ldl(dj), dy = ldl(dj + L), dz = ldl(dj + 2 * L);
            }
            if (kJoined && it > 0) {  // C d_j
                const P d0 = dx, d1 = dy, d2 = dz;
                auto c = [&](int e) IWR_FORCE_INLINE_LAMBDA { return ldl(cm + e * L); };
                dx = row_times(c(0), c(1), c(2), d0, d1, d2);
                dy = row_times(c(3), c(4), c(5), d0, d1, d2);
                dz = row_times(c(6), c(7), c(8), d0, d1, d2);
            }
            if (kJoined) {
                store(dj, dx);
                store(dj + L, dy);
                store(dj + 2 * L, dz);
            }
            const P vx = (p[0] - ha(j, 0)) + dx;
            const P vy = (p[1] - ha(j, 1)) + dy;
            const P vz = (p[2] - ha(j, 2)) + dz;
            const P fj = fma(vz, vz, fma(vy, vy, fma(vx, vx, ldl(nl2 + j * L)))) * in(54 + j);
            store(f + j * L, fj);
            err = fma(fj, fj, err);
        }
        // Per lane: converged, not contracting (the damped Newton fallback), or on to a step.
        const MK live = and_not(act, err <= tol2);
        const MK stalled = it == tc.max_iter ? live : and_not(live, err < quarter * prev);
        stalled_lanes = stalled_lanes | stalled;
        act = and_not(live, stalled);
        if (bits(act) == 0) break;
        prev = select(act, err, prev);
        P s[6];
        inverse_times<NB>(inv, f, s, [&](int r, R& sm, R acc) IWR_FORCE_INLINE_LAMBDA {
            sm = m_keep(act.v[r], r_sub(zero.v[r], acc));
        });
        const MK refine = act & (refine_above < err);
        if (it > 0 && bits(refine) != 0) {
            // g = J s0 + f, then s = s0 - J_ref^-1 g in the lanes that refine (the others keep s0).
#pragma GCC unroll 1
            for (int j = 0; j < 6; ++j) {
                const double* dj = d + 3 * j * L;
                const P dx = ldl(dj), dy = ldl(dj + L), dz = ldl(dj + 2 * L);
                const P ex = s[0] + fms(s[4], dz, s[5] * dy);
                const P ey = s[1] + fms(s[5], dx, s[3] * dz);
                const P ez = s[2] + fms(s[3], dy, s[4] * dx);
                const P dot = fma((p[2] - ha(j, 2)) + dz, ez,
                                  fma((p[1] - ha(j, 1)) + dy, ey,
                                      ((p[0] - ha(j, 0)) + dx) * ex));
                const P h = in(54 + j);
                store(g + j * L, fma(h + h, dot, ldl(f + j * L)));
            }
            inverse_times<NB>(inv, g, s, [&](int r, R& sm, R acc) IWR_FORCE_INLINE_LAMBDA {
                sm = r_sub(sm, m_keep(refine.v[r], acc));
            });
        }
        for (int c = 0; c < 3; ++c) p[c] = p[c] + s[c];
        const P half = sp(0.5), one = sp(1.0);
        const P hx = half * s[3], hy = half * s[4], hz = half * s[5];
        const P xx = hx * hx, yy = hy * hy, zz = hz * hz, xy = hx * hy, xz = hx * hz, yz = hy * hz;
        // k = 2 / (1 + |h|^2); where |h|^2 < 1e-4 (every step within DE's search box on the
        // benchmarks' tracker data: 1e-7 to 1e-5 at the first, below 1e-10 after) its series
        // 2 (1 - |h|^2 + |h|^4 - |h|^6), without the division: k (1 + |h|^2) / 2 = 1 - |h|^8, and
        // C^T C - I = 2 (1 - k (1 + |h|^2) / 2) k [h]^2 is then at most 4 |h|^10 < 4e-20 in norm,
        // far below rounding. A lane's choice rests on its own |h|^2: its value is the same
        // whatever its neighbours; the division is skipped where no lane needs it.
        const P h2 = xx + yy + zz;
        const MK small = h2 < sp(1e-4);
        const P k_series = fma(h2, fma(h2, fma(sp(-2.0), h2, sp(2.0)), sp(-2.0)), sp(2.0));
        const P k = bits(small) == (1 << L) - 1 ? k_series
                                                : select(small, k_series, sp(2.0) / (one + h2));
        const P c00 = fma(k, xx - h2, one), c01 = k * (xy - hz), c02 = k * (xz + hy);
        const P c10 = k * (xy + hz), c11 = fma(k, yy - h2, one), c12 = k * (yz - hx);
        const P c20 = k * (xz - hy), c21 = k * (yz + hx), c22 = fma(k, zz - h2, one);
        if (kJoined) {  // the joints turn in the next residuals' pass
            const P cc[9] = {c00, c01, c02, c10, c11, c12, c20, c21, c22};
            for (int e = 0; e < 9; ++e) store(cm + e * L, cc[e]);
            continue;
        }
#pragma GCC unroll 1
        for (int j = 0; j < 6; ++j) {
            double* dj = d + 3 * j * L;
            const P d0 = ldl(dj), d1 = ldl(dj + L), d2 = ldl(dj + 2 * L);
            store(dj, row_times(c00, c01, c02, d0, d1, d2));
            store(dj + L, row_times(c10, c11, c12, d0, d1, d2));
            store(dj + 2 * L, row_times(c20, c21, c22, d0, d1, d2));
        }
    }
    for (int c = 0; c < 3; ++c) out(pout, 3 * B, c, p[c]);
    {
        const double* di = d + 3 * tc.pair[0] * L;
        const double* dk = d + 3 * tc.pair[1] * L;
        const P ix = ldl(di), iy = ldl(di + L), iz = ldl(di + 2 * L);
        const P kx = ldl(dk), ky = ldl(dk + L), kz = ldl(dk + 2 * L);
        const P fm[9] = {ix, kx, fms(iy, kz, iz * ky), iy, ky, fms(iz, kx, ix * kz),
                         iz, kz, fms(ix, ky, iy * kx)};
        for (int e = 0; e < 9; ++e) out(fout, 9 * B, e, fm[e]);
    }
    const int two = bits(short_leg), one = bits(stalled_lanes);
    for (int l = 0; l < L; ++l) status[l] = (two >> l & 1) ? 2 : (one >> l & 1) ? 1 : 0;
}

void tracker_chord(const double* blk, const TrackerConsts& tc, double* pout, double* fout,
                   int* status) {
    const double* const b[1] = {blk};
    chord_blocks<1>(b, tc, pout, fout, status);
}

// Two blocks at once (blk1 after blk0: out as tracker_chord's, block 1's after block 0's), the
// same values as tracker_chord on each. chord_pair: it where the variant runs it (kChordPair: where
// it is faster), else null and the caller runs tracker_chord block by block (as one call deeper on
// the stack, the SSE2 chord ran 3-4 % slower).
[[maybe_unused]] void tracker_chord2(const double* blk0, const double* blk1, const TrackerConsts& tc,
                                    double* pout, double* fout, int* status) {
    const double* const b[2] = {blk0, blk1};
    chord_blocks<2>(b, tc, pout, fout, status);
}
constexpr auto chord_pair = kChordPair ? &tracker_chord2 : nullptr;

// nb (1 or 2) blocks with per-lane constants (lc[b] for blk[b]): out as tracker_chord2's. Two at
// once where the variant runs pairs (kChordPair), else one after the other.
void tracker_chord_lanes(const double* const* blk, const LaneConsts* lc, int nb,
                         const TrackerConsts& tc, double* pout, double* fout, int* status) {
    if (kChordPair && nb == 2) {
        const double* const b[2] = {blk[0], blk[1]};
        chord_blocks<2, true>(b, tc, pout, fout, status, lc);
        return;
    }
    for (int i = 0; i < nb; ++i) {
        const double* const b[1] = {blk[i]};
        chord_blocks<1, true>(b, tc, pout + 3 * kBlock * i, fout + 9 * kBlock * i,
                              status + kBlock * i, lc + i);
    }
}

// The transform T_T4 = T_T0 0T4 of the block's poses (the registration is folded into the carriage's
// constants; tout: rotation row-major 0..8, position 9..11, each 8 lanes), the points in {T}
// (3 K x 8: yout) from the platform poses (P, F = R B) in {4}, y = T_T4 (P + F c_i) with
// c_i = B^-1 r_i (TrackerConsts::refl), and each
// lane's sum of squared residuals added to acc (8). meas: the measured points (3 K x 8, 0 where not
// seen); seen (K x 8) and bad (8): 1 or 0; plain: every point of the block seen and no lane bad
// (the caller knows; bad is written lane by lane, and a vector load of it must wait for those
// stores to reach the cache). A point not seen
// contributes 0, a lane whose forward kinematics failed kFailedResidual on every seen
// coordinate, whatever its prediction. tout, yout may be null (the cost alone).
// Whitened (MW >= 0; wh: the block's whitening, TrackerConsts::wh_rows): the lane's m = 3 K
// residuals v are whitened in the block, s_i = sum_{j <= i} W_ij v_j over the rows that are not
// zero at every pose, and s_i^2 summed. MW > 0: m = MW, the rows R0..MW-1 stored, v in registers;
// MW = 0: any m and rows, v through vbuf (m x 8). NPT > 0: the unwhitened chain's number of points
// as a constant (its loop unrolled), else tc.n_points. OUT false: the cost alone (tout and yout
// not written, not tested in the loop).
template <int NP, int NR, int MW, int R0 = 0, int NPT = 0, bool OUT = true>
IWR_FORCE_INLINE void points_chain(const double* blk, const TrackerConsts& tc, const double* pin,
                                   const double* fin, const double* meas, const double* seen,
                                   const double* bad, bool plain, const double* wh,
                                   double* vbuf, double* tout, double* yout, double* acc) {
    constexpr int B = kBlock, W = kSubLanes;
    // Lanes chosen by masks, not by multiplying with 0 or 1: a prediction that overflows to inf
    // (an absurd but finite x) must give the penalty in a failed lane and 0 for a point not seen,
    // as residuals() does, not inf * 0 = NaN.
    // Every point seen and every pose solved (the rule, plain): the residual is y - measured.
    const R penalty = r_splat(tc.failed_residual), zero = r_splat(0.0);
    const int n_points = MW > 0 ? MW / 3 : NPT > 0 ? NPT : tc.n_points;
    // The block as K passes of one register each, as the leg kernel's (objective_kernel_body.inl):
    // 0T4, P and F are 24 values, more than the 16 registers of SSE2 and AVX2 hold when each is
    // K registers. Each lane sees the same operations in the same order.
    for (int h = 0; h < K; ++h) {
        const int o = h * W;  // the pass's first lane
        Sub t[12];
        carriage<NP, NR>(tc.pd, tc.ec, blk + o, t);
        if (OUT && tout)
            for (int e = 0; e < 12; ++e) r_store(tout + e * B + o, t[e].v[0]);
        // P and F read where they are used (the chord's output, in L1): held in arrays of
        // registers, GCC copied them to the stack first.
        auto p = [&](int c) IWR_FORCE_INLINE_LAMBDA { return r_load(pin + c * B + o); };
        auto f = [&](int e) IWR_FORCE_INLINE_LAMBDA { return r_load(fin + e * B + o); };
        const M failed = m_lt(zero, r_load(bad + o));
        R total = r_load(acc + o);
        R v[MW > 0 ? MW : 1];
        for (int i = 0; i < n_points; ++i) {
            const R x0 = r_splat(tc.refl[3 * i]), x1 = r_splat(tc.refl[3 * i + 1]),
                    x2 = r_splat(tc.refl[3 * i + 2]);
            const R z0 = r_fma(f(2), x2, r_fma(f(1), x1, r_fma(f(0), x0, p(0))));
            const R z1 = r_fma(f(5), x2, r_fma(f(4), x1, r_fma(f(3), x0, p(1))));
            const R z2 = r_fma(f(8), x2, r_fma(f(7), x1, r_fma(f(6), x0, p(2))));
            const M on = plain ? m_all(true) : m_lt(zero, r_load(seen + i * B + o));
            for (int c = 0; c < 3; ++c) {
                const R y = r_fma(t[3 * c + 2].v[0], z2,
                                  r_fma(t[3 * c + 1].v[0], z1, r_fma(t[3 * c].v[0], z0, t[9 + c].v[0])));
                if (OUT && yout) r_store(yout + (3 * i + c) * B + o, y);
                const R e = r_sub(y, r_load(meas + (3 * i + c) * B + o));
                const R vc = plain ? e : m_select(on, m_select(failed, penalty, e), zero);
                if constexpr (MW < 0)
                    total = r_fma(vc, vc, total);
                else if constexpr (MW > 0)
                    v[3 * i + c] = vc;
                else
                    r_store(vbuf + (3 * i + c) * B + o, vc);
            }
        }
        if constexpr (MW >= 0) {
            // The whitening's stored rows, each j = 0..i, 8 lanes an entry, row after row. Each row
            // in two chains (even and odd j) and the squares of the rows of even and odd i in two
            // sums: the FMA's latency, not its throughput, held a row of 9 terms back.
            const double* w = wh + o;
            R tw[2] = {total, zero};  // rows of even i, of odd i
            auto row = [&](int i, auto vj) IWR_FORCE_INLINE_LAMBDA {
                R se = r_mul(r_load(w), vj(0)), so = zero;
                if (i >= 1) so = r_mul(r_load(w + B), vj(1));
#pragma GCC unroll 16
                for (int j = 2; j <= i; ++j) {
                    R& sj = j % 2 == 0 ? se : so;
                    sj = r_fma(r_load(w + j * B), vj(j), sj);
                }
                w += (i + 1) * B;
                const R sum = r_add(se, so);
                R& t = tw[i % 2];
                t = r_fma(sum, sum, t);
            };
            if constexpr (MW > 0) {  // rows R0..MW-1 stored (no runtime test: no spills)
#pragma GCC unroll 16
                for (int i = R0; i < MW; ++i)
                    row(i, [&](int j) IWR_FORCE_INLINE_LAMBDA { return v[j]; });
            } else {
                auto vj = [&](int j) IWR_FORCE_INLINE_LAMBDA { return r_load(vbuf + j * B + o); };
                for (int i = 0; i < 3 * n_points; ++i)
                    if (tc.wh_rows[i]) row(i, vj);
            }
            total = r_add(tw[0], tw[1]);
        }
        r_store(acc + o, total);
    }
}

// The whitened objective's chains, each a function of its own: inlined beside the unweighted ones
// they made GCC compile tracker_points differently and the unweighted AVX-512 objective 4-6 %
// slower.
template <int NP, int NR, int MW, int R0 = 0>
IWR_NOINLINE void points_whitened(const double* blk, const TrackerConsts& tc, const double* pin,
                                  const double* fin, const double* meas, const double* seen,
                                  const double* bad, bool plain, const double* wh, double* vbuf,
                                  double* tout, double* yout, double* acc) {
    if (MW > 0 && !tout && !yout)  // the cost alone: 0.5-1 % of the AVX-512 weighted objective
        points_chain<NP, NR, MW, R0, 0, false>(blk, tc, pin, fin, meas, seen, bad, plain, wh,
                                               vbuf, nullptr, nullptr, acc);
    else
        points_chain<NP, NR, MW, R0>(blk, tc, pin, fin, meas, seen, bad, plain, wh, vbuf, tout,
                                     yout, acc);
}

void tracker_points(const double* blk, const TrackerConsts& tc, const double* pin,
                    const double* fin, const double* meas, const double* seen, const double* bad,
                    bool plain, const double* wh, double* vbuf, double* tout, double* yout,
                    double* acc) {
#define IWR_POINTS(F, ...) \
    F<__VA_ARGS__>(blk, tc, pin, fin, meas, seen, bad, plain, wh, vbuf, tout, yout, acc)
    const bool iwr = chain_is(tc.pd, 2, 2);  // the IWR's carriage unrolled, as the leg kernel's
    if (wh) {
        // The whitening of 3 reflectors (m = 9, every row) and of a probe (m = 12, rows 6.. or
        // every row) with its residuals in registers; any other through memory.
        const int m = 3 * tc.n_points, r0 = tc.wh_first;
        if (iwr && m == 9 && r0 == 0)
            IWR_POINTS(points_whitened, 2, 2, 9, 0);
        else if (iwr && m == 12 && r0 == 6)
            IWR_POINTS(points_whitened, 2, 2, 12, 6);
        else if (iwr && m == 12 && r0 == 0)
            IWR_POINTS(points_whitened, 2, 2, 12, 0);
        else if (iwr)
            IWR_POINTS(points_whitened, 2, 2, 0);
        else
            IWR_POINTS(points_whitened, -1, 0, 0);
    } else if (iwr && tc.n_points == 3 && K == 1) {
        // AVX-512 only: SSE2 ran 2-8 % slower unrolled, AVX2 1.00x in bench_regression.py
        // (BENCHMARKS.md, eighteenth round).
        IWR_POINTS(points_chain, 2, 2, -1, 0, 3);
    } else if (iwr) {
        IWR_POINTS(points_chain, 2, 2, -1);
    } else {
        IWR_POINTS(points_chain, -1, 0, -1);
    }
#undef IWR_POINTS
}
