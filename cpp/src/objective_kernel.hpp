// Internal: the SIMD kernel behind Objective::cost and Objective::residuals (not installed, not API).
//
// Poses are stored in blocks of kBlock poses, structure of arrays inside each block ("AoSoA"): all
// quantities of one block are contiguous, so one block's data is a few cache lines and the
// per-pose arithmetic maps one-to-one onto SIMD lanes. The kernel is compiled several times for
// different instruction sets (baseline x86-64 SSE2, AVX2, AVX-512) and picked at run time. Every
// variant performs the same IEEE operations in the same order on each lane (no reassociation); the
// AVX2 and AVX-512 variants fuse the multiply-adds the body writes as fma/fms and give bit-identical
// results, the SSE2 baseline rounds those twice and differs from them at the level of rounding.
#pragma once

#include <string>
#include <vector>

namespace iwr::detail {

constexpr int kBlock = 8;  // poses per block: one AVX-512 register, two AVX2, four SSE2

/// Per-data-set, parameter-independent layout of the pose data (built once by Objective).
struct PoseData {
    const double* data = nullptr;  // n_blocks * stride doubles, 64-byte aligned
    int n = 0;                     // number of poses
    int n_blocks = 0;
    int stride = 0;                // doubles per block = n_quantities * kBlock
    // Offsets (in units of kBlock doubles) of each quantity inside a block.
    int off_r5 = 0;   // 9: 0R5 row-major
    int off_p5 = 0;   // 3: 0P5
    int off_s = 0;    // 6: measured leg readings
    int off_w = -1;   // 6: sqrt of weights, or -1 when unweighted
    int off_wh = -1;  // 21: the whitening's lower triangle row by row, or -1 when not whitened
    int n_joints = 0;
    int n_prefix = 0;            // leading prismatic joints: their rotation is the same at every pose
    const int* q_off = nullptr;  // per joint: q (prismatic) or cos q, sin q (revolute, 2 quantities)
    const char* prismatic = nullptr;  // per joint: 1 prismatic, 0 revolute
};

/// The leg kernel's carriage of a prismatic prefix and two revolute joints (the IWR's PPRR), folded
/// into per-evaluation constants (fold_carriage). With c, s the cosine and sine of the first
/// revolute reading, the rotation S = Rc Rz(theta1 + q) Rx(alpha1) Rz(theta2) is s0 + c s1 + s s2,
/// entry by entry; per pose R' = S Rz(q2) and p' = p0 + sum_i q_i z_i + c pc + s ps, and 0T4 =
/// [R' Rx(alpha2), p' + a2 R' e_x]. A leg's length is the same in the frame {4'} = {4}
/// Rx(alpha2)^T, where the base joint is a_j' = Rx(alpha2) a_j + a2 e_x (a2 R' e_x is a2 e_x there):
/// v_j = R'^T (R5 b_j + p5 - p') - a_j'. 32 fewer multiplies and FMAs a pose than the chain joint
/// by joint (156 against 188 with the legs and the residuals), the same lengths to rounding.
struct FoldedCarriage {
    double s0[9], s1[9], s2[9];  // row-major
    double p0[3], pc[3], ps[3];
    double a[6][3];              // a_j'
};

/// Per-evaluation constants that depend on the parameters only (computed once per cost call).
struct EvalConsts {
    double rc[9];              // rotation after the prismatic prefix (row-major)
    double pc[3];              // its position for zero prefix readings
    double a[6][3], b[6][3], l0[6];
    const double* z = nullptr;      // per prefix joint: 3, position += q * z
    const double* joint = nullptr;  // per joint (index >= n_prefix): 6: cos/sin alpha, cos/sin theta, a, d
    bool folded = false;  // fold holds the carriage folded (fold_carriage; the leg kernel's PPRR)
    FoldedCarriage fold;
};

/// ec.fold from ec's rc, pc and joint constants when the carriage is two prismatic joints then two
/// revolute ones (the chain the leg kernel compiles in); ec.folded says whether it did.
void fold_carriage(EvalConsts& ec, int n_prefix, int n_joints, const char* prismatic);

/// Sum of squared (weighted) residuals; when residuals != nullptr also writes them (N*6, pose-major).
using KernelFn = double (*)(const PoseData&, const EvalConsts&, double* residuals);

/// Per-evaluation constants of the tracker point objective (TrackerObjective, tracker.cpp).
struct TrackerConsts {
    EvalConsts ec;  // the carriage at x and the hexapod's a, b, l0
    PoseData pd;    // the carriage's layout in the tracker's blocks (n_joints, n_prefix, q_off,
                    // prismatic; nothing else)
    double binv[9];  // B^-1 (row-major), B = [b_i, b_k, b_i x b_k] for the pair (i, k)
    int pair[2] = {0, 1};
    double tol = 0;   // forward kinematics: the leg residuals' 2-norm at most (mm)
    int max_iter = 0; // chord steps before the fallback
    double rt[9], tt[3];  // the registration T_T0 at x (rotation row-major)
    int n_points = 0;
    // The points in the platform joints' frame: point i of {5} is B c_i, so that R r_i = F c_i
    // with F = [d_i, d_k, d_i x d_k] = R B, the chord's output (3 per point).
    const double* refl = nullptr;
    double failed_residual = 0;
    // Whitened: per residual row of a pose (3 n_points), 1 when the whitening's row is not zero
    // at some pose (its entries j = 0..i stored, TrackerObjective::set_whitening), 0 when it is
    // zero at every pose (skipped: a probe's first six rows).
    const char* wh_rows = nullptr;
    int wh_first = -1;  // the rows stored are wh_first.. (every one), or -1: another pattern
};
/// The hexapod's constants of TrackerConsts (ec.a, ec.b, ec.l0) lane by lane, for a block of the
/// chord whose lanes belong to different parameter vectors: quantity q of lane l at
/// v[q * kBlock + l], leg j's coordinate c of a at kA + 3 j + c, of b at kB + 3 j + c, l0 at
/// kL0 + j.
struct alignas(64) LaneConsts {
    static constexpr int kA = 0, kB = 18, kL0 = 36, kQuantities = 42;
    double v[kQuantities * kBlock];
    /// Lanes [l0, l1) from tc.
    void set(const TrackerConsts& tc, int l0, int l1);
};

/// The two halves of a block of the tracker objective (tracker_kernel_body.inl): the forward
/// kinematics by chord iterations, and the carriage, the points and the squared residuals
/// (whitened when wh, the block's whitening, is given; vbuf: 3 n_points x 8 doubles of scratch,
/// 64-byte aligned).
/// A platform pose is given as P (3 x 8) and F = R B = [d_i, d_k, d_i x d_k] (9 x 8, row-major;
/// the rotation R = F B^-1, TrackerConsts::binv): the points need R r_i = F c_i alone
/// (TrackerConsts::refl), so the chord does not form R.
struct TrackerKernels {
    void (*chord)(const double* blk, const TrackerConsts& tc, double* p, double* f, int* status);
    // Two blocks: p, f, status of blk1 after blk0's (3 x 8, 9 x 8, 8 each); the same values as
    // chord on each. Null where the variant runs chord block by block.
    void (*chord2)(const double* blk0, const double* blk1, const TrackerConsts& tc, double* p,
                   double* f, int* status);
    // nb (1 or 2) blocks blk[0..nb) whose lanes take the hexapod's constants from lc[0..nb) (tol,
    // max_iter and pair from tc): p, f, status as chord2's; each lane the same values as chord's on
    // a block of that lane's parameter vector.
    void (*chord_lanes)(const double* const* blk, const LaneConsts* lc, int nb,
                        const TrackerConsts& tc, double* p, double* f, int* status);
    void (*points)(const double* blk, const TrackerConsts& tc, const double* p, const double* f,
                   const double* meas, const double* seen, const double* bad, bool plain,
                   const double* wh, double* vbuf, double* t, double* y, double* acc);
};
/// The variant of the same instruction set as active_kernel().
TrackerKernels active_tracker_kernels();

/// The variant chosen for this CPU at start-up, or the one forced by select_kernel.
KernelFn active_kernel();
const char* active_kernel_name();
/// Names of the variants compiled in that this CPU can run, baseline first.
std::vector<std::string> supported_kernels();
/// Names of every variant compiled in, baseline first.
std::vector<std::string> compiled_kernels();
/// Forces a variant (tests and benchmarks); throws std::invalid_argument when unknown/unsupported.
void select_kernel(const std::string& name);

}  // namespace iwr::detail
