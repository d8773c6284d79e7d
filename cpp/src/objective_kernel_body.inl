// The body of the SIMD kernel, written once for a block of 8 lanes. objective_kernel.cpp includes it
// once per instruction set, inside that set's namespace and target region, after defining the
// register type R, the number K of registers per block (K * lanes of R == 8) and the register
// operations r_splat, r_load, r_store, r_add, r_sub, r_mul, r_sqrt, r_fma, r_fms and kFused (whether
// r_fma, r_fms round once), and the leg kernel's options kRereadConsts (the per-evaluation
// constants read again in every block: see reread) and kLegPipe (the blocks software-pipelined:
// see run; needs K == 1). Each Pack operation
// is applied register by register, so every lane sees exactly the same IEEE operations in the same
// order for any R: the variants whose r_fma fuses (AVX2, AVX-512) are bit-identical; the SSE2
// baseline's r_fma rounds twice (see objective_kernel.cpp).
// (No include guard: included several times on purpose.)

// A pack of KK registers. Pack: a block's 8 lanes (K registers). Sub: one register's lanes, what
// the leg kernel works on: it runs a block as K passes of one register each, so that its working
// set (0T4, M, w: 24 values) fits the register file of every instruction set (16 registers for
// SSE2 and AVX2); with K registers at once it spilled, and GCC moved the spilled packs through the
// stack in halves. Each lane still sees the same operations in the same order.
template <int KK>
struct PackN {
    static constexpr int n = KK;
    R v[KK];
};
using Pack = PackN<K>;
using Sub = PackN<1>;
constexpr int kSubLanes = kBlock / K;  // lanes of one register

template <class P>
IWR_FORCE_INLINE P bcast(double x) {
    P p;
    for (auto& r : p.v) r = r_splat(x);
    return p;
}
template <class P>
IWR_FORCE_INLINE P ld(const double* ptr) {  // aligned to the register's width
    P p;
    for (int k = 0; k < P::n; ++k) p.v[k] = r_load(ptr + k * kSubLanes);
    return p;
}
IWR_FORCE_INLINE Pack splat(double x) { return bcast<Pack>(x); }
IWR_FORCE_INLINE Pack load(const double* ptr) { return ld<Pack>(ptr); }  // 64-byte aligned
template <int KK>
IWR_FORCE_INLINE void store(double* ptr, const PackN<KK>& a) {  // aligned
    for (int k = 0; k < KK; ++k) r_store(ptr + k * kSubLanes, a.v[k]);
}
template <int KK>
IWR_FORCE_INLINE PackN<KK> operator+(const PackN<KK>& a, const PackN<KK>& b) {
    PackN<KK> p;
    for (int k = 0; k < KK; ++k) p.v[k] = r_add(a.v[k], b.v[k]);
    return p;
}
template <int KK>
IWR_FORCE_INLINE PackN<KK> operator-(const PackN<KK>& a, const PackN<KK>& b) {
    PackN<KK> p;
    for (int k = 0; k < KK; ++k) p.v[k] = r_sub(a.v[k], b.v[k]);
    return p;
}
template <int KK>
IWR_FORCE_INLINE PackN<KK> operator*(const PackN<KK>& a, const PackN<KK>& b) {
    PackN<KK> p;
    for (int k = 0; k < KK; ++k) p.v[k] = r_mul(a.v[k], b.v[k]);
    return p;
}
template <int KK>
IWR_FORCE_INLINE PackN<KK> sqrt(const PackN<KK>& a) {
    PackN<KK> p;
    for (int k = 0; k < KK; ++k) p.v[k] = r_sqrt(a.v[k]);
    return p;
}
// a * b + c and a * b - c: one rounding where the variant has fused multiply-adds (AVX2, AVX-512:
// r_fma, r_fms are the FMA instructions), two in the SSE2 baseline, which has none (a multiply, then
// the add). Written out rather than left to the compiler (-ffp-contract=off): the same contractions
// in the same order in the AVX2 and AVX-512 variants, so those two give the same bits, and the
// baseline differs from them at the level of rounding.
template <int KK>
IWR_FORCE_INLINE PackN<KK> fma(const PackN<KK>& a, const PackN<KK>& b, const PackN<KK>& c) {
    PackN<KK> p;
    for (int k = 0; k < KK; ++k) p.v[k] = r_fma(a.v[k], b.v[k], c.v[k]);
    return p;
}
template <int KK>
IWR_FORCE_INLINE PackN<KK> fms(const PackN<KK>& a, const PackN<KK>& b, const PackN<KK>& c) {
    PackN<KK> p;
    for (int k = 0; k < KK; ++k) p.v[k] = r_fms(a.v[k], b.v[k], c.v[k]);
    return p;
}
// Where the shortest fused form is not the baseline's earlier order of operations, the two forms
// (kFused: the variant's r_fma fuses): the baseline keeps the bits and the speed it had before the
// FMA variants (a fused chain's order, unfused, made its leg objective 3-5 % slower).
// t + (a x + b y):
template <class P>
IWR_FORCE_INLINE P plus_two_products(const P& t, const P& a, const P& x, const P& b, const P& y) {
    if constexpr (kFused) return fma(a, x, fma(b, y, t));
    return t + fma(a, x, b * y);
}
// (a0 x0 + a1 x1 + a2 x2) + t:
template <class P>
IWR_FORCE_INLINE P dot3_plus(const P& a0, const P& x0, const P& a1, const P& x1, const P& a2,
                             const P& x2, const P& t) {
    if constexpr (kFused) return fma(a2, x2, fma(a1, x1, fma(a0, x0, t)));
    return fma(a2, x2, fma(a1, x1, a0 * x0)) + t;
}

