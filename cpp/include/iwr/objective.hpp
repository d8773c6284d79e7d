// The calibration objective of eq. (10): the (optionally weighted) sum over poses and legs of
// (predicted - measured)^2 leg sensor readings, its residual vector and its exact Jacobian.
#pragma once

#include <cstddef>
#include <memory>
#include <new>
#include <string>
#include <vector>

#include "iwr/model.hpp"
#include "iwr/parallel.hpp"

namespace iwr {

namespace detail {
struct EvalConsts;  // objective_kernel.hpp (internal)

/// Allocator for SIMD data: 64-byte (cache line, AVX-512 vector) alignment.
template <class T>
struct AlignedAllocator {
    using value_type = T;
    AlignedAllocator() = default;
    template <class U>
    AlignedAllocator(const AlignedAllocator<U>&) noexcept {}
    T* allocate(std::size_t n) {
        return static_cast<T*>(::operator new(n * sizeof(T), std::align_val_t(64)));
    }
    void deallocate(T* p, std::size_t) noexcept { ::operator delete(p, std::align_val_t(64)); }
    template <class U>
    bool operator==(const AlignedAllocator<U>&) const noexcept { return true; }
    template <class U>
    bool operator!=(const AlignedAllocator<U>&) const noexcept { return false; }
};
struct EvalConsts;

/// What the carriage's per-evaluation constants need of the geometry alone (both objectives).
class CarriageNominal {
public:
    CarriageNominal() = default;
    explicit CarriageNominal(const Geometry& g);
    int n_prefix() const { return n_prefix_; }
    /// ec at x: the prismatic prefix's rotation and position, cos/sin of alpha and theta, a, d of
    /// each joint (into jbuf, 15 n_joints + 1 doubles), and the hexapod's a, b, l0.
    void consts(const Geometry& g, const double* x, EvalConsts& ec, double* jbuf) const;

private:
    int n_prefix_ = 0;             // leading prismatic joints
    std::vector<double> nominal_;  // nominal alpha_i, theta_i (interleaved), their cos, their sin
};
}  // namespace detail

/// SIMD variants of the cost kernels (the leg objective's and the tracker point objective's) that
/// this CPU can run, baseline first: "baseline" (x86-64 SSE2, or the compiler's default
/// elsewhere), "avx2" (with FMA), "avx512". The same operation order on every lane and the kernels'
/// explicit fused multiply-adds (no other contraction): "avx2" and "avx512" give bit-identical
/// results; "baseline" (no FMA on x86-64: a multiply and an add) the same to rounding.
std::vector<std::string> supported_kernels();
/// The variant in use: the widest one the CPU supports, unless select_kernel chose another.
std::string active_kernel();
/// Uses the named variant from now on, process-wide (for tests and benchmarks). Throws
/// std::invalid_argument if the name is unknown or the CPU cannot run it.
void select_kernel(const std::string& name);
/// The variant the environment variable IWR_KERNEL names (a name of supported_kernels(), or
/// "auto": the widest this CPU runs, as when it is not set or empty), selected process-wide. The
/// front ends (import iwr, the iwr and iwr-calibrate commands, iwr-engine) call it at start. Throws
/// std::invalid_argument naming the variable and its value if the name is unknown or the CPU
/// cannot run it.
void select_kernel_from_environment();
/// "kernel K; this CPU runs A, B, C": the variant in use and those this CPU runs (--version).
std::string kernel_summary();
/// "IWR_KERNEL=K " when the environment names a variant (not auto), else "": the prefix of a
/// command that repeats or resumes a run with the same variant.
std::string kernel_environment_prefix();

class Objective {
public:
    /// q (N, n_joints), poses (N, 6), legs (N, 6) measured sensor readings, weights (N, 6) or empty
    /// (all ones). Residual k*6+j is sqrt(w_kj) * (predicted_kj - legs_kj).
    ///
    /// whitening (N, 36) or empty: per pose a lower-triangular 6x6 matrix W_k (row-major, its
    /// upper triangle 0), and residuals k*6+i = sum_{j<=i} W_k[i][j] (predicted_kj - legs_kj):
    /// generalised least squares with fixed weights, cost = sum_k r_k^T W_k^T W_k r_k, for
    /// example W_k = L_k^-1 with L_k L_k^T the covariance of pose k's six residuals. Not together
    /// with weights (fold them into W_k).
    Objective(Geometry geometry, const RowMatrixXd& q, const RowMatrixXd& poses,
              const RowMatrixXd& legs, const RowMatrixXd& weights = RowMatrixXd(),
              const RowMatrixXd& whitening = RowMatrixXd());

    /// Whether the residuals are whitened (a whitening was given).
    bool whitened() const { return off_wh_ >= 0; }

    const Geometry& geometry() const { return geometry_; }
    int n_params() const { return geometry_.n_params(); }
    int n_poses() const { return n_; }
    int n_residuals() const { return kLegs * n_; }

    /// Scratch memory for one thread's evaluations; makes cost() allocation-free.
    class Workspace {
        friend class Objective;
        std::vector<double> buf;
    };
    Workspace make_workspace() const;

    /// The cost of eq. (10) at x (n_params entries, unchecked: the hot path).
    double cost(const double* x, Workspace& ws) const;
    /// Checked convenience overload.
    double cost(const Eigen::Ref<const VectorXd>& x) const;

    /// Residual vector (N*6, pose-major) at x.
    VectorXd residuals(const Eigen::Ref<const VectorXd>& x) const;

    /// Residuals and their exact, analytic Jacobian (N*6 x n_params) at x.
    void jacobian(const Eigen::Ref<const VectorXd>& x, VectorXd* residuals, RowMatrixXd* jac) const;

    /// Costs of the rows of X (M, n_params) into out (M), across the pool's threads. Unchecked.
    void cost_batch(const double* X, Eigen::Index m, double* out, ThreadPool& pool) const;

private:
    // Per-evaluation constants (rotation of the prismatic prefix, cos/sin of alpha and theta, ...)
    // into ec, using jbuf (15 n_joints doubles) for the per-joint parts.
    void prepare(const double* x, detail::EvalConsts& ec, double* jbuf) const;
    // Runs the SIMD kernel; writes the residuals too when res != nullptr.
    double evaluate(const double* x, double* jbuf, double* res) const;
    // Quantity e of pose k in the blocked layout.
    double pose_value(int e, int k) const {
        return blocks_[static_cast<size_t>(k / kBlock) * static_cast<size_t>(stride_) +
                       static_cast<size_t>(e * kBlock + k % kBlock)];
    }

    static constexpr int kBlock = 8;  // = detail::kBlock (checked in objective.cpp)
    Geometry geometry_;
    int n_ = 0;
    RowMatrixXd q_;  // joint readings as given (for the Jacobian)
    // Pose data in blocks of kBlock poses, structure of arrays inside a block (see
    // objective_kernel.hpp): quantities 0R5 (9, row-major), 0P5 (3), readings (6), sqrt weights
    // (6, when weighted), the whitening's lower triangle row by row (21, when whitened), then per
    // joint q (prismatic) or cos q, sin q (revolute). The last block is padded with copies of the
    // last pose.
    std::vector<double, detail::AlignedAllocator<double>> blocks_;
    int n_blocks_ = 0, stride_ = 0, off_w_ = -1, off_wh_ = -1;
    RowMatrixXd whitening_;  // (N, 36) as given, for the Jacobian
    std::vector<int> q_off_;
    std::vector<char> prismatic_;
    detail::CarriageNominal carriage_;
};

}  // namespace iwr
