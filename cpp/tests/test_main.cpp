// C++ tests of the core, run by ctest (and under AddressSanitizer/UBSan with -DIWR_SANITIZE=ON).
// Deliberately framework-free: the core has no dependency beyond Eigen and the standard library.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include "check.hpp"
#include "iwr/forward.hpp"
#include "iwr/model.hpp"
#include "iwr/objective.hpp"
#include "iwr/parallel.hpp"

namespace test_main {

namespace {

iwr::Geometry iwr_geometry(bool with_carriage) {
    const double h = M_PI / 2;
    iwr::RowMatrixXd dh(4, 4);
    dh << h, 0, 500, 0, h, 0, 300, h, h, 400, 250, 0, -h, 300, 0, 0;
    iwr::LegMatrix base, platform;
    for (int j = 0; j < 6; ++j) {
        const double ab = (120.0 * (j / 2) + (j % 2 ? 10.0 : -10.0)) * M_PI / 180;
        const double ap = ab + M_PI / 3;
        base.row(j) << 400 * std::cos(ab), 400 * std::sin(ab), 0;
        platform.row(j) << 250 * std::cos(ap), 250 * std::sin(ap), 0;
    }
    iwr::LegVector l0 = iwr::LegVector::Constant(600);
    if (!with_carriage) return iwr::Geometry("", iwr::RowMatrixXd(0, 4), base, platform, l0);
    return iwr::Geometry("PPRR", dh, base, platform, l0);
}

iwr::Objective make_objective(const iwr::Geometry& g, int n, std::mt19937_64& rng, bool weighted) {
    std::uniform_real_distribution<double> u(-1, 1);
    iwr::RowMatrixXd q(n, g.n_joints()), poses(n, 6), legs(n, 6), w;
    for (int k = 0; k < n; ++k) {
        for (int i = 0; i < g.n_joints(); ++i) q(k, i) = g.is_prismatic(i) ? 500 * (1 + u(rng)) : u(rng);
        poses.row(k) << 1000 * u(rng), 1000 * u(rng), 1000 + 500 * u(rng), u(rng), u(rng), u(rng);
        for (int j = 0; j < 6; ++j) legs(k, j) = 200 + 100 * u(rng);
    }
    if (weighted) w = iwr::RowMatrixXd::Constant(n, 6, 1.0) + 0.5 * iwr::RowMatrixXd::Random(n, 6);
    return iwr::Objective(g, q, poses, legs, w);
}

IWR_TEST(cost_residuals_jacobian) {
    std::mt19937_64 rng(42);
    std::uniform_real_distribution<double> u(-0.5, 0.5);
    for (bool carriage : {true, false}) {
        for (bool weighted : {false, true}) {
            for (int n : {1, 7, 64}) {
                const iwr::Geometry g = iwr_geometry(carriage);
                const iwr::Objective obj = make_objective(g, n, rng, weighted);
                iwr::VectorXd x(g.n_params());
                for (int i = 0; i < x.size(); ++i) x(i) = u(rng);
                iwr::VectorXd r;
                iwr::RowMatrixXd jac;
                obj.jacobian(x, &r, &jac);
                const double c = obj.cost(x);
                CHECK(std::abs(c - r.squaredNorm()) <= 1e-10 * r.squaredNorm());
                // central differences
                const double h = 1e-6;
                double worst = 0;
                for (int i = 0; i < x.size(); ++i) {
                    iwr::VectorXd xp = x, xm = x;
                    xp(i) += h;
                    xm(i) -= h;
                    const iwr::VectorXd fd = (obj.residuals(xp) - obj.residuals(xm)) / (2 * h);
                    worst = std::max(worst, (fd - jac.col(i)).cwiseAbs().maxCoeff() /
                                                (1 + fd.cwiseAbs().maxCoeff()));
                }
                CHECK(worst < 1e-6);
            }
        }
    }
}

IWR_TEST(batch_is_thread_independent) {
    std::mt19937_64 rng(7);
    const iwr::Geometry g = iwr_geometry(true);
    const iwr::Objective obj = make_objective(g, 33, rng, false);
    const int m = 101;
    iwr::RowMatrixXd X = 0.5 * iwr::RowMatrixXd::Random(m, g.n_params());
    iwr::VectorXd one(m), two(m), three(m);
    iwr::ThreadPool p1(1), p2(2), p3(3);
    obj.cost_batch(X.data(), m, one.data(), p1);
    obj.cost_batch(X.data(), m, two.data(), p2);
    obj.cost_batch(X.data(), m, three.data(), p3);
    CHECK(one == two);
    CHECK(one == three);
    auto ws = obj.make_workspace();
    for (int i = 0; i < m; ++i) CHECK(one(i) == obj.cost(X.row(i).data(), ws));
}

// The compiled instruction-set variants of the kernel with fused multiply-adds (AVX2, AVX-512) give
// the same bits, the baseline (SSE2: each multiply-add rounded twice) the same to rounding, and all
// agree with the per-pose Eigen model (predict_legs) for carriages of mixed joint types and N not a
// multiple of 8.
IWR_TEST(kernel_variants) {
    std::mt19937_64 rng(3);
    std::uniform_real_distribution<double> u(-1, 1);
    const std::string before = iwr::active_kernel();
    for (const std::string types : {"", "PPRR", "RPRP", "PRRRP"}) {
        const int nj = static_cast<int>(types.size());
        iwr::RowMatrixXd dh(nj, 4);
        for (int i = 0; i < nj; ++i) dh.row(i) << 3 * u(rng), 300 * u(rng), 300 * u(rng), 3 * u(rng);
        const iwr::Geometry h = iwr_geometry(false);
        const iwr::Geometry g(types, dh, h.base(), h.platform(), h.leg_offsets());
        for (int n : {1, 9, 13}) {
            iwr::RowMatrixXd q(n, nj), poses(n, 6), legs(n, 6), w(n, 6);
            for (int k = 0; k < n; ++k) {
                for (int i = 0; i < nj; ++i) q(k, i) = types[i] == 'P' ? 500 * (1 + u(rng)) : u(rng);
                poses.row(k) << 300 * u(rng), 300 * u(rng), 800 + 100 * u(rng), u(rng), u(rng), u(rng);
                for (int j = 0; j < 6; ++j) legs(k, j) = 200 + 100 * u(rng), w(k, j) = 1 + u(rng);
            }
            iwr::VectorXd x(g.n_params());
            for (int i = 0; i < x.size(); ++i) x(i) = 0.4 * u(rng);
            const iwr::RowMatrixXd pred = iwr::predict_legs(g, x, q, poses);
            for (bool weighted : {false, true}) {
                const iwr::Objective obj(g, q, poses, legs, weighted ? w : iwr::RowMatrixXd());
                double first = 0, fused = 0;
                iwr::VectorXd r0, rf;
                for (const std::string& k : iwr::supported_kernels()) {
                    iwr::select_kernel(k);
                    const double c = obj.cost(x);
                    const iwr::VectorXd r = obj.residuals(x);
                    if (k == "baseline") {
                        first = c, r0 = r;
                    } else if (rf.size() == 0) {
                        fused = c, rf = r;
                    } else {
                        CHECK(c == fused);
                        CHECK(r == rf);
                    }
                    CHECK(std::abs(c - first) <= 1e-13 * first);
                    CHECK((r - r0).cwiseAbs().maxCoeff() <= 1e-10);
                }
                CHECK(std::abs(first - r0.squaredNorm()) <= 1e-13 * first);
                double worst = 0;
                for (int k = 0; k < n; ++k)
                    for (int j = 0; j < 6; ++j) {
                        const double sw = weighted ? std::sqrt(w(k, j)) : 1.0;
                        worst = std::max(worst, std::abs(r0(6 * k + j) - sw * (pred(k, j) - legs(k, j))));
                    }
                CHECK(worst < 1e-9);
            }
        }
    }
    iwr::select_kernel(before);
    bool thrown = false;
    try {
        iwr::select_kernel("nope");
    } catch (const std::invalid_argument& e) {
        thrown = std::string(e.what()).find("'nope' is unknown") != std::string::npos;
    }
    CHECK(thrown);
}

// IWR_KERNEL (what iwr-engine and the Python front ends read at start): a variant this CPU runs,
// auto or empty (the widest), or an error that names the variable and its value.
IWR_TEST(kernel_from_environment) {
    const std::string before = iwr::active_kernel();
    const std::vector<std::string> runs = iwr::supported_kernels();
    const char* saved = std::getenv("IWR_KERNEL");
    const std::string saved_value = saved ? saved : "";
    for (const std::string& k : runs) {
        setenv("IWR_KERNEL", k.c_str(), 1);
        iwr::select_kernel_from_environment();
        CHECK(iwr::active_kernel() == k);
        for (const char* widest : {"auto", ""}) {
            setenv("IWR_KERNEL", widest, 1);
            iwr::select_kernel_from_environment();
            CHECK(iwr::active_kernel() == runs.back());
            iwr::select_kernel(k);
        }
    }
    unsetenv("IWR_KERNEL");
    iwr::select_kernel(runs.front());
    iwr::select_kernel_from_environment();
    CHECK(iwr::active_kernel() == runs.back());
    for (const char* bad : {"sse9", "AVX2", "avx2 "}) {
        setenv("IWR_KERNEL", bad, 1);
        std::string msg;
        try {
            iwr::select_kernel_from_environment();
        } catch (const std::invalid_argument& e) {
            msg = e.what();
        }
        CHECK(msg.find("environment variable IWR_KERNEL='" + std::string(bad) +
                       "': not a kernel variant; expected one this CPU runs") == 0);
        CHECK(iwr::active_kernel() == runs.back());  // unchanged by a refused value
    }
    if (saved) setenv("IWR_KERNEL", saved_value.c_str(), 1);
    else unsetenv("IWR_KERNEL");
    iwr::select_kernel(before);
}

IWR_TEST(pool_propagates_exceptions) {
    iwr::ThreadPool pool(2);
    bool thrown = false;
    try {
        pool.parallel_for(10, [](std::size_t b, std::size_t, int) {
            if (b > 0) throw std::runtime_error("boom");
        });
    } catch (const std::runtime_error&) {
        thrown = true;
    }
    CHECK(thrown);
    // The pool still works afterwards, workers included (n >= 2), again and again.
    for (int round = 0; round < 5; ++round) {
        std::atomic<int> sum{0};
        pool.parallel_for(10, [&](std::size_t b, std::size_t e, int) {
            sum += static_cast<int>(e - b);
        });
        CHECK(sum == 10);
    }
}

IWR_TEST(pool_sizes_and_lifetimes) {
    // More threads than the machine has (the pool then sleeps instead of spinning), pools
    // destroyed right after a call, and many short calls in a row: every item once.
    const int hw = iwr::ThreadPool::resolve(0);
    for (int threads : {1, 2, hw + 3}) {
        for (int rep = 0; rep < 20; ++rep) {
            iwr::ThreadPool pool(threads);
            std::vector<int> seen(1000, 0);
            for (int call = 0; call < 10; ++call) {
                pool.parallel_for(seen.size(), [&](std::size_t b, std::size_t e, int) {
                    for (std::size_t i = b; i < e; ++i) ++seen[i];
                });
            }
            CHECK(std::all_of(seen.begin(), seen.end(), [](int v) { return v == 10; }));
        }
    }
}

IWR_TEST(pool_dynamic_chunks_cover_every_item_once) {
    // parallel_for_dynamic: every item exactly once, in ranges within [0, n) that the threads
    // claim; any grain (0 counts as 1, the largest too), n below the grain, pools larger than the
    // machine.
    const int hw = iwr::ThreadPool::resolve(0);
    for (int threads : {1, 2, hw + 3}) {
        iwr::ThreadPool pool(threads);
        for (std::size_t n : {0, 1, 2, 7, 600, 1001}) {
            // (a grain near SIZE_MAX wrapped a share's counter: items claimed twice; a review)
            for (std::size_t grain : {std::size_t{0}, std::size_t{1}, std::size_t{8}, std::size_t{5000},
                                      SIZE_MAX / 2 + 7, SIZE_MAX}) {
                std::vector<std::atomic<int>> seen(n);
                std::atomic<bool> sane{true};
                pool.parallel_for_dynamic(n, grain, [&](std::size_t b, std::size_t e, int id) {
                    if (!(b < e && e <= n && id >= 0 && id < pool.size())) sane = false;
                    for (std::size_t i = b; i < e && i < n; ++i) ++seen[i];
                });
                CHECK(sane);
                CHECK(std::all_of(seen.begin(), seen.end(),
                                  [](const std::atomic<int>& v) { return v == 1; }));
            }
        }
        bool thrown = false;
        try {
            pool.parallel_for_dynamic(100, 1, [](std::size_t, std::size_t e, int) {
                if (e > 50) throw std::runtime_error("boom");  // the chunk holding item 50
            });
        } catch (const std::runtime_error&) {
            thrown = true;
        }
        CHECK(thrown);
    }
}

IWR_TEST(pool_dynamic_steals_from_a_held_up_thread) {
    // A thread first takes its own share (parallel_for's chunk), then the others': a worker held
    // up in its first chunk (another process on its core) leaves the rest of its share to the
    // calling thread, which so takes more than its half (a static partition gives it 300).
    iwr::ThreadPool pool(2);
    for (int rep = 0; rep < 3; ++rep) {
        std::vector<int> by(600, -1);
        std::atomic<bool> slept{false};
        pool.parallel_for_dynamic(600, 8, [&](std::size_t b, std::size_t e, int id) {
            if (id == 1 && !slept.exchange(true))
                std::this_thread::sleep_for(std::chrono::milliseconds(200));
            for (std::size_t i = b; i < e; ++i) by[i] = id;
        });
        CHECK(std::count(by.begin(), by.end(), -1) == 0);
        CHECK(std::count(by.begin(), by.end(), 0) > 300);
    }
    // Not held up: the worker's first items are from its own share, [300, 600), if any are left
    // when it comes (the calling thread may have taken them all).
    for (int rep = 0; rep < 20; ++rep) {
        std::atomic<long> first{-1};
        pool.parallel_for_dynamic(600, 8, [&](std::size_t b, std::size_t e, int id) {
            long none = -1;
            if (id == 1) first.compare_exchange_strong(none, static_cast<long>(b));
            // About 2 us an item, so that the worker comes before the items are gone.
            const auto until = std::chrono::steady_clock::now() + std::chrono::microseconds(2 * (e - b));
            while (std::chrono::steady_clock::now() < until) {
            }
        });
        CHECK(first == -1 || first >= 300);
    }
}

IWR_TEST(pool_refuses_too_many_threads) {
    const int cap = iwr::ThreadPool::max_threads();
    CHECK(cap >= iwr::ThreadPool::kMinMaxThreads);
    CHECK(cap >= iwr::ThreadPool::kThreadsPerCpu * iwr::ThreadPool::resolve(0));
    bool named = false;
    try {
        iwr::ThreadPool pool(cap + 1);
    } catch (const std::invalid_argument& e) {
        named = std::string(e.what()).find(std::to_string(cap + 1) + " threads asked for; at most") != std::string::npos;
    }
    CHECK(named);
    iwr::ThreadPool ok(cap);  // the cap itself is allowed
    CHECK(ok.size() == cap);
}

// Runs `body` in a forked child with a 30 s alarm (a hang is a failure, not a stuck test); true if
// the child exited 0.
template <class Body>
bool in_child(Body body) {
    std::fflush(nullptr);
    const pid_t pid = ::fork();
    if (pid == 0) {
        ::alarm(30);
        ::_exit(body() ? 0 : 1);
    }
    int status = 0;
    ::waitpid(pid, &status, 0);
    return WIFEXITED(status) && WEXITSTATUS(status) == 0;
}

IWR_TEST(pool_thread_refused_is_an_error_not_a_hang) {
    // No thread may be created: RLIMIT_NPROC 0 for a user without privileges (root ignores the
    // limit, so a root test drops to uid 65534 first). The pool must say so and stop the threads
    // it did start, not wait on the ones that do not exist.
    CHECK(in_child([] {
        if (::getuid() == 0 && ::setuid(65534) != 0) return false;
        const struct rlimit none = {0, 0};
        if (::setrlimit(RLIMIT_NPROC, &none) != 0) return false;
        try {
            iwr::ThreadPool pool(4);
        } catch (const std::runtime_error& e) {
            const bool named = std::string(e.what()).find("cannot start 4 threads") != std::string::npos;
            if (!named) std::fprintf(stderr, "message: %s\n", e.what());
            return named;
        }
        return false;
    }));
}

IWR_TEST(pool_after_fork) {
    // A pool that ran in the parent: in a forked child its threads do not exist. Using it there is
    // an error (not a hang), destroying it returns, and a new pool works.
    auto* pool = new iwr::ThreadPool(3);
    std::atomic<int> sum{0};
    pool->parallel_for(30, [&](std::size_t b, std::size_t e, int) { sum += static_cast<int>(e - b); });
    CHECK(sum == 30);
    CHECK(in_child([&] {
        if (pool->usable_here()) return false;
        bool refused = false;
        try {
            pool->parallel_for(30, [](std::size_t, std::size_t, int) {});
        } catch (const std::logic_error&) {
            refused = true;
        }
        delete pool;
        iwr::ThreadPool fresh(3);
        std::atomic<int> n{0};
        fresh.parallel_for(30, [&](std::size_t b, std::size_t e, int) { n += static_cast<int>(e - b); });
        return refused && n == 30;
    }));
    CHECK(pool->usable_here());
    delete pool;
}

IWR_TEST(validation) {
    bool thrown = false;
    try {
        iwr::Geometry("PX", iwr::RowMatrixXd::Zero(2, 4), iwr::LegMatrix::Zero(),
                      iwr::LegMatrix::Zero(), iwr::LegVector::Zero());
    } catch (const std::invalid_argument& e) {
        thrown = std::string(e.what()).find("letter 1") != std::string::npos;
    }
    CHECK(thrown);
    thrown = false;
    try {
        const iwr::Geometry g = iwr_geometry(true);
        iwr::Objective(g, iwr::RowMatrixXd::Zero(3, 4), iwr::RowMatrixXd::Zero(3, 6),
                       iwr::RowMatrixXd::Zero(2, 6));
    } catch (const std::invalid_argument& e) {
        thrown = std::string(e.what()).find("legs: shape (2, 6)") != std::string::npos;
    }
    CHECK(thrown);
}

// Forward kinematics: a round trip through the inverse model, and a clean error when the legs
// cannot close. The platform joints are rolled by one so that leg j spans 40 degrees, alternately
// behind and ahead (iwr_geometry's pairing is architecturally singular: see docs/model.md).
IWR_TEST(forward_kinematics) {
    const iwr::Geometry g0 = iwr_geometry(true);
    iwr::LegMatrix platform;
    for (int j = 0; j < 6; ++j) platform.row(j) = g0.platform().row((j + 5) % 6);
    const iwr::Geometry g("PPRR", g0.dh(), g0.base(), platform, g0.leg_offsets());
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<double> u(-1, 1);
    const int n = 20;
    iwr::VectorXd x(g.n_params());
    for (int i = 0; i < x.size(); ++i) x(i) = 0.3 * u(rng);
    iwr::RowMatrixXd q(n, 4), poses(n, 6), none(0, 6);
    iwr::Vector6d home;
    home << 0, 0, 750, 0, 0, 0;
    for (int k = 0; k < n; ++k) {
        q.row(k) << 1000 * (1 + u(rng)), 500 * (1 + u(rng)), u(rng), 0.8 * u(rng);
        iwr::Vector6d local = home;
        local.head<3>() += iwr::Vec3(100 * u(rng), 100 * u(rng), 60 * u(rng));
        local.tail<3>() += iwr::Vec3(0.15 * u(rng), 0.15 * u(rng), 0.15 * u(rng));
        const iwr::Mat4 t4 = iwr::carriage_transform(g, x.data(), q.row(k).data());
        const iwr::Mat3 r4 = t4.topLeftCorner<3, 3>();
        const iwr::Mat3 r5 = r4 * iwr::euler_zyx(local(3), local(4), local(5));
        poses.block<1, 3>(k, 0) =
            (t4.topRightCorner<3, 1>() + t4.topLeftCorner<3, 3>() * local.head<3>()).transpose();
        poses.block<1, 3>(k, 3) = iwr::euler_from_matrix(r5).transpose();
    }
    const iwr::RowMatrixXd legs = iwr::predict_legs(g, x, q, poses);
    const iwr::RowMatrixXd back = iwr::forward_kinematics(g, x, q, legs, none, home);
    for (int k = 0; k < n; ++k) {
        const iwr::Mat3 ra = iwr::euler_zyx(poses(k, 3), poses(k, 4), poses(k, 5));
        const iwr::Mat3 rb = iwr::euler_zyx(back(k, 3), back(k, 4), back(k, 5));
        CHECK((poses.row(k).head<3>() - back.row(k).head<3>()).norm() < 1e-7);
        CHECK((ra - rb).cwiseAbs().maxCoeff() < 1e-10);
    }
    iwr::RowMatrixXd bad = legs;
    bad(3, 0) = -590;  // leg 1 of pose 3 is 10 mm long: the legs cannot close
    bool thrown = false;
    try {
        iwr::forward_kinematics(g, x, q, bad, none, home);
    } catch (const iwr::ForwardKinematicsError& e) {
        thrown = e.pose() == 3 && std::string(e.what()).find("pose 3") != std::string::npos;
    }
    CHECK(thrown);
}

}  // namespace

// One pose conversion in both languages: Z-Y-X angles back from the matrix, exact also at and
// near the gimbal lock (iwr.transforms.euler_from_matrix has the same formula and test).
IWR_TEST(euler_from_matrix_at_the_gimbal_lock) {
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> u(-3, 3);
    const double half_pi = std::acos(0.0);
    for (double beta : {half_pi, -half_pi, half_pi - 1e-9, -half_pi + 3e-10, 0.3}) {
        for (int i = 0; i < 20; ++i) {
            const iwr::Mat3 r = iwr::euler_zyx(u(rng), beta, u(rng));
            const iwr::Vec3 e = iwr::euler_from_matrix(r);
            CHECK((iwr::euler_zyx(e(0), e(1), e(2)) - r).cwiseAbs().maxCoeff() < 1e-14);
            CHECK(std::abs(e(1) - beta) < 1e-7);
        }
    }
    iwr::Mat3 locked = iwr::euler_zyx(0.0, half_pi, 0.7);
    locked(0, 0) = locked(1, 0) = 0.0;  // cos(beta) exactly 0
    const iwr::Vec3 e = iwr::euler_from_matrix(locked);
    CHECK(e(0) == 0.0);
    CHECK((iwr::euler_zyx(e(0), e(1), e(2)) - locked).cwiseAbs().maxCoeff() < 1e-14);
}

}  // namespace test_main

// The one main of the test program, whose other files are the other test_*.cpp (check.hpp).
IWR_TEST_MAIN