// p itself, its value hidden from the optimiser: what is read through it is read again, not kept in
// registers from an earlier read. GCC kept the chord's J_ref^-1 (loop-invariant: 36 packs) from one
// iteration to the next; with AVX2 (16 registers) that meant a copy of it on the stack, a store for
// every load. Likewise the leg kernel's EvalConsts (kRereadConsts). No operation on the values
// changes.
template <class T>
IWR_FORCE_INLINE const T* reread(const T* p) {
#if defined(__GNUC__) || defined(__clang__)
    __asm__ volatile("" : "+r"(p));
#endif
    return p;
}

// 0T4 of a block's 8 poses by the DH chain (eq. 1-2): the prismatic prefix (the same rotation at
// every pose), then joint by joint. t: rotation row-major (0..8), position (9..11).
// P: Pack (the whole block) or Sub (one register's lanes; blk then points at its first lane).
// NP >= 0: the chain known at compile time, NP prismatic joints then NR revolute ones (pd's joint
// counts and types unused), so the loops unroll and 0T4 stays in registers (the IWR, PPRR: 14 %
// faster with AVX2, 12 % with SSE2, 5-10 % with AVX-512 than the loops over pd's joints, which spill
// 0T4 with 16 registers); NP < 0: any chain, from pd. The same operations in the same order either
// way, so the same bits.
template <int NP, int NR, class P>
IWR_FORCE_INLINE void carriage(const PoseData& pd, const EvalConsts& ec, const double* blk,
                               P (&t)[12]) {
    constexpr int B = kBlock;
    const int n_prefix = NP >= 0 ? NP : pd.n_prefix;
    const int n_joints = NP >= 0 ? NP + NR : pd.n_joints;
    for (int e = 0; e < 9; ++e) t[e] = bcast<P>(ec.rc[e]);
    for (int r = 0; r < 3; ++r) t[9 + r] = bcast<P>(ec.pc[r]);
#pragma GCC unroll 8
    for (int i = 0; i < n_prefix; ++i) {
        const P q = ld<P>(blk + pd.q_off[i] * B);
        const double* z = ec.z + 3 * i;
        for (int r = 0; r < 3; ++r) t[9 + r] = fma(q, bcast<P>(z[r]), t[9 + r]);
    }
#pragma GCC unroll 8
    for (int i = n_prefix; i < n_joints; ++i) {
        const double* jc = ec.joint + 6 * i;
        const P ca = bcast<P>(jc[0]), sa = bcast<P>(jc[1]), ct = bcast<P>(jc[2]),
                st = bcast<P>(jc[3]);
        const P a = bcast<P>(jc[4]), d = bcast<P>(jc[5]);
        const double* q = blk + pd.q_off[i] * B;
        P c, s, dk;
        if (NP < 0 && pd.prismatic[i]) {
            c = ct, s = st, dk = d + ld<P>(q);
        } else {  // angle-sum identity on the per-data-set cos q, sin q
            const P cq = ld<P>(q), sq = ld<P>(q + B);
            c = fms(ct, cq, st * sq), s = fma(st, cq, ct * sq), dk = d;
        }
        // T <- T A_i row by row: u = T0 c + T1 s, v = T1 c - T0 s; the new row is
        // (u, ca v + sa T2, ca T2 - sa v) and the position gains a u + d_k T2.
        for (int r = 0; r < 3; ++r) {
            const P t0 = t[3 * r], t1 = t[3 * r + 1], w = t[3 * r + 2];
            const P u = fma(t0, c, t1 * s);
            const P v = fms(t1, c, t0 * s);
            t[3 * r] = u;
            t[3 * r + 1] = fma(ca, v, sa * w);
            t[3 * r + 2] = fms(ca, w, sa * v);
            t[9 + r] = plus_two_products(t[9 + r], a, u, dk, w);
        }
    }
}

// The carriage of NP prismatic joints then two revolute ones folded (FoldedCarriage,
// fold_carriage): t holds R' and p' (not 0T4: see FoldedCarriage), for the legs to the base joints
// EvalConsts::fold.a. Per pose 18 + 12 + 12 multiplies and FMAs, against 74 joint by joint.
template <int NP, class P>
IWR_FORCE_INLINE void carriage_folded(const PoseData& pd, const EvalConsts& ec, const double* blk,
                                      P (&t)[12]) {
    constexpr int B = kBlock;
    const FoldedCarriage& f = ec.fold;
    const double* q1 = blk + pd.q_off[NP] * B;
    const double* q2 = blk + pd.q_off[NP + 1] * B;
    const P c = ld<P>(q1), s = ld<P>(q1 + B), c2 = ld<P>(q2), s2 = ld<P>(q2 + B);
    for (int r = 0; r < 3; ++r) {
        P sr[3];  // row r of S = s0 + c s1 + s s2
        for (int k = 0; k < 3; ++k) {
            const int e = 3 * r + k;
            sr[k] = fma(bcast<P>(f.s2[e]), s, fma(bcast<P>(f.s1[e]), c, bcast<P>(f.s0[e])));
        }
        const P u = fma(sr[0], c2, sr[1] * s2);  // R' = S Rz(q2)
        t[3 * r] = u;
        t[3 * r + 1] = fms(sr[1], c2, sr[0] * s2);
        t[3 * r + 2] = sr[2];
        P pos = bcast<P>(f.p0[r]);
#pragma GCC unroll 8
        for (int i = 0; i < NP; ++i)
            pos = fma(ld<P>(blk + pd.q_off[i] * B), bcast<P>(ec.z[3 * i + r]), pos);
        t[9 + r] = fma(bcast<P>(f.ps[r]), s, fma(bcast<P>(f.pc[r]), c, pos));
    }
}

// One register's lanes of a block of 8 poses (blk points at the first of them): 0T4 (carriage),
// then M = 4R0 0R5 and w = 4R0 (0P5 - 0P4), the platform pose in frame {4}; leg j is
// v = M b_j + w - a_j (eq. 8 expressed in {4}) and sq[j] = |v|^2, or |v| (Root: each square root
// right after its square).
template <int NP, int NR, bool Root = false>
IWR_FORCE_INLINE void leg_squares(const PoseData& pd, const EvalConsts& ec, const double* blk,
                                  Sub (&sq)[6]) {
    constexpr int B = kBlock;
    using P = Sub;
    P t[12];  // 0T4: rotation row-major (0..8), position (9..11)
    // NP >= 0, NR == 2: folded (R', p' for 0T4, and the base joints in {4'}: FoldedCarriage).
    constexpr bool kFold = NP >= 0 && NR == 2;
    const double(*base)[3] = kFold ? ec.fold.a : ec.a;
    if constexpr (kFold)
        carriage_folded<NP>(pd, ec, blk, t);
    else
        carriage<NP, NR>(pd, ec, blk, t);

    // --- platform pose in {4}: M = R4^T R5, w = R4^T (p5 - p4) -------------------------------------
    P m[12];
    {
        const double* p5 = blk + pd.off_p5 * B;
        const double* r5 = blk + pd.off_r5 * B;
        const P d0 = ld<P>(p5) - t[9], d1 = ld<P>(p5 + B) - t[10], d2 = ld<P>(p5 + 2 * B) - t[11];
        for (int r = 0; r < 3; ++r)  // w = R4^T (p5 - p4): column r of R4 . d
            m[9 + r] = fma(t[6 + r], d2, fma(t[3 + r], d1, t[r] * d0));
        for (int c = 0; c < 3; ++c) {  // column c of R5 (fewer live registers than all nine)
            const P f0 = ld<P>(r5 + c * B), f1 = ld<P>(r5 + (3 + c) * B),
                    f2 = ld<P>(r5 + (6 + c) * B);
            for (int r = 0; r < 3; ++r) m[3 * r + c] = fma(t[6 + r], f2, fma(t[3 + r], f1, t[r] * f0));
        }
    }
    for (int j = 0; j < 6; ++j) {  // the six lengths first: their square roots overlap
        const P b0 = bcast<P>(ec.b[j][0]), b1 = bcast<P>(ec.b[j][1]), b2 = bcast<P>(ec.b[j][2]);
        const P vx = dot3_plus(m[0], b0, m[1], b1, m[2], b2, m[9] - bcast<P>(base[j][0]));
        const P vy = dot3_plus(m[3], b0, m[4], b1, m[5], b2, m[10] - bcast<P>(base[j][1]));
        const P vz = dot3_plus(m[6], b0, m[7], b1, m[8], b2, m[11] - bcast<P>(base[j][2]));
        sq[j] = fma(vz, vz, fma(vy, vy, vx * vx));
        if (Root) sq[j] = sqrt(sq[j]);
    }
}

// The residuals sqrt(w_kj) (|v| - l0_j - s_kj) of one register's lanes from the legs' lengths
// len (blk: the first lane); returns the per-lane sums of squares.
// Weighted: 0 none, 1 a weight per leg, 2 a whitening per pose (the raw residuals of the six
// legs first, then W r row by row, the lower triangle only).
template <int Weighted, bool Residuals>
IWR_FORCE_INLINE Sub leg_residuals(const PoseData& pd, const EvalConsts& ec, const double* blk,
                                   const Sub (&len)[6], Sub (&res)[6]) {
    constexpr int B = kBlock;
    using P = Sub;
    P acc = bcast<P>(0.0), raw[6];
    for (int j = 0; j < 6; ++j) {
        P r = (len[j] - bcast<P>(ec.l0[j])) - ld<P>(blk + (pd.off_s + j) * B);
        if (Weighted == 1) r = r * ld<P>(blk + (pd.off_w + j) * B);
        if (Weighted == 2) {
            raw[j] = r;
        } else {
            if (Residuals) res[j] = r;
            acc = fma(r, r, acc);
        }
    }
    if (Weighted == 2) {
        const double* w = blk + pd.off_wh * B;
        for (int i = 0; i < 6; ++i) {
            P r = ld<P>(w) * raw[0];
            w += B;
            for (int j = 1; j <= i; ++j, w += B) r = fma(ld<P>(w), raw[j], r);
            if (Residuals) res[i] = r;
            acc = fma(r, r, acc);
        }
    }
    return acc;
}

// One register's lanes of a block: the legs' lengths, then the residuals.
template <int Weighted, bool Residuals, int NP, int NR>
IWR_FORCE_INLINE Sub block(const PoseData& pd, const EvalConsts& ec, const double* blk,
                           Sub (&res)[6]) {
    Sub len[6];
    leg_squares<NP, NR, true>(pd, ec, blk, len);
    return leg_residuals<Weighted, Residuals>(pd, ec, blk, len, res);
}

#ifdef IWR_HALF_PASS
// Defined as the namespace of a variant with registers of 4 lanes (the AVX-512 variant: avx2): a
// block of at most 4 poses (the last one, padded: at N = 100 the 13th holds 4) runs as that
// variant's pass of 4 lanes, the same operations on each lane (so the same bits), instead of a
// full pass of 8. The cost only; the residuals keep the full pass.
constexpr bool kHalfPass = true;
template <int Weighted, int NP, int NR>
IWR_FORCE_INLINE void half_pass(const PoseData& pd, const EvalConsts& ec, const double* blk,
                                double* out) {  // out: the 4 lanes' sums of squares (aligned)
    IWR_HALF_PASS::Sub res[6];
    const IWR_HALF_PASS::Sub acc = IWR_HALF_PASS::block<Weighted, false, NP, NR>(pd, ec, blk, res);
    IWR_HALF_PASS::store(out, acc);
}
#else
constexpr bool kHalfPass = false;
template <int Weighted, int NP, int NR>
void half_pass(const PoseData&, const EvalConsts&, const double*, double*) {}
#endif

static_assert(!kLegPipe || K == 1, "kLegPipe: one register a block");
template <int Weighted, bool Residuals, int NP, int NR>
IWR_FORCE_INLINE double run(const PoseData& pd, const EvalConsts& ec, double* out) {
    constexpr int B = kBlock, W = kSubLanes;
    // Per-lane partial sums: pose k goes to lane k mod 8 whatever the register width, so the order
    // of summation (and the result) is the same for every variant.
    Sub lanes[K], res[6];
    for (auto& l : lanes) l = bcast<Sub>(0.0);
    alignas(64) double tmp[B];
    // One register of block b (its lanes h W ...); valid: the block's poses, the rest padding.
    auto pass = [&](int b, int h, int valid) IWR_FORCE_INLINE_LAMBDA {
        const double* blk = pd.data + static_cast<long>(b) * pd.stride;
        const Sub acc = block<Weighted, Residuals, NP, NR>(pd, kRereadConsts ? *reread(&ec) : ec,
                                                           blk + h * W, res);
        if (valid == B) {
            lanes[h] = lanes[h] + acc;
        } else {
            store(tmp, acc);
            for (int l = 0; l < W; ++l)
                if (h * W + l >= valid) tmp[l] = 0.0;
            lanes[h] = lanes[h] + ld<Sub>(tmp);
        }
        if (Residuals) {
            for (int j = 0; j < 6; ++j) {
                store(tmp, res[j]);
                for (int l = 0; l < W && h * W + l < valid; ++l)
                    out[(static_cast<long>(b) * B + h * W + l) * 6 + j] = tmp[l];
            }
        }
    };
    const int full = pd.n / B;
    if constexpr (kLegPipe) {
        // The full blocks software-pipelined (one register a block: K == 1): block b's square
        // roots, then block b + 1's squared lengths (multiplies and adds that do not wait for
        // them), then block b's residuals. The same operations on each lane, the sums added block
        // after block.
        Sub sq[6], len[6];
        auto at = [&](int b) IWR_FORCE_INLINE_LAMBDA {
            return pd.data + static_cast<long>(b) * pd.stride;
        };
        if (full > 0) leg_squares<NP, NR>(pd, ec, at(0), sq);
        for (int b = 0; b < full; ++b) {
            for (int j = 0; j < 6; ++j) len[j] = sqrt(sq[j]);
            const EvalConsts& e = kRereadConsts ? *reread(&ec) : ec;
            if (b + 1 < full) leg_squares<NP, NR>(pd, e, at(b + 1), sq);
            const Sub acc = leg_residuals<Weighted, Residuals>(pd, e, at(b), len, res);
            lanes[0] = lanes[0] + acc;
            if (Residuals) {
                for (int j = 0; j < 6; ++j) {
                    store(tmp, res[j]);
                    for (int l = 0; l < B; ++l) out[(static_cast<long>(b) * B + l) * 6 + j] = tmp[l];
                }
            }
        }
    } else {
        for (int b = 0; b < full; ++b)
            for (int h = 0; h < K; ++h) pass(b, h, B);  // the block's registers one at a time
    }
    if (full < pd.n_blocks) {  // the last block, padded
        const int valid = pd.n - full * B;
        bool done = false;
        if constexpr (kHalfPass && !Residuals) {
            if (valid <= B / 2) {  // at most 4 poses: that half of the block on 4 lanes
                half_pass<Weighted, NP, NR>(pd, ec, pd.data + static_cast<long>(full) * pd.stride,
                                            tmp);
                for (int l = valid; l < B; ++l) tmp[l] = 0.0;
                lanes[0] = lanes[0] + ld<Sub>(tmp);
                done = true;
            }
        }
        // A register of padding only would add zeros to its lanes' sums: skipped (the same sums).
#pragma GCC unroll 4
        for (int h = 0; h < K; ++h)
            if (!done && h * W < valid) pass(full, h, valid);
    }
    for (int h = 0; h < K; ++h) store(tmp + h * W, lanes[h]);
    return ((tmp[0] + tmp[4]) + (tmp[1] + tmp[5])) + ((tmp[2] + tmp[6]) + (tmp[3] + tmp[7]));
}

template <int NP, int NR>
double kernel_chain(const PoseData& pd, const EvalConsts& ec, double* out) {
    if (pd.off_wh >= 0) return out ? run<2, true, NP, NR>(pd, ec, out) : run<2, false, NP, NR>(pd, ec, out);
    if (pd.off_w >= 0) return out ? run<1, true, NP, NR>(pd, ec, out) : run<1, false, NP, NR>(pd, ec, out);
    return out ? run<0, true, NP, NR>(pd, ec, out) : run<0, false, NP, NR>(pd, ec, out);
}

// Whether the carriage is np prismatic joints then nr revolute ones (carriage<np, nr> applies).
inline bool chain_is(const PoseData& pd, int np, int nr) {
    if (pd.n_prefix != np || pd.n_joints != np + nr) return false;
    for (int i = np; i < np + nr; ++i)
        if (pd.prismatic[i]) return false;
    return true;
}

// The chains compiled in: the IWR's (PPRR), folded (fold_carriage); any other through the general
// loops.
double kernel(const PoseData& pd, const EvalConsts& ec, double* out) {
    if (chain_is(pd, 2, 2) && ec.folded) return kernel_chain<2, 2>(pd, ec, out);
    return kernel_chain<-1, 0>(pd, ec, out);
}
